"""Tracking regression of learned fields in closed loop, against tests/golden/tracking.json.

Small models are trained here (fixed seed, short training) on a short spiral, then run on the
planar arm and on the Panda (computed-torque actuation, dls IK, 500 Hz). A run fails if a tracked
metric is worse than golden * (1 + REL) + ABS_M. The contraction policy must recover from the
20 N, 0.2 s push, and no run may leave the joint limits.

Regenerate the golden file (after an intended change, and say why in the commit):
    UPDATE_GOLDEN=1 pytest tests/test_arm_regression.py
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

import lfd
import sim  # noqa: F401  (sets MUJOCO_GL first)
from robots import load_robot

pytestmark = pytest.mark.usefixtures("one_thread")   # torch rollouts: one thread (conftest.py)

GOLDEN = Path(__file__).parent / "golden" / "tracking.json"
REL, ABS_M = 0.25, 0.0005          # tolerance: 25 % + 0.5 mm
CHECKED = ("tracking_rmse_m", "final_goal_error_m", "imitation_rmse_m")
# Every option that shapes these small models is pinned, so a change of a learner's defaults does
# not move the golden numbers (a change of its algorithm may: then regenerate, see above).
TRAINING = {
    "node": {"hidden": (32, 32), "iterations": 150, "lr": 1e-2, "lr_final": 1e-4, "seg": 10, "seg_start": 2,
             "batch": 128, "samples": 100},
    "contraction": {"layers": 2, "hidden": 16, "iterations": 30, "rate": 0.5, "batch": 1000,
                    "traj_weight": 1.0, "traj_points": 25, "speed_weight": 0.02, "path_samples": 50},
}
UPDATE = os.environ.get("UPDATE_GOLDEN") == "1"


@pytest.fixture(scope="module")
def demos() -> lfd.DemoSet:
    return lfd.spiral(n_demos=3, n_samples=100, duration=3.0)


@pytest.fixture(scope="module")
def fields(demos) -> dict[str, lfd.VelocityField]:
    return {name: lfd.train(name, demos, seed=0, progress=False, **opts) for name, opts in TRAINING.items()}


@pytest.fixture(scope="module")
def experiments(demos) -> dict[str, sim.Experiment]:
    return {name: sim.Experiment(load_robot(name, actuation="torque"), demos, settle_s=0.5)
            for name in ("planar", "panda")}


def golden() -> dict:
    return json.loads(GOLDEN.read_text()) if GOLDEN.is_file() else {"runs": {}}


def update_golden(key: str, values: dict[str, float]) -> None:
    """Write one run's entry into the golden file, keeping the others: each test updates its own
    entry, so regenerating does not depend on which tests ran or in what order."""
    data = golden()
    runs = {**data.get("runs", {}), key: values}
    GOLDEN.parent.mkdir(exist_ok=True)
    GOLDEN.write_text(json.dumps({
        "about": "tracking metrics (m) of short closed-loop runs, see tests/test_arm_regression.py",
        "tolerance": {"relative": REL, "absolute_m": ABS_M},
        "training": {k: {o: list(v) if isinstance(v, tuple) else v for o, v in opts.items()}
                     for k, opts in TRAINING.items()},
        "runs": dict(sorted(runs.items())),
    }, indent=2) + "\n")


@pytest.mark.parametrize("robot", ["planar", "panda"])
@pytest.mark.parametrize("learner", ["node", "contraction"])
def test_tracking_not_worse_than_golden(robot, learner, fields, experiments):
    m = experiments[robot].run(fields[learner], "none").metrics
    key = f"{robot}/{learner}"
    assert m["joint_limit_violations"] == 0
    if UPDATE:
        update_golden(key, {k: round(float(m[k]), 6) for k in CHECKED})
        return
    ref = golden()["runs"].get(key)
    assert ref is not None, f"no golden entry {key}; run with UPDATE_GOLDEN=1"
    for k in CHECKED:
        bound = ref[k] * (1 + REL) + ABS_M
        assert m[k] <= bound, f"{key} {k} = {m[k]:.5f} m, golden {ref[k]:.5f} m, bound {bound:.5f} m"


@pytest.mark.parametrize("robot, max_recovery_s", [("panda", 1.5), ("planar", None)])
def test_contraction_recovers_from_push(robot, max_recovery_s, fields, experiments):
    r = experiments[robot].run(fields["contraction"], "push")
    m = r.metrics
    assert m["max_deviation_m"] > 0.005                    # the push did move the tool off its path
    assert m["recovery_time_s"] is not None                 # ... and it came back within 5 mm, to stay
    if max_recovery_s is not None:
        assert m["recovery_time_s"] <= max_recovery_s
    assert m["joint_limit_violations"] == 0
    assert m["final_goal_error_m"] < 0.005
