"""A run's time series as an .npz beside metrics.json, so a user can plot it themselves.

Arrays (K+1 control steps, n arm joints, d task dimensions):

* ``t`` (K+1,) s; ``q`` (K+1, n) rad or m; ``qdot`` (K+1, n) rad/s or m/s, both as the control
  loop read them from MuJoCo at each step (``sim.control.loop.RunTrace``);
* ``ee`` (K+1, 3) the measured tool position, world m; ``reference`` (K+1, 3) the field's own
  rollout from the same start; ``unperturbed`` (K+1, 3) the same run without its push or hold
  (NaN when it had neither); ``deviation`` (K+1,) |ee - unperturbed| m;
  ``tracking_error`` (K+1,) |ee - reference| m;
* ``command`` (K+1, d) the field's command, task units per second, as the loop fed it to the
  controller, and ``command_world`` (K+1, 3) the same in m/s;
* ``push_force`` (K+1, 3) N, world: the external force the push actually applied during each
  control step, as the loop read it back from ``xfrc_applied`` (zero outside its window);
* ``goal`` (3,) world m; ``push_window`` (2,) s (NaN without a push); ``q_min``, ``q_max`` (n,);
  ``phase`` (K+1,) for a phase field (NaN otherwise);
  ``learner``, ``scenario``, ``joint_names`` as strings, and ``perturbations``, the JSON list of
  the run's perturbations (``RunResult.perturbations``, each ``describe()``).
"""

from __future__ import annotations

import io
import json
import os
from typing import Any

import numpy as np


def arrays(result: Any, placement: Any, robot: Any) -> dict[str, np.ndarray]:
    """The arrays of the module docstring.

    Parameters
    ----------
    result : sim.RunResult
        The run; its trace's recorded states, command and applied force are used as they are.
    placement : sim.Placement
        The run's placement (task velocity -> world).
    robot : robots.RobotModel
        The run's robot (joint limits and names).

    Returns
    -------
    dict of str to ndarray
        Name -> array, shapes as in the module docstring.
    """
    ro = result.trace
    t = np.asarray(ro.t)
    n_steps = len(t)
    window = np.array([np.nan, np.nan]) if ro.push_window_s is None else np.asarray(ro.push_window_s, dtype=np.float64)
    unpert = (np.full_like(ro.ee, np.nan) if result.unperturbed is None
              else np.asarray(result.unperturbed, dtype=np.float64))
    command = np.asarray(ro.command if result.command is None else result.command, dtype=np.float64)
    return {
        "t": t, "q": np.asarray(ro.q), "qdot": np.asarray(ro.qdot),
        "ee": np.asarray(ro.ee), "reference": np.asarray(result.reference), "unperturbed": unpert,
        "deviation": np.linalg.norm(ro.ee - unpert, axis=1),
        "tracking_error": np.linalg.norm(ro.ee - result.reference, axis=1),
        "command": command, "command_world": placement.velocity_to_world(command),
        "push_force": np.asarray(ro.applied_force, dtype=np.float64), "goal": np.asarray(ro.goal_world),
        "push_window": window, "q_min": np.asarray(robot.q_min), "q_max": np.asarray(robot.q_max),
        "phase": np.full(n_steps, np.nan) if ro.phase is None else np.asarray(ro.phase),
        "learner": np.array(result.learner), "scenario": np.array(result.scenario),
        "joint_names": np.array(list(robot.arm_joints)),
        "perturbations": np.array(json.dumps([p.describe() for p in result.perturbations])),
    }


def save(path: str | os.PathLike, data: dict[str, np.ndarray]) -> None:
    """Write ``data`` as a compressed .npz at ``path`` atomically (``lfd.io.atomic_write``)."""
    from lfd.io import atomic_write

    buf = io.BytesIO()
    # ignore: numpy's stubs let the **data arrays match the bool allow_pickle keyword
    np.savez_compressed(buf, **data)  # type: ignore[arg-type]
    atomic_write(path, lambda f: f.write(buf.getvalue()))
