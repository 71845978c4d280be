"""Obstacle shapes in task space: ``Sphere``, ``Box`` (axis-aligned) and ``Capsule``, static or moving.

Each shape is a closed convex set grown by a clearance ``margin``, described by its distance-based
Gamma function

.. math::

    \\Gamma(x) = 1 + \\mathrm{sdf}(x) / \\ell

with sdf the signed distance to the grown shape and :math:`\\ell` the radius of its bounding sphere
(for a sphere this is the :math:`\\lVert x - c \\rVert / R` of Khansari-Zadeh and Billard, 2012):
Gamma > 1 outside, 1 on the surface, < 1 inside. It is C1 everywhere outside: a box grown by a
margin is a rounded box. The outward normal is n = grad Gamma / |grad Gamma|; each shape also has a
reference point inside it (the modulation's x_ref, ``lfd.obstacles.avoidance``). A moving obstacle
is displaced by ``velocity * t`` or by a ``path(t)``.

Every shape gives its geometry twice: batched numpy (``sdf``) and one point as plain floats
(``point_sdf3``, the control-loop path, padded to 3-D): the helpers of ``lfd.obstacles._point_kernel``
applied to the shape's ``point_numbers``, the arithmetic the compiled kernel inlines.
"""

from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import Any, ClassVar

import numpy as np

from lfd.errors import ConfigError
from lfd.obstacles._point_kernel import EPS, Point4, box_sdf, capsule_sdf, pad3, sphere_sdf

__all__ = ["Obstacle", "Sphere", "Box", "Capsule"]


def _vec(name: str, value: Any, dim: int | None = None) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.size not in (2, 3) or (dim is not None and a.size != dim) or not np.all(np.isfinite(a)):
        want = f"{dim}" if dim is not None else "2 or 3"
        raise ConfigError(f"obstacle {name} must be {want} finite numbers, got {np.asarray(value).tolist()}")
    return a


@dataclass(eq=False, repr=False, kw_only=True)
class Obstacle(ABC):
    """Base of the obstacle shapes: a closed convex set in task space, static or moving.

    Parameters
    ----------
    margin : float
        Clearance [user units] added around the shape: the avoided set is the shape grown by it.
    velocity : array, shape (d,), optional
        Constant velocity [units/s]: the obstacle is at ``position + velocity * t``.
    path : callable t -> array, shape (d,), optional
        Displacement of the obstacle at time t from its position at t = 0 (``path(0)`` should be
        zero); its velocity is taken by a central difference. Exclusive with ``velocity``.
    reference : array, shape (d,), optional
        Reference point at t = 0, inside the shape (default: its centre).

    Subclasses: ``Sphere``, ``Box`` (axis-aligned) and ``Capsule`` (a cylinder with round caps);
    build them with ``Obstacle.sphere``, ``Obstacle.box``, ``Obstacle.capsule`` or ``parse_obstacle``.
    """

    margin: float = 0.0
    velocity: Any = None
    path: Callable[[float], Any] | None = None
    reference: Any = None
    kind: str = dc_field(default="obstacle", init=False)
    #: the shape's plain-float distance of ``lfd.obstacles._point_kernel``: (numbers..., y0, y1, y2) -> (sdf, n (3))
    point_sdf: ClassVar[Callable[..., Point4]]

    # ---- construction
    def _finish(self, dim: int) -> None:
        """Check the common parameters of a shape of dimension ``dim``; ``kind`` is the class name."""
        self.kind = type(self).__name__.lower()
        if not (math.isfinite(self.margin) and self.margin >= 0):
            raise ConfigError(f"obstacle margin must be a finite number >= 0, got {self.margin}")
        if self.velocity is not None and self.path is not None:
            raise ConfigError("give an obstacle either a velocity or a path, not both")
        if self.velocity is not None:
            self.velocity = _vec("velocity", self.velocity, dim)
        if self.path is not None and not callable(self.path):
            raise ConfigError("obstacle path must be a function of time t -> displacement (d,)")
        ref = self._center() if self.reference is None else _vec("reference", self.reference, dim)
        self.reference = ref
        if 1.0 + float(self.sdf(ref[None])[0][0]) / self.size >= 1.0:   # in the obstacle's frame
            raise ConfigError(f"the reference point {ref.tolist()} is not inside the {self.describe()}")

    @staticmethod
    def sphere(center: Sequence[float], radius: float, **kw: Any) -> Sphere:
        """A ball (a disc in 2-D); see ``Sphere``."""
        return Sphere(center, radius, **kw)

    @staticmethod
    def box(center: Sequence[float], half_sizes: Sequence[float], **kw: Any) -> Box:
        """An axis-aligned box; see ``Box``."""
        return Box(center, half_sizes, **kw)

    @staticmethod
    def capsule(a: Sequence[float], b: Sequence[float], radius: float, **kw: Any) -> Capsule:
        """The points within ``radius`` of the segment ab; see ``Capsule``."""
        return Capsule(a, b, radius, **kw)

    # ---- shape (in the obstacle's frame at t = 0); subclasses implement these
    @property
    def dim(self) -> int:
        return int(self._center().size)

    @abstractmethod
    def _center(self) -> np.ndarray:
        """The shape's centre, shape (d,), at t = 0."""

    @property
    @abstractmethod
    def size(self) -> float:
        """l: radius [units] of the bounding sphere of the grown shape, Gamma's length scale."""

    @abstractmethod
    def sdf(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance to the grown shape and its outward normal, in the frame at t = 0.

        Parameters
        ----------
        y : ndarray, shape (B, d)
            Points in the obstacle's frame at t = 0 (a moving obstacle's offset already taken off).

        Returns
        -------
        sdf : ndarray, shape (B,)
            Signed distance to the grown shape: > 0 outside, 0 on the surface, < 0 inside.
        normal : ndarray, shape (B, d)
            Outward unit normal.
        """

    @abstractmethod
    def point_numbers(self) -> list[float]:
        """The shape's numbers as its ``point_sdf`` takes them before the point, padded to 3-D (packed
        for the compiled kernel too)."""

    def point_sdf3(self) -> Callable[[float, float, float], Point4]:
        """``sdf`` for one point as plain floats, padded to 3-D (a 2-D shape has z = 0).

        Returns
        -------
        callable
            (y0, y1, y2) -> (sdf, n0, n1, n2): the control-loop path, no arrays.
        """
        return functools.partial(self.point_sdf, *self.point_numbers())

    @abstractmethod
    def describe(self) -> str:
        """One line naming the shape, its numbers and margin."""

    # ---- motion
    @property
    def moving(self) -> bool:
        return self.velocity is not None or self.path is not None

    def offset(self, t: float) -> np.ndarray:
        """Displacement, shape (d,), of the obstacle at time t from its pose at t = 0."""
        if self.velocity is not None:
            return self.velocity * float(t)
        if self.path is not None:
            return np.asarray(self.path(float(t)), dtype=np.float64).reshape(self.dim)
        return np.zeros(self.dim)

    def offset_velocity(self, t: float, h: float = 1e-4) -> np.ndarray:
        """Velocity, shape (d,), of the obstacle at time t [units/s]."""
        if self.velocity is not None:
            return self.velocity
        if self.path is not None:
            return (self.offset(t + h) - self.offset(t - h)) / (2 * h)
        return np.zeros(self.dim)

    def reference_point(self, t: float = 0.0) -> np.ndarray:
        """The reference point x_ref, shape (d,), at time t."""
        return self.reference + self.offset(t) if self.moving else self.reference

    # ---- public geometry
    def gamma(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Gamma(x) = 1 + sdf(x)/l: > 1 outside, 1 on the surface, < 1 inside (always > 0).

        x : array, shape (..., d); returns shape (...).
        """
        x = np.asarray(x, dtype=np.float64)
        y = x.reshape(-1, self.dim) - (self.offset(t) if self.moving else 0.0)
        sdf, _ = self.sdf(y)
        return (1.0 + sdf / self.size).reshape(x.shape[:-1])

    def normal(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Outward unit normal n = grad Gamma / |grad Gamma|, shape (..., d), of x : (..., d)."""
        x = np.asarray(x, dtype=np.float64)
        y = x.reshape(-1, self.dim) - (self.offset(t) if self.moving else 0.0)
        return self.sdf(y)[1].reshape(x.shape)

    def surface_points(self, n: int = 256, seed: int = 0) -> np.ndarray:
        """n points, shape (n, d), on the surface Gamma = 1 at t = 0: bisection along random rays
        from the reference point (the grown shape is convex, so each ray crosses it once)."""
        rng = np.random.default_rng(seed)
        u = rng.normal(size=(n, self.dim))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        lo, hi = np.zeros(n), np.full(n, 2.0 * (self.size + np.linalg.norm(self.reference - self._center())))
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            inside = self.gamma(self.reference + mid[:, None] * u) < 1.0
            lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
        return self.reference + (0.5 * (lo + hi))[:, None] * u

    def __repr__(self) -> str:
        motion = ", moving" if self.moving else ""
        return f"{type(self).__name__}({self.describe()}{motion})"

    def _margin_text(self) -> str:
        """`` margin M`` for ``describe``, empty without a margin."""
        return f" margin {self.margin:g}" if self.margin else ""


def _check_radius(kind: str, radius: float) -> None:
    """ConfigError unless a shape's radius is a finite number > 0."""
    if not (math.isfinite(radius) and radius > 0):
        raise ConfigError(f"{kind} radius must be a finite number > 0, got {radius}")


def _fmt(a: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:g}" for v in a) + ")"


@dataclass(eq=False, repr=False)
class _CentredObstacle(Obstacle):
    """A shape placed by its centre ``center``, shape (d,), d = 2 or 3 (``Sphere``, ``Box``)."""

    center: Any = None

    def _center(self) -> np.ndarray:
        return self.center


@dataclass(eq=False, repr=False)
class Sphere(_CentredObstacle):
    """A ball of ``radius`` around ``center`` (shape (d,), d = 2 or 3): Gamma = |x - c| / (r + margin)."""

    radius: float = 0.0

    def __post_init__(self) -> None:
        self.center = _vec("centre", self.center)
        _check_radius("sphere", self.radius)
        self._finish(self.center.size)

    @property
    def size(self) -> float:
        return float(self.radius + self.margin)

    def sdf(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = y - self.center                                   # (B, d)
        dist = np.linalg.norm(q, axis=1)                      # (B,)
        n = q / np.maximum(dist, EPS)[:, None]
        n[dist < EPS] = np.eye(self.dim)[0]
        return dist - self.size, n

    point_sdf = staticmethod(sphere_sdf)

    def point_numbers(self) -> list[float]:
        """c (3), R = radius + margin (``sphere_sdf``)."""
        return [*pad3(self.center), self.size]

    def describe(self) -> str:
        return f"sphere at {_fmt(self.center)} radius {self.radius:g}{self._margin_text()}"


@dataclass(eq=False, repr=False)
class Box(_CentredObstacle):
    """An axis-aligned box, ``center`` and ``half_sizes`` (shape (d,) each), grown by the margin
    into a rounded box (edges and corners rounded with radius ``margin``)."""

    half_sizes: Any = None

    def __post_init__(self) -> None:
        self.center = _vec("centre", self.center)
        self.half_sizes = _vec("half sizes", self.half_sizes, self.center.size)
        if np.any(self.half_sizes <= 0):
            raise ConfigError(f"box half sizes must be > 0, got {self.half_sizes.tolist()}")
        self._finish(self.center.size)

    @property
    def size(self) -> float:
        return float(np.linalg.norm(self.half_sizes) + self.margin)

    def sdf(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = y - self.center                                   # (B, d)
        a = np.abs(q) - self.half_sizes                       # (B, d) distance past each face pair
        o = np.maximum(a, 0.0)
        out = np.linalg.norm(o, axis=1)                       # (B,) distance outside the box
        inside = np.minimum(a.max(axis=1), 0.0)               # (B,) <= 0 inside
        sgn = np.where(q >= 0, 1.0, -1.0)
        n_out = sgn * o / np.maximum(out, EPS)[:, None]
        n_in = sgn * np.eye(self.dim)[np.argmax(a, axis=1)]
        n = np.where((out > 0)[:, None], n_out, n_in)
        return out + inside - self.margin, n

    point_sdf = staticmethod(box_sdf)

    def point_numbers(self) -> list[float]:
        """c (3), the margin, h (3) (``box_sdf``; a 2-D box is a prism of infinite height)."""
        return [*pad3(self.center), float(self.margin), *pad3(self.half_sizes, 1e300)]

    def describe(self) -> str:
        return f"box at {_fmt(self.center)} half sizes {_fmt(self.half_sizes)}{self._margin_text()}"


@dataclass(eq=False, repr=False)
class Capsule(Obstacle):
    """The points within ``radius`` of the segment from ``a`` to ``b`` (shape (d,) each): a cylinder
    with hemispherical caps (use it for cylinders; the caps add ``radius`` at each end)."""

    a: Any = None
    b: Any = None
    radius: float = 0.0

    def __post_init__(self) -> None:
        self.a = _vec("end point", self.a)
        self.b = _vec("end point", self.b, self.a.size)
        _check_radius("capsule", self.radius)
        self._finish(self.a.size)

    def _center(self) -> np.ndarray:
        return 0.5 * (self.a + self.b)

    @property
    def size(self) -> float:
        return float(0.5 * np.linalg.norm(self.b - self.a) + self.radius + self.margin)

    def sdf(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ab = self.b - self.a
        s = np.clip((y - self.a) @ ab / max(float(ab @ ab), EPS), 0.0, 1.0)   # (B,)
        q = y - (self.a + s[:, None] * ab)                                      # (B, d)
        dist = np.linalg.norm(q, axis=1)
        n = q / np.maximum(dist, EPS)[:, None]
        if np.any(dist < EPS):  # on the axis: any direction orthogonal to it
            perp = np.eye(self.dim)[int(np.argmin(np.abs(ab)))]
            perp = perp - (perp @ ab) / max(float(ab @ ab), EPS) * ab
            n[dist < EPS] = perp / np.linalg.norm(perp)
        return dist - (self.radius + self.margin), n

    point_sdf = staticmethod(capsule_sdf)

    def point_numbers(self) -> list[float]:
        """a (3), b - a (3), max(|b - a|^2, ``EPS``), radius + margin, the normal chosen on the axis (3)
        (``capsule_sdf``)."""
        b = pad3(self.b - self.a)
        return [*pad3(self.a), *b, max(b[0] * b[0] + b[1] * b[1] + b[2] * b[2], EPS),
                float(self.radius + self.margin), *pad3(self.sdf(self._center()[None])[1][0])]

    def describe(self) -> str:
        return f"capsule from {_fmt(self.a)} to {_fmt(self.b)} radius {self.radius:g}{self._margin_text()}"
