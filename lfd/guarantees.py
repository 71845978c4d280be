"""What a learned field states about its own contraction, for ``lfd.certify`` and
``lfd.pose_contraction`` to check: ``Guarantees``, the defaults of every ``lfd.field.VelocityField``
(nothing stated). A learner that states more overrides them: ``lfd.field.ContractingField`` (a rate,
metric bounds and a Lipschitz bound), the contraction learners' fields (their metric, Eq. (C1), the
theorem's conditions read from the weights, and the goal contraction's flow in closed form, Eq. (C4)),
the NODE's (a bound of Lip(J_f) from its weights) and the stable NODE's (a Lyapunov function and its
constants, Eqs. (L1)-(L3))."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from torch import Tensor

__all__ = ["Guarantees"]


class Guarantees:
    """Nothing stated: each answer is None (``lfd.certify`` then checks the identity metric at its own
    rate, and rollouts integrate)."""

    @property
    def rate(self) -> float | None:
        """The contraction rate the field is built with, 1/s; None: none."""
        return None

    @property
    def metric_bounds(self) -> tuple[float, float] | None:
        """(a, b) with a I <= M(x) <= b I for every x in R^d, user units; None: no metric stated."""
        return None

    @property
    def lipschitz_bound(self) -> float | None:
        """An upper bound of the field's Lipschitz constant in x, 1/s; None: none stated."""
        return None

    def contraction_metric(self) -> Callable[[Tensor], Tensor] | None:
        """M_n: x_n (B, d) -> (B, d, d), the metric the field is built to contract in (normalised units,
        differentiable; ``lfd.certify`` checks Eq. (C1) in it); None: none (the identity is checked)."""
        return None

    def theorem_conditions(self) -> dict[str, Any] | None:
        """The conditions of the theorem the field is built on, read from its weights (keys ``holds`` and
        the values checked; ``lfd.certify`` reports them and refuses a field where they fail); None: none."""
        return None

    def jacobian_lipschitz_bound(self) -> float | None:
        """An upper bound of Lip(J_f) from the weights; None: none known."""
        return None

    def stability_constants(self) -> dict[str, Any] | None:
        """The analytic constants of a Lyapunov function the field is built to decrease (keys ``holds``,
        ``rate``, ``alpha``, ``s_lo``, ``s_hi``, ``overshoot``; ``lfd.stability`` checks them); None: none."""
        return None

    def lyapunov(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """V(x), dV/dt along the field and the rate alpha(V) with dV/dt <= -alpha(V) V stated, each of
        shape x.shape[:-1], at x of shape (..., d) in user units; None: no Lyapunov function stated."""
        return None

    def closed_form_rollout(self, x0: np.ndarray, t: np.ndarray) -> np.ndarray | None:
        """The exact flow from x0, shape (B, d), over t, shape (T,): (B, T, d) where the learner has it
        in closed form; None: integrate instead (``rollout``)."""
        return None
