"""Step 3: run the field on the Franka Panda in closed loop at 500 Hz, and push it.

    python examples/03_arm_push.py [OUT]

One library call does the whole job (``sim.run_job``): it takes the cached model, places the demos
in front of the arm, runs the field through Pinocchio's differential IK and MuJoCo, pushes the hand
with 20 N for 0.2 s, scores the runs and writes the video, time series, figures and metrics.json.
"""

import sys

import sim

out = sys.argv[1] if len(sys.argv) > 1 else "out/examples"
job = sim.ArmJob(robot="panda", learners=("contraction",), demos="lasa:Angle",
                 scenarios=("none", "push"), out=f"{out}/03_arm", overwrite=True, size=(320, 240))
report = sim.run_job(job)

for r in report.results:
    m = r.metrics
    line = (f"{r.scenario:5s} tracking {1e3 * m['tracking_rmse_m']:.2f} mm, "
            f"goal {1e3 * m['final_goal_error_m']:.2f} mm, joint-limit violations {m['joint_limit_violations']}")
    if "recovery_time_s" in m:
        back = "never" if m["recovery_time_s"] is None else f"{m['recovery_time_s']:.2f} s"
        line += f", push deviation {1e3 * m['max_deviation_m']:.1f} mm, recovered in {back}"
    print(line)
print(f"wrote {report.json_path} and {report.n_videos} video(s)")
