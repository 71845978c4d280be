"""Where a task sits on an arm: the measured tool pose -> the task point, a task velocity -> the tool twist.

A task point x (d,) of a learned field lives in the demos' frame and units. A ``TaskFrame`` places it
in the world as p = o + s A x (Eqs. (S1)-(S2) of docs/equations.md: origin o (3,), orthonormal
axes A (3, d), scale s), and maps the field's velocity v (d,) to the tool twist [s A v; w]:

* a 2-D task on a spatial arm adds a pull back onto the task plane, -k_n n (n . p - n . o);
* a position task with a held tool orientation R_ref turns the tool toward it,
  w = k_r log(R_ref R^T);
* a pose task's point is a chart point z (6,) of the tool pose (``chart``, ``lfd.pose``, Eq. (P1)),
  and its velocity z_dot gives the whole twist (Eq. (P3)), turned into the world by A and R_w.

It is plain geometry (numpy and Pinocchio's SO(3) log): ``robots.controller.ArmController`` uses it
on a machine without MuJoCo, and ``sim.scene.placement.Placement.task_frame`` builds one for a run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import pinocchio as pin


class Chart(Protocol):
    """A pose task's chart (``lfd.pose.PoseChart``): z (6,) of a tool position x (3,) and rotation
    R (3, 3), both in the task frame (Eq. (P1)), and the twist (6,) of a chart velocity (Eq. (P3))."""

    def point(self, x: np.ndarray, rot: np.ndarray) -> np.ndarray: ...

    def twist(self, z: np.ndarray, zdot: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class TaskFrame:
    """The placement of a task on an arm (module docstring).

    Attributes
    ----------
    origin : ndarray, shape (3,)
        o, world, m.
    axes : ndarray, shape (3, d)
        A, orthonormal columns (d = 3 on a pose task).
    scale : float
        s, m per task unit.
    rotation : ndarray, shape (3, 3)
        R_w, the task frame's rotation in the world (a pose task's chart is in the task frame).
    chart : Chart or None
        A pose task's chart; None on a position task.
    rotation_ref : ndarray, shape (3, 3), or None
        R_ref, the tool orientation a position task holds (None: not held).
    plane_gain, rotation_gain : float
        k_n and k_r, 1/s.
    """

    origin: np.ndarray
    axes: np.ndarray
    scale: float
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    chart: Chart | None = None
    rotation_ref: np.ndarray | None = None
    plane_gain: float = 20.0
    rotation_gain: float = 10.0
    _At_s: np.ndarray = field(init=False, repr=False, compare=False)
    _sA: np.ndarray = field(init=False, repr=False, compare=False)
    _normal: np.ndarray = field(init=False, repr=False, compare=False)
    _kn_n: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        axes = np.asarray(self.axes, dtype=np.float64)
        if axes.ndim != 2 or axes.shape[0] != 3 or not 1 <= axes.shape[1] <= 3 or not np.isfinite(axes).all():
            raise ValueError(f"axes must be a finite (3, d) array, d <= 3, got shape {axes.shape}")
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be a positive number, got {self.scale}")
        object.__setattr__(self, "axes", axes)
        object.__setattr__(self, "origin", np.asarray(self.origin, dtype=np.float64).reshape(3))
        object.__setattr__(self, "rotation", np.asarray(self.rotation, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "_At_s", axes.T / self.scale)
        object.__setattr__(self, "_sA", self.scale * axes)
        normal = np.cross(axes[:, 0], axes[:, 1]) if axes.shape[1] == 2 else np.zeros(3)
        object.__setattr__(self, "_kn_n", self.plane_gain * normal)
        object.__setattr__(self, "_normal", normal)

    @property
    def dim(self) -> int:
        """d: the task's dimension (6 on a pose task)."""
        return 6 if self.chart is not None else self.axes.shape[1]

    def point(self, p: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """The task point, shape (d,), of the tool pose p (3,), rot (3, 3), world."""
        x = self._At_s.dot(p - self.origin)
        if self.chart is None:
            return x
        return self.chart.point(x, self.rotation.T.dot(rot))

    def twist(self, x: np.ndarray, v: np.ndarray, p: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """The tool twist [v; w], shape (6,), world, for the task velocity v (d,) at the task point x
        (d,) of the tool pose p (3,), rot (3, 3) (module docstring)."""
        sA = self._sA
        if self.chart is not None:
            tw = np.array(self.chart.twist(x, v), dtype=np.float64)
            tw[:3] = sA.dot(tw[:3])
            tw[3:] = self.rotation.dot(tw[3:])
            return tw
        tw = np.zeros(6)
        tw[:3] = sA.dot(v)
        if self.axes.shape[1] == 2:
            tw[:3] -= self._kn_n * self._normal.dot(p - self.origin)
        if self.rotation_ref is not None:
            tw[3:] = self.rotation_gain * pin.log3(self.rotation_ref.dot(rot.T))
        return tw
