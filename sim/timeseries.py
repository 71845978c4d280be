"""A run's time series as an .npz beside metrics.json, so a user can plot it themselves.

Arrays (K+1 control steps, n arm joints, d task dimensions):

* ``t`` (K+1,) s; ``q`` (K+1, n) rad or m; ``qdot`` (K+1, n) rad/s or m/s, central differences
  of ``q`` (``numpy.gradient``: the loop records positions only);
* ``ee`` (K+1, 3) the measured tool position, world m; ``reference`` (K+1, 3) the field's own
  rollout from the same start; ``unperturbed`` (K+1, 3) the same run without its push or hold
  (NaN when it had neither); ``deviation`` (K+1,) |ee - unperturbed| m;
  ``tracking_error`` (K+1,) |ee - reference| m;
* ``command`` (K+1, d) the field's command, task units per second, and ``command_world``
  (K+1, 3) the same in m/s (recomputed from the recorded states, ``Experiment.command``);
* ``push_force`` (K+1, 3) N, the push applied at each step (zero outside its window);
* ``goal`` (3,) world m; ``push_window`` (2,) s (NaN without a push); ``q_min``, ``q_max`` (n,);
  ``phase`` (K+1,) for a phase field (NaN otherwise);
  ``learner``, ``scenario``, ``joint_names`` as strings.
"""

from __future__ import annotations

import io
import os
from typing import Any

import numpy as np


def arrays(result: Any, placement: Any, robot: Any) -> dict[str, np.ndarray]:
    """The arrays of the module docstring for a ``sim.RunResult``."""
    ro = result.rollout
    t = np.asarray(ro.t)
    n_steps = len(t)
    force = np.zeros((n_steps, 3))
    window = np.array([np.nan, np.nan])
    if ro.push_window_s is not None and ro.push_force is not None:
        window = np.asarray(ro.push_window_s, dtype=np.float64)
        on = (t >= window[0] - 1e-9) & (t < window[1] - 1e-9)
        force[on] = ro.push_force
    unpert = (np.full_like(ro.ee, np.nan) if result.unperturbed is None
              else np.asarray(result.unperturbed, dtype=np.float64))
    command = (np.full((n_steps, placement.dim), np.nan) if result.command is None
               else np.asarray(result.command, dtype=np.float64))
    return {
        "t": t, "q": np.asarray(ro.q), "qdot": np.gradient(np.asarray(ro.q), t, axis=0),
        "ee": np.asarray(ro.ee), "reference": np.asarray(result.reference), "unperturbed": unpert,
        "deviation": np.linalg.norm(ro.ee - unpert, axis=1),
        "tracking_error": np.linalg.norm(ro.ee - result.reference, axis=1),
        "command": command, "command_world": placement.velocity_to_world(command),
        "push_force": force, "goal": np.asarray(ro.goal_world), "push_window": window,
        "q_min": np.asarray(robot.q_min), "q_max": np.asarray(robot.q_max),
        "phase": np.full(n_steps, np.nan) if ro.phase is None else np.asarray(ro.phase),
        "learner": np.array(result.learner), "scenario": np.array(result.scenario),
        "joint_names": np.array(list(robot.arm_joints)),
    }


def save(path: str | os.PathLike, data: dict[str, np.ndarray]) -> None:
    """Write ``data`` as a compressed .npz at ``path`` atomically (``lfd.io.atomic_write``)."""
    from lfd.io import atomic_write

    buf = io.BytesIO()
    # ignore: numpy's stubs let the **data arrays match the bool allow_pickle keyword
    np.savez_compressed(buf, **data)  # type: ignore[arg-type]
    atomic_write(path, lambda f: f.write(buf.getvalue()))
