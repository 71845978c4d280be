"""Hand-built fields with known equilibria and closed orbits, for the tests of ``lfd.equilibria``, the
certificate and the plots (no training but one NODE iteration).

- ``bistable_field(d)``: f(z) = (u - u^3, -z_2, ..., -z_d) with u = z_1 + 1 and the goal at z = 0:
  sinks at z_1 = 0 (the goal) and z_1 = -2 (eigenvalues -2, -1, ...), a saddle at z_1 = -1 (+1, -1, ...).
- ``hopf_field(a)``: r' = -r (r - a)(r - 2a), theta' = 1 (radians per second): the goal a sink, a
  repelling circle r = a, an attracting one r = 2a of period 2 pi.
- ``bistable_node(demos)``: a NODE (a model file can hold it) with f_n(u, v) = (-tanh(4u) - tanh(4(u + 1))
  + c tanh(4(u + 0.5)), -tanh(4v)), c = tanh(4) / tanh(2): sinks at u = 0 (the goal) and u = -1, a saddle
  at u = -0.5, in normalised units.
"""

from __future__ import annotations

import math

import numpy as np
import torch

import lfd
from lfd.field import VelocityField
from lfd.normalization import Normalization


class Bistable(torch.nn.Module):
    def forward(self, z: torch.Tensor) -> torch.Tensor:
        u = z[:, :1] + 1.0
        return torch.cat([u - u ** 3, -z[:, 1:]], dim=1)


class Hopf(torch.nn.Module):
    def __init__(self, a: float) -> None:
        super().__init__()
        self.a = a

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        r = torch.linalg.vector_norm(z, dim=1, keepdim=True)
        rdot = -(r - self.a) * (r - 2 * self.a)                  # r' / r
        turn = torch.stack([-z[:, 1], z[:, 0]], dim=1)
        return rdot * z + turn


def bistable_field(dim: int = 2) -> VelocityField:
    """``Bistable`` in user units = normalised units, goal at the origin."""
    return VelocityField(Bistable(), Normalization(goal=np.zeros(dim), scale=1.0), "hand", {},
                         {"loss": [1.0, 0.5, 0.2]})


def hopf_field(a: float = 1.0) -> VelocityField:
    """``Hopf`` with its circles at r = a (repelling) and r = 2a (attracting), goal at the origin."""
    return VelocityField(Hopf(a), Normalization(goal=np.zeros(2), scale=1.0), "hand", {})


C = math.tanh(4.0) / math.tanh(2.0)


def bistable_node(demos: lfd.DemoSet) -> VelocityField:
    """A 2-D NODE (one iteration of training, then the weights of the module docstring) on ``demos``'
    normalisation: its spurious sink is at goal + scale (-1, 0), its saddle at goal + scale (-0.5, 0)."""
    field = lfd.train("node", demos, seed=0, progress=False, iterations=1, hidden=(4,))
    first, last = field.module.linears()
    with torch.no_grad():
        first.weight.copy_(torch.tensor([[4.0, 0.0], [4.0, 0.0], [4.0, 0.0], [0.0, 4.0]]))
        first.bias.copy_(torch.tensor([0.0, 4.0, 2.0, 0.0]))
        last.weight.copy_(torch.tensor([[-1.0, -1.0, C, 0.0], [0.0, 0.0, 0.0, -1.0]]))
        last.bias.zero_()
    field.__dict__.pop("_point", None)
    return field
