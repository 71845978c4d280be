"""Scores of one closed-loop run, all in metres and seconds of simulated time.

* ``tracking_rmse_m``: RMSE between the measured tool path p(t_k) and the reference
  p_ref(t_k) = placement(x_ref(t_k)), x_ref the task-space rollout of the same (goal-shifted)
  field from the same start, unperturbed.
* ``imitation_rmse_m`` / ``imitation_dtw_m``: the tool path sampled at the demonstration's times
  against the demonstration mapped to world; the DTW is ``lfd.metrics.dtw`` (a sum of point
  distances) divided by the demo's sample count, i.e. the mean aligned distance.
* ``final_goal_error_m``: |p(T) - g|, g the (shifted) goal in world.
* ``max_deviation_m`` / ``recovery_time_s`` (runs with a push): e(t) = |p(t) - p_u(t)|, p_u the
  same run without the push. max_deviation = max_{t >= t0} e(t); recovery time = t_r - t0 with
  t_r the first time after the push ends (t1) from which e stays <= 5 mm to the end of the run.

A pose task adds the same scores for the tool's orientation, in degrees of geodesic angle
|log(R_1^T R_2)| (``lfd.pose``, Eq. (P4); ``orientation_metrics``): ``tracking_rmse_deg``,
``imitation_orientation_error_deg`` (the RMS angle at the demonstration's times) and
``final_goal_error_deg``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lfd import metrics as lfd_metrics
from lfd.pose import geodesic_angle
from robots.limits import Limits

RECOVERY_TOLERANCE_M = 0.005


def recovery_time(t: np.ndarray, deviation: np.ndarray, window: tuple[float, float],
                  tol: float = RECOVERY_TOLERANCE_M) -> float | None:
    """t_r - t0 (see module docstring); t : (K,), deviation : (K,). None if e never settles <= tol."""
    t0, t1 = window
    over = np.flatnonzero(deviation > tol)
    after = np.flatnonzero(t >= t1)
    if after.size == 0:
        return None
    last_over = over[-1] if over.size else -1
    k = max(int(after[0]), int(last_over) + 1)
    if k >= len(t):
        return None
    return float(t[k] - t0)


def path_at(t_query: np.ndarray, t: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Linear interpolation of a path p : (K, 3) sampled at t : (K,) at times t_query : (M,)."""
    tq = np.clip(t_query, t[0], t[-1])
    return np.stack([np.interp(tq, t, p[:, j]) for j in range(p.shape[1])], axis=1)


def run_metrics(t: np.ndarray, ee: np.ndarray, reference: np.ndarray, goal: np.ndarray,
                demo_t: np.ndarray, demo: np.ndarray, unperturbed: np.ndarray | None = None,
                push_window: tuple[float, float] | None = None) -> dict[str, float | None]:
    """The path metrics of one run.

    t : (K,) times; ee, reference : (K, 3) measured and reference tool paths (m, world);
    goal : (3,); demo_t : (T,) and demo : (T, 3) the demonstration (m, world), times from 0;
    unperturbed : (K, 3) the same run without its push (needed with ``push_window``).
    """
    at_demo = path_at(demo_t - demo_t[0] + t[0], t, ee)
    out: dict[str, float | None] = {
        "tracking_rmse_m": lfd_metrics.rmse(ee, reference),
        "imitation_rmse_m": lfd_metrics.rmse(at_demo, demo),
        "imitation_dtw_m": lfd_metrics.dtw(at_demo, demo) / len(demo),
        "final_goal_error_m": float(np.linalg.norm(ee[-1] - goal)),
    }
    if push_window is not None:
        if unperturbed is None:
            raise ValueError("push metrics need the unperturbed run")
        e = np.linalg.norm(ee - unperturbed, axis=1)
        out["max_deviation_m"] = float(e[t >= push_window[0]].max())
        out["recovery_time_s"] = recovery_time(t, e, push_window)
    return out


def orientation_metrics(t: np.ndarray, rot: np.ndarray, reference: np.ndarray, goal: np.ndarray,
                        demo_t: np.ndarray, demo: np.ndarray) -> dict[str, float]:
    """The orientation metrics of one run of a pose task (module docstring), degrees.

    t : (K,) times; rot, reference : (K, 3, 3) measured and reference tool rotations (world);
    goal : (3, 3); demo_t : (T,) and demo : (T, 3, 3) the demonstration's rotations, times from 0.
    The tool's rotation at a demo time is that of the nearest control step.
    """
    k = np.clip(np.rint(np.interp(demo_t - demo_t[0] + t[0], t, np.arange(len(t)))).astype(int), 0, len(t) - 1)
    track = np.degrees(geodesic_angle(rot, reference))
    imit = np.degrees(geodesic_angle(rot[k], demo))
    return {"tracking_rmse_deg": float(np.sqrt(np.mean(track ** 2))),
            "imitation_orientation_error_deg": float(np.sqrt(np.mean(imit ** 2))),
            "final_goal_error_deg": float(np.degrees(geodesic_angle(rot[-1], goal)))}


#: a run is ``blocked`` when it ends further than this from its goal ...
BLOCKED_GOAL_M = 0.005
#: ... with a collision damper holding the arm back within this last part of the run, s
BLOCKED_WINDOW_S = 0.5


def clearance_metrics(t: np.ndarray, clearance: np.ndarray, active: np.ndarray, goal_error_m: float
                      ) -> dict[str, Any]:
    """Scores of whole-arm clearance (``sim.scene.collision``).

    Parameters
    ----------
    t : ndarray, shape (K+1,)
        Step times, s.
    clearance : ndarray, shape (K+1,)
        The smallest distance the dampers saw at each step, m (inf: nothing within their reach).
    active : ndarray of bool, shape (K+1,)
        Steps with a damper at its bound.
    goal_error_m : float
        The run's final distance to its goal, m.

    Returns
    -------
    dict
        ``arm_min_clearance_m`` (over the run; None if nothing came within reach),
        ``final_clearance_m`` (over the last ``BLOCKED_WINDOW_S``), ``guard_active_s`` (time with
        a damper at its bound), ``blocked``: the run ends more than ``BLOCKED_GOAL_M`` from its
        goal while a damper held the arm back in its last ``BLOCKED_WINDOW_S`` (a damper at its bound
        in some step of it, the arm within the dampers' reach through all of it), and
        ``stopped_short``: it ends more than ``BLOCKED_GOAL_M`` from its goal with nothing holding
        it back (the field did not take the tool there within the run).
    """
    dt = float(t[1] - t[0]) if len(t) > 1 else 0.0
    finite = clearance[np.isfinite(clearance)]
    late = t >= t[-1] - BLOCKED_WINDOW_S
    last = clearance[late][np.isfinite(clearance[late])]
    blocked = bool(goal_error_m > BLOCKED_GOAL_M and np.any(active[late])
                   and bool(np.all(np.isfinite(clearance[late][:-1]))))
    return {"arm_min_clearance_m": float(finite.min()) if finite.size else None,
            "final_clearance_m": float(last.min()) if last.size else None,
            "guard_active_s": float(np.count_nonzero(active) * dt),
            "blocked": blocked, "stopped_short": bool(goal_error_m > BLOCKED_GOAL_M and not blocked)}


def command_metrics(limits: Limits, t: np.ndarray, q: np.ndarray, command: np.ndarray,
                    ik_command: np.ndarray) -> dict[str, Any]:
    """Scores of a joint-velocity command stream (``robots.controller.ArmController``).

    Parameters
    ----------
    limits : Limits
        The arm's limits (``robots.limits``).
    t : ndarray, shape (K+1,)
        Step times, s.
    q : ndarray, shape (K+1, n)
        Measured joints, rad (the stream's positions).
    command, ik_command : ndarray, shape (K+1, n)
        The commands sent and the IK's joint velocities the limiter took as targets, rad/s (the last
        row, which no step sent, is ignored).

    Returns
    -------
    dict
        ``command_limits``: ``Limits.check`` of the stream (velocity as sent, its acceleration and
        jerk by differences); ``limiter_active_s``: time the limiter changed the IK's command;
        ``limiter_window_s``: the first and last time it did ([] if never).
    """
    dt = float(t[1] - t[0])
    acted = np.abs(command[:-1] - ik_command[:-1]).max(axis=1) > 1e-9
    steps = np.flatnonzero(acted)
    return {"command_limits": limits.check(t[:-1], q[:-1], command[:-1]),
            "limiter_active_s": float(len(steps) * dt),
            "limiter_window_s": [float(t[steps[0]]), float(t[steps[-1]])] if len(steps) else []}
