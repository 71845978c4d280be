"""Step 7: the controller a real arm runs, in a 1 kHz loop, with no simulator in the process.

    python examples/07_real_arm_loop.py [OUT]

The arm is the Panda's URDF in Pinocchio alone; the task is a recorded Franka pour in full pose,
where it was recorded. Each cycle the controller takes the measured joints and returns a joint
velocity within the Panda's published limits. On hardware the two marked lines are pylibfranka's
(robots.franka.stream_joint_velocities); here the arm follows its command exactly.
"""

import importlib.metadata
import time
from pathlib import Path

import numpy as np

import lfd
from lfd.rotations import quaternion_matrices
from robots.controller import ArmController
from robots.ik import solve_pose_ik
from robots.limits import PANDA
from robots.pinocchio_arm import load_urdf_arm
from robots.task_frame import TaskFrame

share = Path(importlib.metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data"))
arm = load_urdf_arm(share / "robots/panda_description/urdf/panda.urdf", "panda_hand_tcp",
                    q_home=np.array([0, -np.pi / 4, 0, -3 * np.pi / 4, 0, np.pi / 2, np.pi / 4]))
demos = lfd.load_demos("robottasks:pouring")
field = lfd.train("tracking", demos, seed=0)
frame = TaskFrame(origin=np.zeros(3), axes=np.eye(3), scale=1.0, chart=field.chart)   # poses as recorded
dt, duration = 1e-3, float(demos.t[0, -1]) + 1.5
ctl = ArmController(arm, frame, dt, limits=PANDA)

p0, R0 = demos.x[0, 0], quaternion_matrices(demos.q[0, 0])
q, _, _ = solve_pose_ik(arm, p0, R0, q0=arm.q_home, posture=0.1)
dq = np.zeros(7)
ctl.start(field.runner(frame.point(p0, R0), dt))

sent, joints, late = [], [], 0
next_tick = time.perf_counter()
for k in range(int(round(duration / dt))):
    cmd = ctl(q, dq, k * dt)
    q, dq = q + dt * cmd, cmd          # hardware: send cmd, then read q and dq at the next tick
    sent.append(cmd)
    joints.append(q)
    next_tick += dt
    late += time.perf_counter() > next_tick
    while (rest := next_tick - time.perf_counter()) > 0:
        time.sleep(max(rest - 2e-4, 0.0))   # sleep, then spin the last 0.2 ms

goal = field.goal[:3]
report = PANDA.check(np.arange(len(sent)) * dt, np.array(joints), np.array(sent))
print(f"{len(sent)} cycles at 1 kHz, {late} late; tool at {1e3 * np.linalg.norm(ctl.p - goal):.2f} mm from the goal")
print("command peaks (fraction of the limits):",
      ", ".join(f"{o} {report['joint'][o]['peak']:.2f}" for o in ("velocity", "acceleration", "jerk")),
      f"; over the limits: {report['violations']}")
