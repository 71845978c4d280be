"""Normalisation: goal to the origin, data into the unit box.

x_n = (x - goal) / s and v_n = v / s, with one scalar s = max |x - goal| over all demos,
so every demo lies in [-1, 1]^d. A scalar (isotropic) scale keeps angles and the
contraction geometry intact; time is not rescaled, so rates stay in 1/s of user time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class Normalization:
    """Affine map between user units and the learner's unit box.

    goal : array, shape (d,)  -- the attractor in user units
    scale : float             -- user units per normalised unit
    """

    goal: np.ndarray
    scale: float

    @classmethod
    def from_points(cls, x: np.ndarray, goal: np.ndarray) -> Normalization:
        """x : array, shape (..., d); goal : array, shape (d,)."""
        goal = np.asarray(goal, dtype=np.float64)
        s = float(np.max(np.abs(np.asarray(x) - goal)))
        return cls(goal=goal, scale=s if s > 0 else 1.0)

    @property
    def dim(self) -> int:
        return int(self.goal.shape[0])

    def to_norm(self, x: np.ndarray) -> np.ndarray:
        """x_n = (x - goal) / s, shape preserved."""
        return (np.asarray(x, dtype=np.float64) - self.goal) / self.scale

    def from_norm(self, x_n: np.ndarray) -> np.ndarray:
        """x = s x_n + goal, shape preserved."""
        return np.asarray(x_n) * self.scale + self.goal

    def to_norm_torch(self, x: torch.Tensor) -> torch.Tensor:
        return (x - torch.as_tensor(self.goal, dtype=x.dtype)) / self.scale

    def from_norm_torch(self, x_n: torch.Tensor) -> torch.Tensor:
        return x_n * self.scale + torch.as_tensor(self.goal, dtype=x_n.dtype)

    def to_dict(self) -> dict:
        return {"goal": [float(g) for g in self.goal], "scale": float(self.scale)}

    @classmethod
    def from_dict(cls, d: dict) -> Normalization:
        return cls(goal=np.asarray(d["goal"], dtype=np.float64), scale=float(d["scale"]))
