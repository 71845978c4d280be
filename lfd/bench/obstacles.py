"""The field-level obstacle sweep: every learner, seeded obstacle scenes, convergence and entries.

A cell is one learner on one demo set with one seeded scene (``lfd.obstacles.random_scene``),
modulated with Eqs. (O1)-(O3) (``convergence`` True) or with the plain modulation of
Khansari-Zadeh and Billard (False, the ablation). It rolls the avoiding field out from every demo
start for ``HORIZON`` x the demos' duration and records each start's final distance to the goal
in mm, and the smallest Gamma met along every trajectory (< 1: it entered an obstacle grown by
its margin). LASA shapes are in mm; the spirals count mm at ``SPIRAL_EXTENT_M`` of extent (their
Panda placement). The sweep caches its cells with the LASA suite's content-checked cache
(``lfd.bench.runner.run_cells``).
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lfd.bench.protocol import stable_hash
from lfd.errors import ConfigError

__all__ = ["ObstacleCell", "SHAPES", "LEARNERS", "HORIZON", "GOAL_RADIUS_MM", "make_cells", "compute_obstacle_cell",
           "demo_set", "mm_per_unit"]

#: the demo sets of the sweep: two spirals and five LASA shapes
SHAPES = ("spiral", "spiral3d", "lasa:Angle", "lasa:CShape", "lasa:GShape", "lasa:Sshape", "lasa:Snake")
LEARNERS = ("node", "stable_node", "contraction", "contracting_node", "tracking")
#: rollout length, x the demos' duration
HORIZON = 3.0
#: a start converged when its final position lies within this of the goal
GOAL_RADIUS_MM = 1.0
#: the spirals' extent on the Panda, m: their mm are counted at this scale
SPIRAL_EXTENT_M = 0.14
#: integration steps per demo duration
STEPS_PER_DURATION = 300
#: samples kept per trajectory for figures
KEEP = 150
VERSION = 1


@dataclass(frozen=True)
class ObstacleCell:
    """One learner on one demo set with one seeded scene; ``convergence`` selects Eq. (O2)-(O3)."""

    learner: str
    shape: str
    scene: int
    convergence: bool = True
    seed: int = 0
    hash: str = field(default="", compare=False)

    @classmethod
    def make(cls, learner: str, shape: str, scene: int, convergence: bool = True, seed: int = 0) -> ObstacleCell:
        from lfd.obstacles.avoidance import settings

        key = {"version": VERSION, "learner": learner, "shape": shape, "scene": scene,
               "convergence": convergence, "seed": seed, "horizon": HORIZON, "steps": STEPS_PER_DURATION,
               "modulation": settings(learner == "tracking")}
        return cls(learner, shape, scene, convergence, seed, stable_hash(key))

    @property
    def stem(self) -> str:
        tag = "" if self.convergence else "__plain"
        return f"{self.learner}__{self.shape.replace(':', '-')}__scene{self.scene:03d}{tag}"


def make_cells(placements: int, learners: tuple[str, ...] = LEARNERS, shapes: tuple[str, ...] = SHAPES,
               plain: bool = False) -> list[ObstacleCell]:
    """``placements`` scenes, dealt round-robin over ``shapes`` (scene i on shape i mod len), each
    run by every learner; with ``plain`` also the ablation without Eqs. (O2)-(O3)."""
    if not 1 <= placements <= 10_000:
        raise ConfigError(f"placements must be between 1 and 10000, got {placements}")
    cells = []
    for i in range(placements):
        for learner in learners:
            for conv in ((True, False) if plain else (True,)):
                cells.append(ObstacleCell.make(learner, shapes[i % len(shapes)], i, conv))
    return cells


def demo_set(shape: str) -> Any:
    """The demos of a sweep shape (``lfd.load_demos``)."""
    import lfd

    return lfd.load_demos(shape)


def mm_per_unit(shape: str, demos: Any) -> float:
    """mm per demo unit: 1 for LASA, else the spiral's extent scaled to ``SPIRAL_EXTENT_M``."""
    return 1.0 if shape.startswith("lasa:") else SPIRAL_EXTENT_M * 1000.0 / float(demos.extent)


def compute_obstacle_cell(cell: ObstacleCell) -> tuple[dict[str, Any], bytes]:
    """Roll the cell's avoiding field out (module docstring): its record and its trajectories
    (``y``, shape (N, KEEP, d)) as NPZ bytes. The learner's model comes from ``lfd.cache``."""
    from lfd.cache import cached_field
    from lfd.obstacles import avoid, random_scene

    t0 = time.perf_counter()
    demos = demo_set(cell.shape)
    nominal, _, _ = cached_field(cell.learner, demos, cell.seed, {}, verbose=False)
    scene = random_scene(demos, cell.scene)
    f = avoid(nominal, scene, convergence=cell.convergence)
    duration = float(demos.t[0, -1] - demos.t[0, 0])
    n = int(round(HORIZON * STEPS_PER_DURATION))
    t = np.linspace(0.0, HORIZON * duration, n + 1)
    y = f.rollout(demos.x[:, 0], t)                                   # (N, T, d)
    gam = np.stack([f.gamma(y[:, j]) for j in range(t.size)], axis=1)
    mm = mm_per_unit(cell.shape, demos)
    err = np.linalg.norm(y[:, -1] - demos.goal, axis=1) * mm
    record = {"hash": cell.hash, "learner": cell.learner, "shape": cell.shape, "scene": cell.scene,
              "seed": cell.seed, "convergence": cell.convergence,
              "obstacles": [o.describe() for o in scene], "final_error_mm": err.tolist(),
              "converged": int(np.sum(err <= GOAL_RADIUS_MM)), "starts": int(len(err)),
              "min_gamma": float(gam.min()), "entries": int(np.sum(gam.min(axis=1) < 1.0)),
              "goal_gamma": float(f.gamma(demos.goal)), "cell_s": time.perf_counter() - t0}
    keep = np.unique(np.linspace(0, t.size - 1, KEEP).astype(int))
    buf = io.BytesIO()
    np.savez_compressed(buf, y=y[:, keep], t=t[keep])
    return record, buf.getvalue()
