"""The field-level obstacle sweep (``lfd.bench.obstacles``): its cells' cache keys follow what the
results depend on, and a cell's record holds what the report counts."""

from __future__ import annotations

import io

import numpy as np
import pytest

import lfd.obstacles.modulation as modulation
from lfd.bench.obstacles import GOAL_RADIUS_MM, KEEP, SHAPES, ObstacleCell, compute_obstacle_cell, make_cells
from lfd.errors import ConfigError


def test_cell_keys_follow_the_modulations_constants(monkeypatch: pytest.MonkeyPatch) -> None:
    """A retuned constant of Eqs. (O1)-(O3) gives every cell a new key (a stale cached cell is not
    reused); the detour weight of Eq. (T4b) acts on phased fields only, so it re-keys the tracking
    cells alone."""
    node, tracking = ObstacleCell.make("node", "lasa:Snake", 6), ObstacleCell.make("tracking", "lasa:Snake", 6)
    plain = ObstacleCell.make("node", "lasa:Snake", 6, convergence=False)
    assert node.hash == ObstacleCell.make("node", "lasa:Snake", 6).hash
    monkeypatch.setattr(modulation, "DETOUR_HOLD", 0.25)
    assert ObstacleCell.make("node", "lasa:Snake", 6).hash == node.hash
    assert ObstacleCell.make("tracking", "lasa:Snake", 6).hash != tracking.hash
    monkeypatch.setattr(modulation, "CONVERGENCE_BAND", 0.75)
    assert ObstacleCell.make("node", "lasa:Snake", 6).hash != node.hash
    assert ObstacleCell.make("node", "lasa:Snake", 6, convergence=False).hash != plain.hash


def test_the_arm_job_gives_obstacle_runs_the_sweeps_horizon() -> None:
    from lfd.bench.obstacles import HORIZON
    from sim.run.pipeline import OBSTACLE_TIME_FACTOR

    assert OBSTACLE_TIME_FACTOR == HORIZON


def test_cells_are_dealt_round_robin_over_the_shapes() -> None:
    cells = make_cells(9, learners=("node", "tracking"), plain=True)
    assert len(cells) == 9 * 2 * 2
    assert [c.shape for c in cells[::4]] == [SHAPES[i % len(SHAPES)] for i in range(9)]
    assert len({c.hash for c in cells}) == len(cells)
    with pytest.raises(ConfigError, match="placements must be between 1 and 10000"):
        make_cells(0)


def test_a_tracking_cell_reaches_every_goal_without_an_entry() -> None:
    """GShape's scene of the sweep (scene 4): every demo start of the tracking learner ends within
    ``GOAL_RADIUS_MM`` of the goal at 3x the demos' duration, no step inside a grown obstacle, and
    the NPZ holds the trajectories the report draws."""
    cell = ObstacleCell.make("tracking", "lasa:GShape", 4)
    record, npz = compute_obstacle_cell(cell)
    assert record["hash"] == cell.hash and record["starts"] == 7 == len(record["final_error_mm"])
    assert record["converged"] == 7 and max(record["final_error_mm"]) <= GOAL_RADIUS_MM
    assert record["entries"] == 0 and record["min_gamma"] >= 1.0 and record["goal_gamma"] > 1.0
    assert 1 <= len(record["obstacles"]) <= 3
    with np.load(io.BytesIO(npz)) as z:
        assert z["y"].shape[0] == 7 and z["y"].shape[1] <= KEEP and z["y"].shape[2] == 2
        assert z["t"].shape == (z["y"].shape[1],) and z["t"][0] == 0.0


def test_the_report_counts_starts_scenes_entries_and_names_the_failing_scenes() -> None:
    """``lfd bench obstacles``' report (``lfd.bench.obstacles_report.report_lines``) of two scenes of
    one learner, with and without Eqs. (O2)-(O3)."""
    from lfd.bench.obstacles_report import report_lines

    def record(scene: int, convergence: bool, converged: int, entries: int, worst: float) -> dict:
        return {"learner": "node", "shape": "lasa:Angle", "scene": scene, "convergence": convergence,
                "converged": converged, "starts": 7, "entries": entries, "final_error_mm": [0.1] * 6 + [worst],
                "obstacles": [f"sphere {scene}"], "cell_s": 1.0 + scene}

    recs = [record(0, True, 7, 0, 0.2), record(1, True, 6, 1, 3.5), record(0, False, 5, 0, 40.0)]
    lines = report_lines(recs, 2)
    assert "| node | Eqs. (O1)-(O3) | 2 | 13/14 (92.9 %) | 1/2 | 1 | 3.5 |" in lines
    assert "| node | plain (KZB 2012) | 1 | 5/7 (71.4 %) | 0/1 | 0 | 40 |" in lines
    assert "| lasa:Angle | 13/14 | - | - | - | - |" in lines and "| spiral | - | - | - | - | - |" in lines
    assert "Scenes that fail with Eqs. (O1)-(O3): 1." in lines
    assert any(line.startswith("- node on lasa:Angle, scene 1: 6/7 converged, worst 3.5 mm") for line in lines)
    assert lines[-1] == "Cell time: median 1.00 s, max 2.00 s."
