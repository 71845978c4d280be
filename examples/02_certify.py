"""Step 2: check the field's contraction guarantee where it matters, beyond the demos.

    python examples/02_certify.py [OUT]

``lfd.certify.certify`` evaluates the contraction condition, Eq. (17) of the paper (Eq. (C1) of
docs/equations.md), on a grid over the demos' box grown by half, and reports the field's
analytic constants: the overshoot bound sqrt(b/a) and the rate lambda of
|dx(t)| <= sqrt(b/a) |dx(0)| exp(-lambda t). Then two far-away starts show it.
"""

import sys

import numpy as np

import lfd
from lfd.cache import cached_field
from lfd.certify import certify

demos = lfd.load_demos("lasa:Angle")
field, _, _ = cached_field("contraction", demos, seed=0)

cert = certify(field, samples=2_500)                   # a 50 x 50 grid
print(f"verdict: {cert.verdict} ({cert.proof})")
print(f"rate {cert.rate} 1/s, overshoot bound sqrt(b/a) = {cert.overshoot:.2f}")

# two starts ten box sizes either side of the goal, far outside the training data
lo, hi = demos.bounds()
a, b = demos.goal + 10 * (hi - lo), demos.goal - 10 * (hi - lo)
t = np.linspace(0.0, 30.0, 601)
xa, xb = field.rollout(np.stack([a, b]), t)
gap = np.linalg.norm(xa - xb, axis=1)                 # shape (601,)
bound = cert.overshoot * gap[0] * np.exp(-cert.rate * t)
print(f"gap at t = 0: {gap[0]:.0f} mm, at t = 30 s: {gap[-1]:.2e} mm")
print(f"the bound holds at every step: {bool(np.all(gap <= bound * (1 + 1e-6) + 1e-9))}")
sys.exit(0 if cert.certified else 1)
