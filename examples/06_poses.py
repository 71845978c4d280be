"""Step 6: a real demonstration in full pose, a pour recorded on a Franka, run where it was recorded.

    python examples/06_poses.py [OUT]

RoboTasks9's demos are positions and orientations (``lfd.demos.robottasks``). The tracking learner
learns them on R^3 x SO(3) through the log chart at the goal orientation (``lfd.pose``), and the
Panda follows the field's whole twist, linear and angular, at 500 Hz. The start is moved 5 cm and
turned 30 degrees; the field still brings the hand to the goal pose.
"""

import sys

import sim

out = sys.argv[1] if len(sys.argv) > 1 else "out/examples"
job = sim.ArmJob(robot="panda", learners=("tracking",), demos="robottasks:pouring",
                 scenarios=("none", "offset"), out=f"{out}/06_poses", overwrite=True, videos=False)
report = sim.run_job(job)

for r in report.results:
    m = r.metrics
    print(f"{r.scenario:6s} tracking {1e3 * m['tracking_rmse_m']:.2f} mm and {m['tracking_rmse_deg']:.3f} deg, "
          f"goal {1e3 * m['final_goal_error_m']:.2f} mm and {m['final_goal_error_deg']:.3f} deg, "
          f"joint-limit violations {m['joint_limit_violations']}")
print(f"wrote {report.json_path}")
