"""Step 5: a small robustness sweep: pushes from eight directions, scored on one Experiment.

    python examples/05_sweep.py [OUT]

``sim.Experiment`` holds the robot, the demos and their placement; each ``run`` is one closed-loop
execution with its own perturbations. For larger grids on a process pool or on Ray, with resumable
records, see scripts/sweep_arm.py.
"""


import numpy as np

import lfd
import sim
from lfd.cache import cached_field
from robots import load_robot

demos = lfd.load_demos("lasa:Angle")
field, _, _ = cached_field("contraction", demos, seed=0)
exp = sim.Experiment(load_robot("panda"), demos)

recoveries = []
for k, angle in enumerate(np.linspace(0.0, 2 * np.pi, 8, endpoint=False)):
    direction = exp.placement.axes @ np.array([np.cos(angle), np.sin(angle)])   # in the task plane, world
    push = sim.Push(force_n=20.0, duration_s=0.2, start_s=1.0, direction=tuple(direction))
    m = exp.run(field, "push", (push,), seed=k).metrics
    recoveries.append(m["recovery_time_s"])                 # None: never back within tolerance
    back = "never" if m["recovery_time_s"] is None else f"{m['recovery_time_s']:.2f} s"
    print(f"push {np.degrees(angle):5.1f} deg: deviation {1e3 * m['max_deviation_m']:5.1f} mm, "
          f"recovered in {back}, goal {1e3 * m['final_goal_error_m']:.2f} mm")
done = [r for r in recoveries if r is not None]
print(f"recovered {len(done)} of {len(recoveries)}" + (f"; median recovery {np.median(done):.2f} s" if done else ""))
