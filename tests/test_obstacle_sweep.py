"""The field-level obstacle sweep (``lfd.bench.obstacles``): its cells' cache keys follow what the
results depend on, and a cell's record holds what the report counts."""

from __future__ import annotations

import io

import numpy as np
import pytest

import lfd.obstacles.avoidance as avoidance
from lfd.bench.obstacles import GOAL_RADIUS_MM, KEEP, SHAPES, ObstacleCell, compute_obstacle_cell, make_cells
from lfd.errors import ConfigError


def test_cell_keys_follow_the_modulations_constants(monkeypatch: pytest.MonkeyPatch) -> None:
    """A retuned constant of Eqs. (O1)-(O3) gives every cell a new key (a stale cached cell is not
    reused); the detour weight of Eq. (T4b) acts on phased fields only, so it re-keys the tracking
    cells alone."""
    node, tracking = ObstacleCell.make("node", "lasa:Snake", 6), ObstacleCell.make("tracking", "lasa:Snake", 6)
    plain = ObstacleCell.make("node", "lasa:Snake", 6, convergence=False)
    assert node.hash == ObstacleCell.make("node", "lasa:Snake", 6).hash
    monkeypatch.setattr(avoidance, "DETOUR_HOLD", 0.25)
    assert ObstacleCell.make("node", "lasa:Snake", 6).hash == node.hash
    assert ObstacleCell.make("tracking", "lasa:Snake", 6).hash != tracking.hash
    monkeypatch.setattr(avoidance, "CONVERGENCE_BAND", 0.75)
    assert ObstacleCell.make("node", "lasa:Snake", 6).hash != node.hash
    assert ObstacleCell.make("node", "lasa:Snake", 6, convergence=False).hash != plain.hash


def test_the_arm_job_gives_obstacle_runs_the_sweeps_horizon() -> None:
    from lfd.bench.obstacles import HORIZON
    from sim.pipeline import OBSTACLE_TIME_FACTOR

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
