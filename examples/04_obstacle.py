"""Step 4: put an obstacle on the path; the field bends around it.

    python examples/04_obstacle.py [OUT]

``lfd.avoid`` modulates the field around the obstacle and turns it toward the goal beside it
(docs/equations.md, Eqs. (O1)-(O3)): a trajectory that starts outside never enters it and still
reaches the goal. That protects the tool point; on the arm the job grows the obstacle by the hand's
size around the tool point, and collision dampers in the IK keep the rest of the arm clear
(Eqs. (A1)-(A2)). The same obstacle goes into the arm's scene as a MuJoCo geom, and the run
reports the arm's contacts with it, its clearance and whether it was ``blocked``.
"""

import sys

import lfd
import sim
from lfd.cache import cached_field

out = sys.argv[1] if len(sys.argv) > 1 else "out/examples"
demos = lfd.load_demos("lasa:Angle")
field, _, _ = cached_field("contraction", demos, seed=0)

# a sphere on the first demo, 40% along it, radius 5% of the demos' extent, no margin of its own
c, r = demos.x[0, 400], 0.05 * demos.extent                          # task units
sphere = f"sphere:{c[0]:.2f},{c[1]:.2f},{r:.2f}"
avoiding = lfd.avoid(field, [sphere])
path = avoiding.rollout(demos.x[0, 0], demos.t[0] - demos.t[0, 0])   # shape (1000, 2)
gamma = avoiding.obstacles[0].gamma(path)                            # > 1 outside the grown sphere
print(f"{sphere}: the field's path stays outside (min gamma {gamma.min():.3f} > 1): {bool(gamma.min() > 1)}")

job = sim.ArmJob(robot="panda", learners=("contraction",), demos="lasa:Angle", scenarios=("none",),
                 obstacles=(sphere,), out=f"{out}/04_obstacle", overwrite=True, size=(320, 240))
(run,) = sim.run_job(job).results
m = run.metrics
print(f"on the arm: goal {1e3 * m['final_goal_error_m']:.2f} mm, contact steps {m['obstacle_steps_in_contact']}, "
      f"smallest clearance {1e3 * m['obstacle_min_clearance_m']:.1f} mm, blocked {m['blocked']}")
