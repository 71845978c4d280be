"""Perturbations of a closed-loop run, each seeded and deterministic.

* ``StartOffset``: the run starts ``distance_m`` away from the demonstration's start (and, for a
  pose task, turned by ``angle_deg`` about a world axis).
* ``Push``: an external force F (N) on a body for ``duration_s`` from ``start_s``, through
  ``xfrc_applied`` (world frame, at the body's centre of mass).
* ``GoalShift``: the goal moves by ``distance_m``; the field is translated with it,
  f_shifted(x) = f(x - dg), so its attractor is g + dg. For a pose task it also turns by ``angle_deg``
  about a world axis u: in the chart at R_g (``lfd.pose``) the turned goal exp(theta u) R_g is the chart
  point l theta R_g^T A^T u, so the same translation of the field moves its attractor there exactly.
* ``JointVelocityNoise``: every control step, qdot_j += N(0, std^2) on each arm joint.
* ``Hold``: the arm is held still for ``duration_s`` from ``start_s`` (its joints clamped at rest).
* ``Release``: not a disturbance but a scene's event: its equality constraint (a grip) switched off
  at ``start_s``, so the hand lets go of what it holds (``sim.scene.place``).

A random direction (when none is given) is drawn from the perturbation's own seed: in the task
plane for a 2-D task, in space for a 3-D one. :func:`compile_schedule` turns a list of
perturbations into the arrays the control loop reads, so the loop itself draws nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from sim.errors import SimError
from sim.scene.placement import Placement


def _direction(direction: Sequence[float] | None, seed: int, placement: Placement) -> np.ndarray:
    """A unit world vector, shape (3,): ``direction`` normalised, else a seeded random direction
    in the task space mapped to world (in the task plane when d = 2)."""
    if direction is not None:
        u = np.asarray(direction, dtype=np.float64).reshape(3)
        n = float(np.linalg.norm(u))
        if not np.isfinite(n) or n == 0:
            raise SimError(f"perturbation direction must be a non-zero 3-vector, got {list(direction)}")
        return u / n
    rng = np.random.default_rng(seed)
    u = rng.normal(size=placement.position_dim)
    return placement.axes @ (u / np.linalg.norm(u))


def turn_axis(seed: int) -> np.ndarray:
    """A seeded random unit axis, shape (3,), world, for the turn of a pose task's perturbation (its
    own stream of ``seed``, apart from the direction's)."""
    u = np.random.default_rng([seed, 1]).normal(size=3)
    return u / np.linalg.norm(u)


@dataclass(frozen=True)
class Perturbation:
    """Base class; ``kind`` names the perturbation in metrics and file names."""

    kind = "none"

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


@dataclass(frozen=True)
class _Directed(Perturbation):
    """A perturbation along a world direction: ``direction`` (normalised), or, when None, one drawn
    from ``seed`` (module docstring). Both are keyword-only."""

    direction: tuple[float, float, float] | None = field(default=None, kw_only=True)
    seed: int = field(default=0, kw_only=True)

    def unit_world(self, placement: Placement) -> np.ndarray:
        """The unit direction u, shape (3,), world."""
        return _direction(self.direction, self.seed, placement)


@dataclass(frozen=True)
class _Moved(_Directed):
    """A point moved ``distance_m`` (m) along ``direction`` (world, shape (3,)) or a direction drawn
    from ``seed``; for a pose task also turned by ``angle_deg`` about a world axis drawn from ``seed``
    (``turn_axis``)."""

    distance_m: float = 0.02
    angle_deg: float = field(default=0.0, kw_only=True)

    def turn_world(self) -> np.ndarray:
        """The turn theta u, shape (3,), world, rad (zero without ``angle_deg``)."""
        return np.radians(self.angle_deg) * turn_axis(self.seed)


@dataclass(frozen=True)
class StartOffset(_Moved):
    """Start away from the demonstration's start (``_Moved``)."""

    kind = "offset"

    def offset_world(self, placement: Placement) -> np.ndarray:
        """The start displacement dp, shape (3,), in metres."""
        return self.distance_m * self.unit_world(placement)


@dataclass(frozen=True)
class Push(_Directed):
    """Force ``force_n`` (N) along ``direction`` (world, shape (3,); default: drawn from ``seed``) on
    MuJoCo body ``body`` (default: the body carrying the tool site) during [start_s, start_s + duration_s).
    The control loop records what it applied at each step (``sim.control.loop.RunTrace.applied_force``)."""

    force_n: float = 20.0
    duration_s: float = 0.2
    start_s: float = 1.0
    body: str | None = None
    kind = "push"

    def force_world(self, placement: Placement) -> np.ndarray:
        """The force vector F, shape (3,), in N."""
        return self.force_n * self.unit_world(placement)


@dataclass(frozen=True)
class GoalShift(_Moved):
    """Move (and, for a pose task, turn) the goal (``_Moved``; module docstring)."""

    kind = "goal"

    def offset_world(self, placement: Placement) -> np.ndarray:
        """The goal displacement dg, shape (3,), in metres (projected on the task plane when d = 2)."""
        return self.distance_m * placement.axes @ (placement.axes.T @ self.unit_world(placement))


@dataclass(frozen=True)
class JointVelocityNoise(Perturbation):
    """Add N(0, std_rad_s^2) to every arm joint velocity at every control step."""

    std_rad_s: float = 0.01
    seed: int = 0
    kind = "noise"


@dataclass(frozen=True)
class Hold(Perturbation):
    """Hold the arm still for ``duration_s`` from ``start_s``: after every physics step in that
    window the arm joints are reset to where they were at ``start_s``, at rest."""

    start_s: float = 1.0
    duration_s: float = 1.0
    kind = "hold"


@dataclass(frozen=True)
class Release(Perturbation):
    """Switch the scene's equality constraint ``equality`` off at ``start_s`` (the hand lets go)."""

    start_s: float = 0.0
    equality: str = ""
    kind = "release"


@dataclass
class Schedule:
    """What the control loop applies, precomputed.

    start_offset_task : array, shape (d,) -- added to the start point (task units)
    start_turn_world : array, shape (3,)  -- a pose task's start turn theta u (world, rad)
    goal_offset_task : array, shape (d,)  -- the field's translation dg (task units)
    push_body : int                       -- MuJoCo body id of the push (-1: none)
    push_force : array, shape (6,)        -- xfrc_applied row during the push (force, torque)
    push_steps : tuple[int, int]          -- control steps [k0, k1) of the push
    push_window_s : tuple[float, float] or None -- the same window in seconds of sim time
    qvel_noise : array, shape (K, n) or None -- noise added to arm joint velocities per step
    mocap_pos : array, shape (K+1, nmocap, 3) or None -- mocap body positions (moving obstacles,
        ``sim.scene.obstacles.mocap_path``) written before each step
    hold_steps : tuple[int, int]          -- control steps [h0, h1) of a hold ((-1, -1): none)
    hold_window_s : tuple[float, float] or None -- the same window in seconds of sim time
    release_eq : int                      -- MuJoCo equality id switched off (-1: none)
    release_step : int                    -- the control step that switches it off
    """

    start_offset_task: np.ndarray
    goal_offset_task: np.ndarray
    start_turn_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    push_body: int = -1
    push_force: np.ndarray | None = None
    push_steps: tuple[int, int] = (-1, -1)
    push_window_s: tuple[float, float] | None = None
    qvel_noise: np.ndarray | None = None
    mocap_pos: np.ndarray | None = None
    hold_steps: tuple[int, int] = (-1, -1)
    hold_window_s: tuple[float, float] | None = None
    release_eq: int = -1
    release_step: int = -1


def compile_schedule(perturbations: Sequence[Perturbation], placement: Placement, body_ids: dict[str, int],
                     default_body: str, n_joints: int, n_steps: int, control_dt: float,
                     equality_ids: dict[str, int] | None = None) -> Schedule:
    """Turn perturbations into a :class:`Schedule` for a run of ``n_steps`` control steps of
    ``control_dt`` s. ``body_ids`` maps MuJoCo body names to ids (for the push), ``equality_ids``
    equality names to ids (for a release)."""
    d = placement.dim
    sched = Schedule(np.zeros(d), np.zeros(d))
    pushes = [p for p in perturbations if isinstance(p, Push)]
    if len(pushes) > 1:
        raise SimError("only one push per run is supported")
    if sum(isinstance(p, Hold) for p in perturbations) > 1:
        raise SimError("only one hold per run is supported")
    goal_turn = np.eye(3)   # the goal's turns, composed, world
    for p in perturbations:
        if isinstance(p, (StartOffset, GoalShift)) and p.angle_deg != 0.0 and placement.chart is None:
            raise SimError(f"{p.kind}: a turn (angle_deg) needs a pose task")
        if isinstance(p, StartOffset):
            sched.start_offset_task = sched.start_offset_task + placement.offset_to_task(p.offset_world(placement))
            if p.angle_deg != 0.0:   # turns compose as rotations
                sched.start_turn_world = pin.log3(pin.exp3(p.turn_world()) @ pin.exp3(sched.start_turn_world))
        elif isinstance(p, GoalShift):
            sched.goal_offset_task = sched.goal_offset_task + placement.offset_to_task(p.offset_world(placement))
            if p.angle_deg != 0.0:
                goal_turn = pin.exp3(p.turn_world()) @ goal_turn
        elif isinstance(p, Push):
            name = p.body or default_body
            if name not in body_ids:
                raise SimError(f"push: unknown body '{name}'; bodies: {', '.join(sorted(body_ids))}")
            if p.duration_s <= 0 or p.start_s < 0:
                raise SimError("push: start_s must be >= 0 and duration_s > 0")
            k0 = int(round(p.start_s / control_dt))
            k1 = k0 + max(1, int(round(p.duration_s / control_dt)))
            sched.push_body = body_ids[name]
            sched.push_force = np.concatenate([p.force_world(placement), np.zeros(3)])
            sched.push_steps = (k0, k1)
            sched.push_window_s = (k0 * control_dt, k1 * control_dt)
        elif isinstance(p, JointVelocityNoise):
            if p.std_rad_s < 0:
                raise SimError("noise: std_rad_s must be >= 0")
            rng = np.random.default_rng(p.seed)
            noise = rng.normal(0.0, p.std_rad_s, (n_steps, n_joints))
            sched.qvel_noise = noise if sched.qvel_noise is None else sched.qvel_noise + noise
        elif isinstance(p, Hold):
            if p.duration_s <= 0 or p.start_s < 0:
                raise SimError("hold: start_s must be >= 0 and duration_s > 0")
            h0, h1 = int(round(p.start_s / control_dt)), int(round((p.start_s + p.duration_s) / control_dt))
            sched.hold_steps = (h0, h1)
            sched.hold_window_s = (h0 * control_dt, h1 * control_dt)
        elif isinstance(p, Release):
            if p.equality not in (equality_ids or {}):
                raise SimError(f"release: unknown equality '{p.equality}'; the scene has "
                               f"{', '.join(sorted(equality_ids or {})) or 'none'}")
            if sched.release_eq >= 0 or p.start_s < 0:
                raise SimError("release: one per run, at start_s >= 0")
            sched.release_eq = (equality_ids or {})[p.equality]
            sched.release_step = int(round(p.start_s / control_dt))   # after the run's end: never
        elif type(p) is not Perturbation:
            raise SimError(f"unknown perturbation {p!r}")
    if placement.chart is not None and not np.array_equal(goal_turn, np.eye(3)):
        # the turned goal G A R_g in the chart at R_g (task axes A): l log(R_g^T A^T G A R_g)
        rg, a = placement.chart.goal_rotation, placement.rotation
        sched.goal_offset_task[3:] += placement.chart.length * pin.log3(rg.T @ a.T @ goal_turn @ a @ rg)
    return sched
