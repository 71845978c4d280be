"""The layout of the compiled control step's parameter vector, shared by its two sides.

``sim.control.controller.FieldController._pack`` writes the vector and ``sim.control._control_kernel.kernel`` reads it;
both import ``HEADER`` from here, so the import runs one way (neither module imports the other at
load time, and ``import sim`` never imports numba).

Layout of ``prm``: ``HEADER`` scalars (plane?, spatial?, n . o, k_r, eps^2, fast speed^2, c_ref, 1/dt,
k_d, posture gain, torque?, d, n, nv, m, pose?), then R_ref (9), k_n n (3), n (3), s A (3 d), then
q_home, mid, fast_half, damping, lead, dof address (n each), then the pose block (zeros on a position
task; ``lfd.pose``, Eqs. (P1), (P3)): o (3), A^T / s (9), R_g^T R^T (9), R R_g / l (9) row by row and
l (1): shape (HEADER + 15 + 3 d + 6 n + POSE_BLOCK,), d = 3 on a pose task.
"""

from __future__ import annotations

HEADER = 16   # the scalars at the head of the parameter vector
POSE_BLOCK = 31   # the pose block at its tail
