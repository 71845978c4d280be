"""The single-point modulation of ``AvoidingField.point_modulator`` (Eqs. (O1)-(O3)) compiled with
numba, for static obstacles (spheres, boxes and capsules, merged or not) and a fixed goal.

The obstacles are packed into one float vector (``pack``); ``modulate`` repeats the arithmetic of
the Python closure step by step, so the two agree to round-off (tests/test_obstacles.py).
Imported lazily by ``lfd.obstacles.avoidance``; ``cache=True`` keeps the machine code beside this
file.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numba
import numpy as np

__all__ = ["pack", "modulate", "band_weight", "SHAPES"]

#: the member kinds: 0 sphere, 1 box, 2 capsule (``pack``)
SHAPES = ("Sphere", "Box", "Capsule")
#: floats per member: kind, 1 / l, then the shape's numbers (``pack``)
MEMBER = 15
#: floats per unit: first member, members, 1 / l (1 for a group), 1 / rho of Eq. (O3) (0: none), x_ref (3)
UNIT = 7
#: floats of the head: K, steer, band, 1 / band, 1 / rho, square, goal (3), the Gamma floor, the
#: n . r floor inside, 2-D, merge power p, eps
HEAD = 14


def pack(units: Sequence[Any], fades: Sequence[float], reactivity: float, steer: bool, band: float,
         goal: tuple[float, float, float], floors: tuple[float, float], two: bool, merge_power: float,
         eps: float) -> np.ndarray:
    """The parameters of ``modulate``: head (``HEAD``,), K units (K, ``UNIT``) and their members
    (M, ``MEMBER``); units are ``lfd.obstacles.groups._Unit`` of static members of ``SHAPES``;
    floors: ``GAMMA_FLOOR`` and ``INSIDE_NR_FLOOR`` of ``lfd.obstacles.avoidance``."""
    from lfd.obstacles.shapes import _pad3

    head = [float(len(units)), float(steer), band, 1.0 / band, 1.0 / reactivity, float(1.0 / reactivity == 2.0),
            *goal, *floors, float(two), merge_power, eps]
    rows: list[list[float]] = []
    members: list[list[float]] = []
    for u, rho in zip(units, fades):
        single = len(u.members) == 1
        rows.append([float(len(members)), float(len(u.members)), 1.0 / u.obstacle.size if single else 1.0,
                     1.0 / rho if rho > 0.0 else 0.0, *_pad3(u.reference)])
        for o in u.members:
            kind = SHAPES.index(type(o).__name__)
            if kind == 0:
                numbers = [*_pad3(o.center), o.size]
            elif kind == 1:
                numbers = [*_pad3(o.center), float(o.margin), *_pad3(o.half_sizes, 1e300)]
            else:
                b = _pad3(o.b - o.a)
                numbers = [*_pad3(o.a), *b, max(b[0] * b[0] + b[1] * b[1] + b[2] * b[2], eps),
                           float(o.radius + o.margin), *_pad3(o._sdf(o._center()[None])[1][0])]
            members.append([float(kind), 1.0 / o.size, *numbers] + [0.0] * (MEMBER - 2 - len(numbers)))
    out = np.array(head + [v for r in rows for v in r] + [v for m in members for v in m], dtype=np.float64)
    return out


@numba.njit(cache=True, fastmath=False, nogil=True)
def _sdf(P: np.ndarray, o: int, y0: float, y1: float, y2: float
         ) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """(sdf, n (3)) of the member at P[o:] (``lfd.obstacles.shapes``' ``_point_sdf3``)."""
    kind, eps = P[o], P[HEAD - 1]
    if kind == 0.0:
        q0, q1, q2 = y0 - P[o + 2], y1 - P[o + 3], y2 - P[o + 4]
        R = P[o + 5]
        d = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
        if d < eps:
            return -R, 1.0, 0.0, 0.0
        return d - R, q0 / d, q1 / d, q2 / d
    if kind == 1.0:
        q0, q1, q2 = y0 - P[o + 2], y1 - P[o + 3], y2 - P[o + 4]
        m = P[o + 5]
        a0, a1, a2 = abs(q0) - P[o + 6], abs(q1) - P[o + 7], abs(q2) - P[o + 8]
        o0 = a0 if a0 > 0.0 else 0.0
        o1 = a1 if a1 > 0.0 else 0.0
        o2 = a2 if a2 > 0.0 else 0.0
        out = o0 * o0 + o1 * o1 + o2 * o2
        if out > 0.0:
            out = np.sqrt(out)
            return out - m, np.copysign(o0, q0) / out, np.copysign(o1, q1) / out, np.copysign(o2, q2) / out
        if a0 >= a1 and a0 >= a2:
            return a0 - m, np.copysign(1.0, q0), 0.0, 0.0
        if a1 >= a2:
            return a1 - m, 0.0, np.copysign(1.0, q1), 0.0
        return a2 - m, 0.0, 0.0, np.copysign(1.0, q2)
    p0, p1, p2 = y0 - P[o + 2], y1 - P[o + 3], y2 - P[o + 4]
    b0, b1, b2, ab2, R = P[o + 5], P[o + 6], P[o + 7], P[o + 8], P[o + 9]
    s = (p0 * b0 + p1 * b1 + p2 * b2) / ab2
    s = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
    q0, q1, q2 = p0 - s * b0, p1 - s * b1, p2 - s * b2
    d = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    if d < eps:
        return -R, P[o + 10], P[o + 11], P[o + 12]
    return d - R, q0 / d, q1 / d, q2 / d


@numba.njit(cache=True, fastmath=False, nogil=True)
def _geometry(P: np.ndarray, k: int, x0: float, x1: float, x2: float
              ) -> tuple[float, float, float, float, float, float, float]:  # pragma: no cover - compiled
    """(Gamma, n (3), r (3)) of unit k at x (``_Unit.point_geometry``, static)."""
    K = int(P[0])
    u = HEAD + UNIT * k
    first, count, inv = int(P[u]), int(P[u + 1]), P[u + 2]
    base = HEAD + UNIT * K + MEMBER * first
    if count == 1:
        s, n0, n1, n2 = _sdf(P, base, x0, x1, x2)
    else:   # the smooth minimum of the members' Gammas (``lfd.obstacles.groups``)
        p, eps = P[HEAD - 2], P[HEAD - 1]
        acc = 0.0
        for i in range(count):
            o = base + MEMBER * i
            si, a0, a1, a2 = _sdf(P, o, x0, x1, x2)
            g_k = max(1.0 + si * P[o + 1], eps)
            acc += g_k ** -p
        g = acc ** (-1.0 / p)
        m0 = m1 = m2 = 0.0
        for i in range(count):
            o = base + MEMBER * i
            si, a0, a1, a2 = _sdf(P, o, x0, x1, x2)
            inv_k = P[o + 1]
            g_k = max(1.0 + si * inv_k, eps)
            w = (g / g_k) ** (p + 1.0) * inv_k
            m0, m1, m2 = m0 + w * a0, m1 + w * a1, m2 + w * a2
        mn = np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if mn == 0.0:
            mn = 1.0
        s, n0, n1, n2 = g - 1.0, m0 / mn, m1 / mn, m2 / mn
    q0, q1, q2 = x0 - P[u + 4], x1 - P[u + 5], x2 - P[u + 6]
    qn = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    if qn == 0.0:
        qn = 1.0
    return 1.0 + s * inv, n0, n1, n2, q0 / qn, q1 / qn, q2 / qn


@numba.njit(cache=True, fastmath=False, nogil=True)
def _smoothstep(u: float) -> float:  # pragma: no cover - compiled
    """3 u^2 - 2 u^3 on u clipped to [0, 1] (``lfd.obstacles.avoidance._smoothstep``)."""
    u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
    return u * u * (3.0 - 2.0 * u)


@numba.njit(cache=True, fastmath=False, nogil=True)
def modulate(x: np.ndarray, v: np.ndarray, P: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """The avoiding velocity, shape (d,), at x for the nominal velocity v, shape (d,) each, d = 2
    or 3: Eqs. (O1)-(O3) as ``AvoidingField.point_modulator`` computes them (static obstacles;
    P from ``pack``)."""
    gamma_floor, inside_floor = P[9], P[10]
    two = P[HEAD - 3] != 0.0
    x0, x1 = x[0], x[1]
    v0, v1 = v[0], v[1]
    x2 = 0.0 if two else x[2]
    v2 = 0.0 if two else v[2]
    K = int(P[0])
    scratch = np.empty(9 * K)
    geo = scratch[:7 * K].reshape((K, 7))
    for k in range(K):
        g, n0, n1, n2, r0, r1, r2 = _geometry(P, k, x0, x1, x2)
        geo[k, 0], geo[k, 1], geo[k, 2], geo[k, 3] = g, n0, n1, n2
        geo[k, 4], geo[k, 5], geo[k, 6] = r0, r1, r2
    w = scratch[7 * K:8 * K]   # the weights of Khansari-Zadeh and Billard (``_kzb_weights``)
    w[:] = 1.0
    if K > 1:
        e = scratch[8 * K:]
        for k in range(K):
            e[k] = geo[k, 0] - 1.0 if geo[k, 0] > 1.0 else 0.0
        if K == 2:
            s = e[0] + e[1]
            if s > 0.0:
                w[0], w[1] = e[1] / s, e[0] / s
            else:
                w[0], w[1] = 0.5, 0.5
        elif K == 3 and e[0] > 0.0 and e[1] > 0.0 and e[2] > 0.0:
            a, b, c = e[0], e[1], e[2]
            ab, ac, bc = a + b, a + c, b + c
            w[0], w[1], w[2] = b * c / (ab * ac), a * c / (ab * bc), a * b / (ac * bc)
        else:
            for k in range(K):
                prod = 1.0
                for i in range(K):
                    if i != k:
                        den = e[k] + e[i]
                        prod *= e[i] / den if den > 0.0 else 0.5
                w[k] = prod
    if P[1] != 0.0:   # Eq. (O2)
        eps = P[HEAD - 1]
        c0, c1, c2 = P[6] - x0, P[7] - x1, P[8] - x2
        dist = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        gmin = geo[0, 0]
        for k in range(1, K):
            if geo[k, 0] < gmin:
                gmin = geo[k, 0]
        om = _smoothstep((1.0 + P[2] - gmin) * P[3])
        if om > 0.0:
            sp = om * np.sqrt(v0 * v0 + v1 * v1 + v2 * v2) / (dist if dist > eps else eps)
            keep = 1.0 - om
            v0, v1, v2 = keep * v0 + sp * c0, keep * v1 + sp * c1, keep * v2 + sp * c2
        for k in range(K):   # Eq. (O3)
            inv_r = P[HEAD + UNIT * k + 3]
            if inv_r > 0.0:
                w[k] *= _smoothstep(dist * inv_r)
    inv_rho, square = P[4], P[5] != 0.0
    for k in range(K):
        wk = w[k]
        if wk == 0.0:
            continue
        g = geo[k, 0]
        n0, n1, n2, r0, r1, r2 = geo[k, 1], geo[k, 2], geo[k, 3], geo[k, 4], geo[k, 5], geo[k, 6]
        if g < gamma_floor:
            g = gamma_floor
        inv = wk / (g * g) if square else (wk / g if inv_rho == 1.0 else wk / g ** inv_rho)
        nr = n0 * r0 + n1 * r1 + n2 * r2
        floor = 1e-6 if g >= 1.0 else inside_floor
        a = (n0 * v0 + n1 * v1 + n2 * v2) / (nr if nr > floor else floor)
        lt = 1.0 + inv
        la = (1.0 - inv) * a if a < 0.0 else a
        v0 = la * r0 + lt * (v0 - a * r0)
        v1 = la * r1 + lt * (v1 - a * r1)
        v2 = la * r2 + lt * (v2 - a * r2)
    out = np.empty(2 if two else 3)
    out[0], out[1] = v0, v1
    if not two:
        out[2] = v2
    return out


@numba.njit(cache=True, fastmath=False, nogil=True)
def band_weight(x: np.ndarray, P: np.ndarray, hold: float) -> float:  # pragma: no cover - compiled
    """A band weight at x, shape (d,): 1 up to Gamma = 1 + hold from the nearest obstacle, 0 from
    Gamma = 1 + hold + band on (P from ``pack``; the band whether or not the field steers);
    hold = 0 is omega of Eq. (O2)."""
    two = P[HEAD - 3] != 0.0
    x0, x1 = x[0], x[1]
    x2 = 0.0 if two else x[2]
    K = int(P[0])
    if K == 0:
        return 0.0
    gmin = _geometry(P, 0, x0, x1, x2)[0]
    for k in range(1, K):
        g = _geometry(P, k, x0, x1, x2)[0]
        if g < gmin:
            gmin = g
    return _smoothstep((1.0 + hold + P[2] - gmin) * P[3])
