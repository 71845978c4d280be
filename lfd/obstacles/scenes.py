"""Seeded obstacle scenes on and near a demonstrated path, for sweeps and tests.

``random_scene(demos, seed)`` places 1 to 3 spheres or boxes. Each obstacle is, with probability
``NEAR_GOAL_P``, put beside the goal (the bounding sphere of the grown shape 20 % to 100 % of
``NEAR_GOAL_GAP`` x extent from it), else centred on a random demo at a random fraction of its
arc length and pushed sideways by up to its own size. Sizes are 3 % to 10 % of the demos' extent,
margins 0 to 4 %. A scene keeps the goal clear (Gamma(goal) >= ``MIN_GOAL_GAMMA`` for every
obstacle, and for their merged groups) and every demo start outside the grown obstacles, and
obstacles that overlap must merge into star-shaped groups (``lfd.obstacles.groups``); an obstacle
that breaks this is drawn again. The same (demos, seed) always gives the same scene.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.obstacles.avoidance import MIN_GOAL_GAMMA
from lfd.obstacles.groups import group
from lfd.obstacles.shapes import Box, Obstacle, Sphere

__all__ = ["random_scene", "NEAR_GOAL_P", "NEAR_GOAL_GAP"]

#: chance that an obstacle is put beside the goal
NEAR_GOAL_P = 0.25
#: beside the goal: its grown surface lies within this fraction of the extent of the goal
NEAR_GOAL_GAP = 0.05
#: a demo start must have Gamma above this for every obstacle
START_GAMMA = 1.05
_TRIES = 200


def _arc_point(x: np.ndarray, fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """The point at ``fraction`` of the arc length of the path x, shape (T, d), and the unit
    tangent there, each shape (d,)."""
    seg = np.linalg.norm(np.diff(x, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    j = int(min(np.searchsorted(s, fraction * s[-1]), len(x) - 2))
    tangent = x[j + 1] - x[j]
    return x[j], tangent / max(float(np.linalg.norm(tangent)), 1e-12)


def _shape(center: np.ndarray, half: np.ndarray, margin: float, box: bool) -> Obstacle:
    """A box of half sizes ``half`` (d,), or a sphere of radius half[0], grown by ``margin``."""
    if box:
        return Box(center, half, margin=margin)
    return Sphere(center, float(half[0]), margin=margin)


def _clear(obstacles: list[Obstacle], goal: np.ndarray, starts: np.ndarray, extra: float) -> bool:
    """The goal and the starts, shape (N, d), are clear of every obstacle and merged group, each
    grown by ``extra`` more."""
    if extra > 0:
        obstacles = [dataclasses.replace(o, margin=o.margin + extra) for o in obstacles]
    try:
        units = group(obstacles)
    except ConfigError:   # overlapping without a common interior point: not one star-shaped group
        return False
    for u in units:
        if float(u.geometry(goal[None], 0.0)[0][0]) < MIN_GOAL_GAMMA:
            return False
        if float(np.min(u.geometry(starts, 0.0)[0])) < START_GAMMA:
            return False
    return True


def random_scene(demos: DemoSet, seed: int, count: int | None = None, extra_margin: float = 0.0) -> list[Obstacle]:
    """1 to 3 seeded obstacles (``count`` fixes the number) on and near the demos' path (module
    docstring), in the demos' units and dimension (2-D or 3-D). ``extra_margin`` (units): the goal
    and the starts must also be clear of the obstacles grown by this (a robot's hand margin,
    which the caller adds)."""
    if demos.dim not in (2, 3):
        raise ConfigError(f"obstacle scenes are 2-D or 3-D; these demos are {demos.dim}-D")
    rng = np.random.default_rng([int(seed), 0x0B57])
    k = int(rng.integers(1, 4)) if count is None else int(count)
    if not 1 <= k <= 16:
        raise ConfigError(f"a scene holds 1 to 16 obstacles, not {k}")
    extent, goal, starts = float(demos.extent), demos.goal, demos.x[:, 0]
    scene: list[Obstacle] = []
    for _ in range(k):
        for _ in range(_TRIES):
            size = extent * rng.uniform(0.03, 0.10)
            margin = extent * rng.uniform(0.0, 0.04)
            box = bool(rng.random() < 0.5)
            half = size * (rng.uniform(0.6, 1.4, demos.dim) if box else np.ones(demos.dim))
            if rng.random() < NEAR_GOAL_P:
                u = rng.normal(size=demos.dim)
                u /= np.linalg.norm(u)
                gap = extent * rng.uniform(0.2, 1.0) * NEAR_GOAL_GAP
                reach = _shape(goal, half, margin, box).size      # the grown shape's bounding radius
                ob = _shape(goal + u * (reach + gap), half, margin, box)
            else:
                path = demos.x[int(rng.integers(len(demos.x)))]
                c, tangent = _arc_point(path, float(rng.uniform(0.1, 0.95)))
                side = rng.normal(size=demos.dim)
                side -= side.dot(tangent) * tangent
                side /= max(float(np.linalg.norm(side)), 1e-12)
                ob = _shape(c + side * size * rng.uniform(-1.0, 1.0), half, margin, box)
            if _clear(scene + [ob], goal, starts, float(extra_margin)):
                scene.append(ob)
                break
        else:
            raise ConfigError(f"no clear place for obstacle {len(scene) + 1} of {k} after {_TRIES} tries")
    return scene
