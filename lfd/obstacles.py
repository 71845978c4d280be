"""Obstacle avoidance for any velocity field by dynamical-system modulation [1]_.

A field f (a ``VelocityField`` or a time-varying field such as ``lfd.goal.MovingGoalField``) is
wrapped so that trajectories go around obstacles and still reach the goal:

.. math::

    \\dot x = M(x)\\,\\big(f(x) - \\dot x_o\\big) + \\dot x_o, \\qquad
    M(x) = E(x)\\,D(x)\\,E(x)^{-1}

([1]_'s modulation of a static obstacle, and its moving-obstacle form with the obstacle
velocity :math:`\\dot x_o`; :math:`\\dot x_o = 0` for static ones). E has the reference direction
:math:`r = (x - x_{ref}) / \\lVert x - x_{ref} \\rVert` (a reference point inside the obstacle, as in
[2]_) as its first column and d-1 tangents orthogonal to the normal :math:`n = \\nabla\\Gamma` as the
others; D = diag(1 - 1/Gamma, 1 + 1/Gamma, ...) as in [1]_. With the decomposition
:math:`f = a\\,r + t`, :math:`a = n^\\top f / n^\\top r`, :math:`t \\perp n`, this is simply
:math:`M f = \\lambda_r a r + \\lambda_t t`, O(d) flops and no matrix inverse.

What is preserved (each checked numerically in ``tests/test_obstacles.py``):

- **impenetrability:** on the surface Gamma = 1, lambda_r = 0 and the velocity is tangent, so a
  trajectory that starts outside never enters (proved in [1]_);
- **the goal** remains an equilibrium (f = 0 there, so M f = 0), and for convex obstacles every
  trajectory of a globally stable f still reaches it, except those on the stable manifold of a
  saddle point on the obstacle's far side ([1]_): no new attractor appears;
- **the tail effect** is removed: when f points away from the obstacle (a >= 0) lambda_r = 1, so
  the flow behind an obstacle is not bent back towards it (as in [2]_); the switch is continuous
  because it happens where a = 0.

Several obstacles are combined with the weighted product of [1]_:
:math:`M = \\prod_k M^k` with :math:`\\lambda^k = 1 \\mp w_k/\\Gamma_k` and
:math:`w_k = \\prod_{i \\ne k} (\\Gamma_i - 1) / ((\\Gamma_k - 1) + (\\Gamma_i - 1))`, and the obstacle
velocity :math:`\\dot x_o = \\sum_k w_k \\dot x_o^k`. Obstacles that overlap are merged into one
(their union is star-shaped about a common interior point, the reference point of [2]_) with the
smooth minimum :math:`\\Gamma = (\\sum_k \\Gamma_k^{-p})^{-1/p} \\le \\min_k \\Gamma_k`, whose
surface encloses the union and rounds its concave creases.

Gamma is distance-based: :math:`\\Gamma = 1 + \\mathrm{sdf}(x) / \\ell`, with sdf the signed distance to
the obstacle grown by its margin and :math:`\\ell` the radius of its bounding sphere (for a sphere
this is the paper's :math:`\\lVert x - c \\rVert / R`). It is C1 everywhere outside: a box grown by a
margin is a rounded box.

References
----------
.. [1] S. M. Khansari-Zadeh and A. Billard, "A dynamical system approach to realtime obstacle
   avoidance", Autonomous Robots 32(4), 433-454, 2012. doi:10.1007/s10514-012-9287-y
.. [2] L. Huber, A. Billard and J.-J. Slotine, "Avoidance of convex and concave obstacles with
   convergence ensured through contraction", IEEE Robotics and Automation Letters 4(2),
   1462-1469, 2019.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import Any

import numpy as np

from lfd.errors import ConfigError
from lfd.field import FieldWrapper, cached_single_point_evaluator, is_time_varying
from lfd.integrate import rk4_step

__all__ = ["Obstacle", "Sphere", "Box", "Capsule", "AvoidingField", "avoid", "parse_obstacle", "starts_outside"]

_EPS = 1e-12
#: exponent p of the smooth minimum that merges overlapping obstacles
MERGE_POWER = 8.0
#: default rho of the eigenvalues 1 -+ 1/Gamma^(1/rho) (see ``AvoidingField``)
REACTIVITY = 0.5
#: the goal must have Gamma >= this (1% of the obstacle's size outside its surface)
MIN_GOAL_GAMMA = 1.01


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
        if 1.0 + float(self._sdf(ref[None])[0][0]) / self.size >= 1.0:   # in the obstacle's frame
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
    def _sdf(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance to the grown shape, shape (B,), and outward normal, shape (B, d), of
        the points y, shape (B, d), in the frame at t = 0."""

    @abstractmethod
    def _point_sdf3(self) -> Callable[[float, float, float], tuple[float, float, float, float]]:
        """The same for one point as plain floats, (y0, y1, y2) -> (sdf, n0, n1, n2): the
        control-loop path, written out for 3-D (a 2-D shape is padded with z = 0)."""

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
        sdf, _ = self._sdf(y)
        return (1.0 + sdf / self.size).reshape(x.shape[:-1])

    def normal(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Outward unit normal n = grad Gamma / |grad Gamma|, shape (..., d), of x : (..., d)."""
        x = np.asarray(x, dtype=np.float64)
        y = x.reshape(-1, self.dim) - (self.offset(t) if self.moving else 0.0)
        return self._sdf(y)[1].reshape(x.shape)

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


def _mover_velocity(movers: Sequence[tuple[int, Obstacle]], w: Sequence[float], t: float
                    ) -> tuple[float, float, float]:
    """The weighted velocity sum_k w_k u_k(t) of the moving obstacles, (k, obstacle) pairs, as
    three floats (z = 0 in 2-D): the single-point path's frame velocity."""
    u0 = u1 = u2 = 0.0
    for k, o in movers:
        o0, o1, o2 = _pad3(o.offset_velocity(t))
        u0, u1, u2 = u0 + w[k] * o0, u1 + w[k] * o1, u2 + w[k] * o2
    return u0, u1, u2


def _check_radius(kind: str, radius: float) -> None:
    """ConfigError unless a shape's radius is a finite number > 0."""
    if not (math.isfinite(radius) and radius > 0):
        raise ConfigError(f"{kind} radius must be a finite number > 0, got {radius}")


def _pad3(a: np.ndarray, fill: float = 0.0) -> tuple[float, float, float]:
    """A 2- or 3-vector as three floats, z = ``fill`` for 2-D."""
    v = [float(x) for x in a]
    return (v[0], v[1], v[2] if len(v) == 3 else fill)


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

    def _sdf(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = y - self.center                                   # (B, d)
        dist = np.linalg.norm(q, axis=1)                      # (B,)
        n = q / np.maximum(dist, _EPS)[:, None]
        n[dist < _EPS] = np.eye(self.dim)[0]
        return dist - self.size, n

    def _point_sdf3(self) -> Callable[[float, float, float], tuple[float, float, float, float]]:
        (c0, c1, c2), R = _pad3(self.center), self.size

        def sdf(y0: float, y1: float, y2: float) -> tuple[float, float, float, float]:
            q0, q1, q2 = y0 - c0, y1 - c1, y2 - c2
            d = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
            if d < _EPS:
                return -R, 1.0, 0.0, 0.0
            return d - R, q0 / d, q1 / d, q2 / d
        return sdf

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

    def _sdf(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = y - self.center                                   # (B, d)
        a = np.abs(q) - self.half_sizes                       # (B, d) distance past each face pair
        o = np.maximum(a, 0.0)
        out = np.linalg.norm(o, axis=1)                       # (B,) distance outside the box
        inside = np.minimum(a.max(axis=1), 0.0)               # (B,) <= 0 inside
        sgn = np.where(q >= 0, 1.0, -1.0)
        n_out = sgn * o / np.maximum(out, _EPS)[:, None]
        n_in = sgn * np.eye(self.dim)[np.argmax(a, axis=1)]
        n = np.where((out > 0)[:, None], n_out, n_in)
        return out + inside - self.margin, n

    def _point_sdf3(self) -> Callable[[float, float, float], tuple[float, float, float, float]]:
        (c0, c1, c2), m = _pad3(self.center), float(self.margin)
        h0, h1, h2 = _pad3(self.half_sizes, 1e300)   # a 2-D box is a prism of infinite height
        cs = math.copysign

        def sdf(y0: float, y1: float, y2: float) -> tuple[float, float, float, float]:
            q0, q1, q2 = y0 - c0, y1 - c1, y2 - c2
            a0, a1, a2 = abs(q0) - h0, abs(q1) - h1, abs(q2) - h2
            o0 = a0 if a0 > 0.0 else 0.0
            o1 = a1 if a1 > 0.0 else 0.0
            o2 = a2 if a2 > 0.0 else 0.0
            out = o0 * o0 + o1 * o1 + o2 * o2
            if out > 0.0:
                out = math.sqrt(out)
                return out - m, cs(o0, q0) / out, cs(o1, q1) / out, cs(o2, q2) / out
            if a0 >= a1 and a0 >= a2:
                return a0 - m, cs(1.0, q0), 0.0, 0.0
            if a1 >= a2:
                return a1 - m, 0.0, cs(1.0, q1), 0.0
            return a2 - m, 0.0, 0.0, cs(1.0, q2)
        return sdf

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

    def _sdf(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ab = self.b - self.a
        s = np.clip((y - self.a) @ ab / max(float(ab @ ab), _EPS), 0.0, 1.0)   # (B,)
        q = y - (self.a + s[:, None] * ab)                                      # (B, d)
        dist = np.linalg.norm(q, axis=1)
        n = q / np.maximum(dist, _EPS)[:, None]
        if np.any(dist < _EPS):  # on the axis: any direction orthogonal to it
            perp = np.eye(self.dim)[int(np.argmin(np.abs(ab)))]
            perp = perp - (perp @ ab) / max(float(ab @ ab), _EPS) * ab
            n[dist < _EPS] = perp / np.linalg.norm(perp)
        return dist - (self.radius + self.margin), n

    def _point_sdf3(self) -> Callable[[float, float, float], tuple[float, float, float, float]]:
        a0, a1, a2 = _pad3(self.a)
        b0, b1, b2 = _pad3(self.b - self.a)
        ab2 = max(b0 * b0 + b1 * b1 + b2 * b2, _EPS)
        R = float(self.radius + self.margin)
        e0, e1, e2 = _pad3(self._sdf(self._center()[None])[1][0])   # normal on the axis

        def sdf(y0: float, y1: float, y2: float) -> tuple[float, float, float, float]:
            p0, p1, p2 = y0 - a0, y1 - a1, y2 - a2
            s = (p0 * b0 + p1 * b1 + p2 * b2) / ab2
            s = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
            q0, q1, q2 = p0 - s * b0, p1 - s * b1, p2 - s * b2
            d = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
            if d < _EPS:
                return -R, e0, e1, e2
            return d - R, q0 / d, q1 / d, q2 / d
        return sdf

    def describe(self) -> str:
        return f"capsule from {_fmt(self.a)} to {_fmt(self.b)} radius {self.radius:g}{self._margin_text()}"


# ---------------------------------------------------------------- parsing
_FORMS = "sphere:x,y[,z],r | box:x,y[,z],hx,hy[,hz] | capsule:x1,y1[,z1],x2,y2[,z2],r"
_COUNTS = {"sphere": {3: 2, 4: 3}, "box": {4: 2, 6: 3}, "capsule": {5: 2, 7: 3}}


def parse_obstacle(text: str, dim: int | None = None) -> Obstacle:
    """An obstacle from command-line text, in task units.

    ``sphere:x,y,z,r``, ``box:x,y,z,hx,hy,hz``, ``capsule:x1,y1,z1,x2,y2,z2,r`` (2-D forms with two
    coordinates per point), optionally followed by ``;margin=M`` and ``;velocity=vx,vy[,vz]``.
    Raises ``ConfigError`` (one line) on bad text, or when the dimension is not ``dim``.
    """
    def bad(why: str) -> ConfigError:
        return ConfigError(f"bad obstacle '{text[:80]}': {why} (use {_FORMS})")

    kind, sep, rest = str(text).strip().partition(":")
    kind = kind.strip().lower()
    if not sep or kind not in _COUNTS:
        raise bad(f"unknown shape '{kind[:20]}'" if sep else "missing 'shape:'")
    parts = rest.split(";")
    opts: dict[str, Any] = {}

    def numbers(s: str, what: str) -> list[float]:
        try:
            vals = [float(v) for v in s.split(",")]
        except ValueError:
            raise bad(f"{what} must be comma-separated numbers, got '{s[:40]}'") from None
        if not all(math.isfinite(v) for v in vals):
            raise bad(f"{what} must be finite numbers")
        return vals

    vals = numbers(parts[0], "the shape")
    for opt in parts[1:]:
        key, eq, value = opt.partition("=")
        key = key.strip().lower()
        if not eq or key not in ("margin", "velocity"):
            raise bad(f"unknown option '{opt[:30]}' (options: ;margin=M ;velocity=vx,vy[,vz])")
        v = numbers(value, key)
        if key == "margin":
            if len(v) != 1:
                raise bad("margin must be one number")
            opts["margin"] = v[0]
        else:
            opts["velocity"] = v
    d = _COUNTS[kind].get(len(vals))
    if d is None:
        want = " or ".join(str(k) for k in _COUNTS[kind])
        raise bad(f"{kind} takes {want} numbers, got {len(vals)}")
    if dim is not None and d != dim:
        raise bad(f"a {d}-D {kind} for a {dim}-D field")
    if "velocity" in opts and len(opts["velocity"]) != d:
        raise bad(f"velocity must have {d} numbers")
    try:
        if kind == "sphere":
            return Sphere(vals[:d], vals[d], **opts)
        if kind == "box":
            return Box(vals[:d], vals[d:], **opts)
        return Capsule(vals[:d], vals[d:2 * d], vals[2 * d], **opts)
    except ConfigError as e:
        raise bad(str(e)) from None


# ---------------------------------------------------------------- the modulated field
class _Unit:
    """One modulation unit: a single obstacle, or overlapping static obstacles merged by the smooth
    minimum of their Gammas around a common reference point."""

    def __init__(self, members: list[Obstacle], reference: np.ndarray) -> None:
        self.members = members
        self.reference = reference
        self.obstacle = members[0]
        self.moving = members[0].moving

    def describe(self) -> str:
        if len(self.members) == 1:
            return self.obstacle.describe()
        return "group of overlapping obstacles (" + "; ".join(o.describe() for o in self.members) + ")"

    def geometry(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Gamma (B,), normal (B, d) and reference direction (B, d) of x : (B, d) at time t."""
        off = self.obstacle.offset(t) if self.moving else 0.0
        y = x - off
        if len(self.members) == 1:
            o = self.obstacle
            sdf, n = o._sdf(y)
            g = 1.0 + sdf / o.size
        else:
            p = MERGE_POWER
            gs, grads = [], []
            for o in self.members:
                sdf, n_k = o._sdf(y)
                gs.append(np.maximum(1.0 + sdf / o.size, _EPS))
                grads.append(n_k / o.size)
            G = np.stack(gs)                                          # (K, B)
            g = np.sum(G ** -p, axis=0) ** (-1.0 / p)                 # (B,)
            wk = (g / G) ** (p + 1.0)                                 # (K, B)
            grad = np.einsum("kb,kbd->bd", wk, np.stack(grads))
            n = grad / np.maximum(np.linalg.norm(grad, axis=1), _EPS)[:, None]
        q = y - self.reference
        r = q / np.maximum(np.linalg.norm(q, axis=1), _EPS)[:, None]
        return g, n, r

    def point_geometry(self) -> Callable[[float, float, float, float],
                                         tuple[float, float, float, float, float, float, float]]:
        """The same for one point as plain floats, padded to 3-D:
        (x0, x1, x2, t) -> (Gamma, n0, n1, n2, r0, r1, r2)."""
        f0, f1, f2 = _pad3(self.reference)
        o = self.obstacle
        sqrt = math.sqrt
        if len(self.members) == 1:
            sdf, inv = o._point_sdf3(), 1.0 / o.size
        else:
            sdfs = [(m._point_sdf3(), 1.0 / m.size) for m in self.members]
            p = MERGE_POWER

            def sdf(y0: float, y1: float, y2: float) -> tuple[float, float, float, float]:
                acc, parts = 0.0, []
                for sdf_k, inv_k in sdfs:
                    s, a0, a1, a2 = sdf_k(y0, y1, y2)
                    g_k = max(1.0 + s * inv_k, _EPS)
                    acc += g_k ** -p
                    parts.append((g_k, a0, a1, a2, inv_k))
                g = acc ** (-1.0 / p)
                m0 = m1 = m2 = 0.0
                for g_k, a0, a1, a2, inv_k in parts:
                    w = (g / g_k) ** (p + 1.0) * inv_k
                    m0, m1, m2 = m0 + w * a0, m1 + w * a1, m2 + w * a2
                mn = sqrt(m0 * m0 + m1 * m1 + m2 * m2) or 1.0
                return g - 1.0, m0 / mn, m1 / mn, m2 / mn   # "sdf" in Gamma units: inv = 1
            inv = 1.0
        if not self.moving:
            def geom(x0: float, x1: float, x2: float, t: float
                     ) -> tuple[float, float, float, float, float, float, float]:
                s, n0, n1, n2 = sdf(x0, x1, x2)
                q0, q1, q2 = x0 - f0, x1 - f1, x2 - f2
                qn = sqrt(q0 * q0 + q1 * q1 + q2 * q2) or 1.0
                return 1.0 + s * inv, n0, n1, n2, q0 / qn, q1 / qn, q2 / qn
            return geom
        if o.velocity is not None:
            v0, v1, v2 = _pad3(o.velocity)

            def offset(t: float) -> tuple[float, float, float]:
                return v0 * t, v1 * t, v2 * t
        else:
            def offset(t: float) -> tuple[float, float, float]:
                return _pad3(o.offset(t))

        def geom_moving(x0: float, x1: float, x2: float, t: float
                        ) -> tuple[float, float, float, float, float, float, float]:
            d0, d1, d2 = offset(t)
            x0, x1, x2 = x0 - d0, x1 - d1, x2 - d2
            s, n0, n1, n2 = sdf(x0, x1, x2)
            q0, q1, q2 = x0 - f0, x1 - f1, x2 - f2
            qn = sqrt(q0 * q0 + q1 * q1 + q2 * q2) or 1.0
            return 1.0 + s * inv, n0, n1, n2, q0 / qn, q1 / qn, q2 / qn
        return geom_moving


def _group(obstacles: list[Obstacle]) -> list[_Unit]:
    """Merge overlapping obstacles (connected components of the overlap graph) into units with a
    common reference point: the point that minimises max_k Gamma_k (the deepest common point)."""
    n = len(obstacles)
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    surface = [o.surface_points(128) for o in obstacles]
    for i in range(n):
        for j in range(i + 1, n):
            oi, oj = obstacles[i], obstacles[j]
            overlap = (np.min(oi.gamma(surface[j])) < 1.0 or np.min(oj.gamma(surface[i])) < 1.0
                       or oi.gamma(oj.reference) < 1.0 or oj.gamma(oi.reference) < 1.0)
            if overlap:
                if oi.moving or oj.moving:
                    raise ConfigError(f"obstacles {i} ({oi.describe()}) and {j} ({oj.describe()}) overlap: "
                                      "overlapping obstacles must be static")
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    units = []
    for idx in groups.values():
        members = [obstacles[i] for i in idx]
        if len(members) == 1:
            units.append(_Unit(members, members[0].reference))
            continue
        from scipy.optimize import minimize

        def worst(p: np.ndarray) -> float:
            return max(float(o.gamma(p)) for o in members)  # noqa: B023 (only called in this iteration)

        start = np.mean([o.reference for o in members], axis=0)
        res = minimize(worst, start, method="Nelder-Mead",
                       options={"xatol": 1e-9 * max(o.size for o in members), "fatol": 1e-12, "maxiter": 4000})
        if worst(res.x) >= 1.0:
            raise ConfigError("obstacles " + ", ".join(str(i) for i in idx) + " overlap in a chain without a "
                              "common interior point: split them or make them overlap pairwise")
        units.append(_Unit(members, np.asarray(res.x, dtype=np.float64)))
    return units


def _kzb_weights(gammas: Sequence[float]) -> list[float]:
    """w_k = prod_{i != k} (Gamma_i - 1) / ((Gamma_k - 1) + (Gamma_i - 1)), the weights of [1]_
    (Gamma_i - 1 clipped at 0; a point on or inside an obstacle gives it the full weight)."""
    e = [g - 1.0 if g > 1.0 else 0.0 for g in gammas]
    if len(e) == 2:
        s = e[0] + e[1]
        return [e[1] / s, e[0] / s] if s > 0.0 else [0.5, 0.5]
    if len(e) == 3 and e[0] > 0.0 and e[1] > 0.0 and e[2] > 0.0:
        a, b, c = e
        ab, ac, bc = a + b, a + c, b + c
        return [b * c / (ab * ac), a * c / (ab * bc), a * b / (ac * bc)]
    w = []
    for k, ek in enumerate(e):
        prod = 1.0
        for i, ei in enumerate(e):
            if i != k:
                den = ek + ei
                prod *= ei / den if den > 0.0 else 0.5
        w.append(prod)
    return w


class AvoidingField(FieldWrapper):
    """A velocity field modulated to avoid obstacles [1]_ (see the module docstring for the math).

    Parameters
    ----------
    field : VelocityField or a time-varying field (``lfd.goal.MovingGoalField``)
        The nominal field f(x) (or f(x, t)) [units/s].
    obstacles : sequence of Obstacle
        In the field's dimension and units.
    reactivity : float
        rho > 0, the reactivity of [1]_: eigenvalues 1 -+ w / Gamma^(1/rho); larger reacts earlier.
        The default 0.5 makes a sphere's eigenvalues 1 -+ (R / |x - c|)^2, the paper's sphere
        Gamma = (|x - c| / R)^2 with rho = 1; measured on the spiral (linear fit, a sphere on its
        path), rho = 1 bends paths far from the obstacle: path-length overhead 39% vs 6% at 0.5.
    min_goal_gamma : float
        The goal must have Gamma >= this for every obstacle (default 1.01: 1% of the obstacle's
        size outside it), else ``ConfigError`` ("goal lies inside obstacle ...").

    Calls: ``field(x, t=0)`` with x of shape (d,) or (..., d); ``single_point_evaluator()`` for
    control loops; ``rollout(x0, t)``; ``gamma(x, t)`` the smallest Gamma over obstacles.

    References
    ----------
    .. [1] S. M. Khansari-Zadeh and A. Billard, "A dynamical system approach to realtime obstacle
       avoidance", Autonomous Robots 32(4), 433-454, 2012. doi:10.1007/s10514-012-9287-y
    """

    time_varying = True

    def __init__(self, field: Any, obstacles: Sequence[Obstacle], reactivity: float = REACTIVITY,
                 min_goal_gamma: float = MIN_GOAL_GAMMA) -> None:
        obs: list[Obstacle] = list(obstacles)
        if isinstance(field, AvoidingField):  # avoid(avoid(f, A), B) == avoid(f, A + B)
            obs = field.obstacles + obs
            field = field.field
        for i, o in enumerate(obs):
            if not isinstance(o, Obstacle):
                raise ConfigError(f"obstacle {i} is a {type(o).__name__}, not an lfd Obstacle")
            if o.dim != field.dim:
                raise ConfigError(f"obstacle {i} ({o.describe()}) is {o.dim}-D but the field is {field.dim}-D")
        if not (math.isfinite(reactivity) and reactivity > 0):
            raise ConfigError(f"reactivity must be > 0, got {reactivity}")
        self.field = field
        self.obstacles: list[Obstacle] = obs
        self.reactivity = float(reactivity)
        self._time_varying = is_time_varying(field)
        self.units = _group(obs)
        goals = np.atleast_2d(field.goal_samples() if hasattr(field, "goal_samples") else field.goal)
        for u in self.units:
            g = np.min(u.geometry(goals, 0.0)[0]) if not u.moving else float("inf")
            if g < min_goal_gamma:
                raise ConfigError(f"goal lies inside obstacle {u.describe()}" if g < 1.0 else
                                  f"goal lies inside obstacle {u.describe()}'s clearance: Gamma(goal) = "
                                  f"{g:.4f} < {min_goal_gamma} (move the goal or shrink the obstacle)")
            if u.moving:
                gm = float(u.obstacle.gamma(goals[0], 0.0))
                if gm < min_goal_gamma:
                    raise ConfigError(f"goal lies inside obstacle {u.describe()} at t = 0")

    @property
    def goal(self) -> np.ndarray:
        """The attractor, shape (d,), at t = 0."""
        return self.field.goal

    def avoiding(self, obstacles: Sequence[Obstacle], **kw: Any) -> AvoidingField:
        """This field with more obstacles."""
        return AvoidingField(self, obstacles, **kw)

    def gamma(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """min_k Gamma_k(x, t) over obstacles (merged groups count as one), shape (...) of x (..., d);
        < 1 means inside an obstacle."""
        x = np.asarray(x, dtype=np.float64)
        flat = x.reshape(-1, self.dim)
        if not self.units:
            return np.full(x.shape[:-1], np.inf)
        g = np.min([u.geometry(flat, t)[0] for u in self.units], axis=0)
        return g.reshape(x.shape[:-1])

    # ---- batched numpy path
    def modulate(self, x: np.ndarray, v: np.ndarray, t: float = 0.0) -> np.ndarray:
        """M(x) (v - xdot_o) + xdot_o for points x and nominal velocities v, shape (B, d) each."""
        if not self.units:
            return v
        geo = [u.geometry(x, t) for u in self.units]
        G = np.stack([g for g, _, _ in geo])                             # (K, B)
        E = np.maximum(G - 1.0, 0.0)
        K = len(self.units)
        if K == 1:
            W = np.ones_like(G)
        else:
            W = np.ones_like(G)
            for k in range(K):
                for i in range(K):
                    if i != k:
                        den = E[k] + E[i]
                        W[k] *= np.where(den > 0, E[i] / np.where(den > 0, den, 1.0), 0.5)
        vo = np.zeros_like(v)
        for k, u in enumerate(self.units):
            if u.moving:
                vo = vo + W[k][:, None] * u.obstacle.offset_velocity(t)
        f = v - vo
        for k, (g, n, r) in enumerate(geo):
            inv = W[k] / (np.maximum(g, _EPS) ** (1.0 / self.reactivity))      # (B,)
            nr = np.maximum(np.sum(n * r, axis=1), 1e-6)
            a = np.sum(n * f, axis=1) / nr                                     # (B,)
            tan = f - a[:, None] * r
            lam_r = np.where(a < 0.0, 1.0 - inv, 1.0)
            f = (lam_r * a)[:, None] * r + (1.0 + inv)[:, None] * tan
        return f + vo

    def __call__(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """dx/dt, same shape as x : array, shape (d,) or (..., d) [units/s], at time t [s]."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1] != self.dim:
            raise ValueError(f"field expects points of dimension {self.dim}, got shape {x.shape}")
        if x.ndim == 1:
            return cached_single_point_evaluator(self)(x, t)
        flat = x.reshape(-1, self.dim)
        v = self.field(flat, t) if self._time_varying else self.field(flat)
        return self.modulate(flat, np.asarray(v, dtype=np.float64), t).reshape(x.shape)

    def rollout(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1,
                max_refine: int = 6) -> np.ndarray:
        """Fixed-step RK4 from x0, shape (B, d) or (d,), over times t, shape (T,), with ``substeps``
        steps per interval. Returns shape (B, T, d) (or (T, d)).

        A step that would carry a start from outside into an obstacle (possible only through the
        integration error of a large step, near a sharp corner) is redone for those starts with
        2, 4, ... 2^max_refine sub-steps. ``method`` must be ``rk4`` (the only solver here)."""
        if method != "rk4":
            raise ConfigError(f"an obstacle-avoiding field integrates with rk4 only, not '{method}'")
        x = np.atleast_2d(np.asarray(x0, dtype=np.float64)).copy()
        t = np.asarray(t, dtype=np.float64)
        out = np.empty((x.shape[0], t.size, self.dim))
        out[:, 0] = x
        for j in range(t.size - 1):
            t0, t1 = float(t[j]), float(t[j + 1])
            new = self._rk4(x, t0, t1, substeps)
            outside = self.gamma(x, t0) >= 1.0
            bad = outside & (self.gamma(new, t1) < 1.0)
            level = 1
            while bad.any() and level <= max_refine:
                new[bad] = self._rk4(x[bad], t0, t1, substeps * 2 ** level)
                bad = outside & (self.gamma(new, t1) < 1.0)
                level += 1
            x = new
            out[:, j + 1] = x
        return out[0] if np.ndim(x0) == 1 else out

    def _rk4(self, x: np.ndarray, t0: float, t1: float, n: int) -> np.ndarray:
        """n classic RK4 steps (``lfd.integrate.rk4_step``) of the batch x, shape (B, d), from t0 to t1."""
        h = (t1 - t0) / n
        for s in range(n):
            x = rk4_step(self, x, t0 + s * h, h)
        return x

    # ---- single-point path
    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        """The fast path for one point, for control loops: ``field(x, t)`` on x of shape (d,) calls it.

        Plain floats inside (written out for 3-D; a 2-D point is padded with z = 0).
        ``scripts/bench_obstacles.py`` measures its extra cost over the nominal field's
        ``single_point_evaluator``.

        Returns
        -------
        callable
            (x, array of shape (d,), user units; t, float, s, default 0.0) -> dx/dt, array of
            shape (d,), user units.
        """
        base = self.field.single_point_evaluator()
        tv = self._time_varying
        geoms = [u.point_geometry() for u in self.units]
        movers = [(k, u.obstacle) for k, u in enumerate(self.units) if u.moving]
        inv_rho = 1.0 / self.reactivity
        square = inv_rho == 2.0
        two = self.dim == 2
        K = len(geoms)
        array = np.array

        def f(x: np.ndarray, t: float = 0.0) -> np.ndarray:
            v = base(x, t) if tv else base(x)
            if two:
                x0, x1 = x.tolist()
                v0, v1 = v.tolist()
                x2 = v2 = 0.0
            else:
                x0, x1, x2 = x.tolist()
                v0, v1, v2 = v.tolist()
            if K == 0:
                return array((v0, v1)) if two else array((v0, v1, v2))
            geo = [gm(x0, x1, x2, t) for gm in geoms]
            w: Sequence[float] = (1.0,) if K == 1 else _kzb_weights([gg[0] for gg in geo])
            if movers:
                u0, u1, u2 = _mover_velocity(movers, w, t)
                v0, v1, v2 = v0 - u0, v1 - u1, v2 - u2
            for k in range(K):
                g, n0, n1, n2, r0, r1, r2 = geo[k]
                wk = w[k]
                if wk == 0.0:
                    continue
                if g < _EPS:
                    g = _EPS
                inv = wk / (g * g) if square else (wk / g if inv_rho == 1.0 else wk / g ** inv_rho)
                nr = n0 * r0 + n1 * r1 + n2 * r2
                a = (n0 * v0 + n1 * v1 + n2 * v2) / (nr if nr > 1e-6 else 1e-6)
                lt = 1.0 + inv
                la = (1.0 - inv) * a if a < 0.0 else a
                v0 = la * r0 + lt * (v0 - a * r0)
                v1 = la * r1 + lt * (v1 - a * r1)
                v2 = la * r2 + lt * (v2 - a * r2)
            if movers:
                v0, v1, v2 = v0 + u0, v1 + u1, v2 + u2
            return array((v0, v1)) if two else array((v0, v1, v2))

        return f

    def __repr__(self) -> str:
        return f"AvoidingField({self.field!r}, {len(self.obstacles)} obstacles)"


def avoid(field: Any, obstacles: Sequence[Obstacle | str] | Obstacle | str, **kw: Any) -> AvoidingField:
    """``field`` modulated to avoid ``obstacles`` (Obstacle objects or ``parse_obstacle`` texts);
    see ``AvoidingField``. Raises ``ConfigError`` when the goal lies inside or too close to one."""
    if isinstance(obstacles, (Obstacle, str)):
        obstacles = [obstacles]
    obs = [parse_obstacle(o, field.dim) if isinstance(o, str) else o for o in obstacles]
    return AvoidingField(field, obs, **kw)


def starts_outside(field: AvoidingField, demos: Any, n: int, seed: int = 0, spread: float = 0.15,
                   clearance: float = 1.05) -> np.ndarray:
    """Seeded starts near the demos' starts and outside every obstacle of ``field``.

    Parameters
    ----------
    field : AvoidingField
        Its ``gamma`` (> 1 outside every obstacle) decides what is outside.
    demos : DemoSet
        x of shape (N, T, d); a start is a demo start plus uniform noise of +-spread x the demos'
        extent per coordinate.
    n, seed, spread : int, int, float
        How many starts, the numpy seed, the noise's half-width as a fraction of the extent.
    clearance : float
        Keep only starts with gamma > clearance.

    Returns
    -------
    array, shape (n, d)
    """
    rng = np.random.default_rng(seed)
    extent = np.ptp(demos.x.reshape(-1, demos.dim), axis=0)
    out: list[np.ndarray] = []
    while len(out) < n:
        x = demos.x[rng.integers(len(demos.x)), 0] + rng.uniform(-spread, spread, demos.dim) * extent
        if field.gamma(x) > clearance:
            out.append(x)
    return np.array(out)
