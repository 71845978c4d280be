"""Step 1: learn a contracting velocity field from the LASA "Angle" demonstrations and plot it.

    python examples/01_train_and_plot.py [OUT]

The contraction learner fits f(x) = J_phi(x)^-1 A (phi(x) - phi(goal)), a field that contracts
by construction (docs/equations.md). The figure shows its streamlines, the demos, rollouts from
perturbed starts, and the training loss. The model is cached (``lfd.cache``), so the next
examples reuse it instead of training again.
"""

import sys
from pathlib import Path

import numpy as np

import lfd
from lfd.cache import cached_field
from lfd.plotting import field_figure

out = Path(sys.argv[1] if len(sys.argv) > 1 else "out/examples")
out.mkdir(parents=True, exist_ok=True)

demos = lfd.load_demos("lasa:Angle")                  # 7 demos, t (7, 1000), x (7, 1000, 2), mm
field, path, trained = cached_field("contraction", demos, seed=0)
print(f"{'trained' if trained else 'cached'} model {path}")
print(f"goal {field.goal}, contraction rate {field.config['rate']} 1/s")

x0 = demos.x[:, 0]                                    # each demo's start, shape (7, 2)
t = np.linspace(0.0, demos.t[0, -1] - demos.t[0, 0], 250)  # the demo's duration, shape (250,)
rollout = field.rollout(x0, t)                        # RK4, shape (7, 250, 2)
err = abs(rollout[:, -1] - demos.goal).max()
print(f"largest distance to the goal at the demos' end: {err:.2f} mm")

field_figure(field, demos).savefig(out / "01_field.png", dpi=80)
print(f"wrote {out / '01_field.png'}")
