"""The modulation of one point (Eqs. (O1)-(O3) of docs/equations.md) as plain-float arithmetic,
written once for two callers.

The helpers (``sphere_sdf``, ``box_sdf``, ``capsule_sdf``, ``smoothstep``, ``kzb_weights``, ``steer``,
``modulate_unit``) take and return plain floats: the Python closures of ``lfd.obstacles.shapes`` and
``lfd.obstacles.modulation`` call them as they are (any obstacle, moving ones too), and ``compiled``
builds numba kernels (``modulate``, ``band_weight``) that inline the same helpers, for static
obstacles of the built-in shapes packed into one float vector (``pack``). numba is imported on the
first ``compiled`` call; ``cache=True`` keeps the machine code beside this file, and since every
helper lives in this file, editing one invalidates that cache.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

__all__ = ["EPS", "pad3", "sphere_sdf", "box_sdf", "capsule_sdf", "smoothstep", "kzb_weights", "steer",
           "modulate_unit", "pack", "compiled", "SHAPES"]

#: the length below which a distance counts as zero (a normal is then chosen, not computed)
EPS = 1e-12
#: the member kinds: 0 sphere, 1 box, 2 capsule (``pack``)
SHAPES = ("Sphere", "Box", "Capsule")
#: floats per member: kind, 1 / l, then the shape's numbers (``pack``)
MEMBER = 15
#: floats per unit: first member, members, 1 / l (1 for a group), 1 / rho of Eq. (O3) (0: none), x_ref (3)
UNIT = 7
#: floats of the head: K, steer, band, 1 / band, 1 / rho, square, goal (3), the Gamma floor, the
#: n . r floor inside, 2-D, merge power p
HEAD = 13

Point4 = tuple[float, float, float, float]
Point3 = tuple[float, float, float]


def pad3(a: Any, fill: float = 0.0) -> Point3:
    """A 2- or 3-vector as three floats, z = ``fill`` for 2-D."""
    v = [float(x) for x in a]
    return (v[0], v[1], v[2] if len(v) == 3 else fill)


# ---------------------------------------------------------------- the shared arithmetic
def sphere_sdf(c0: float, c1: float, c2: float, R: float, y0: float, y1: float, y2: float) -> Point4:
    """(sdf, n0, n1, n2) of the point y to the ball of centre c and radius R (grown by its margin)."""
    q0, q1, q2 = y0 - c0, y1 - c1, y2 - c2
    d = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    if d < EPS:
        return -R, 1.0, 0.0, 0.0
    return d - R, q0 / d, q1 / d, q2 / d


def box_sdf(c0: float, c1: float, c2: float, m: float, h0: float, h1: float, h2: float,
            y0: float, y1: float, y2: float) -> Point4:
    """(sdf, n0, n1, n2) of the point y to the axis-aligned box of centre c and half sizes h grown by
    the margin m (a rounded box; a 2-D box has h2 = 1e300, a prism of infinite height)."""
    q0, q1, q2 = y0 - c0, y1 - c1, y2 - c2
    a0, a1, a2 = abs(q0) - h0, abs(q1) - h1, abs(q2) - h2
    o0 = a0 if a0 > 0.0 else 0.0
    o1 = a1 if a1 > 0.0 else 0.0
    o2 = a2 if a2 > 0.0 else 0.0
    out = o0 * o0 + o1 * o1 + o2 * o2
    if out > 0.0:
        out = math.sqrt(out)
        return out - m, math.copysign(o0, q0) / out, math.copysign(o1, q1) / out, math.copysign(o2, q2) / out
    if a0 >= a1 and a0 >= a2:
        return a0 - m, math.copysign(1.0, q0), 0.0, 0.0
    if a1 >= a2:
        return a1 - m, 0.0, math.copysign(1.0, q1), 0.0
    return a2 - m, 0.0, 0.0, math.copysign(1.0, q2)


def capsule_sdf(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float, ab2: float, R: float,
                e0: float, e1: float, e2: float, y0: float, y1: float, y2: float) -> Point4:
    """(sdf, n0, n1, n2) of the point y to the capsule of axis a + s b, s in [0, 1], ab2 = |b|^2
    (at least ``EPS``) and radius R (grown by its margin); e: the normal chosen on the axis."""
    p0, p1, p2 = y0 - a0, y1 - a1, y2 - a2
    s = (p0 * b0 + p1 * b1 + p2 * b2) / ab2
    s = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
    q0, q1, q2 = p0 - s * b0, p1 - s * b1, p2 - s * b2
    d = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    if d < EPS:
        return -R, e0, e1, e2
    return d - R, q0 / d, q1 / d, q2 / d


def smoothstep(u: float) -> float:
    """3 u^2 - 2 u^3 on u clipped to [0, 1]: 0 -> 0, 1 -> 1, C1."""
    u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
    return u * u * (3.0 - 2.0 * u)


def kzb_weights(g: Any, w: Any, n: int) -> None:
    """Fill w[:n] with w_k = prod_{i != k} (Gamma_i - 1) / ((Gamma_k - 1) + (Gamma_i - 1)), the
    weights of Khansari-Zadeh and Billard (2012) of the Gammas g[:n] (Gamma - 1 clipped at 0: a point
    on or inside an obstacle gives it the full weight; 1 for one obstacle). g, w: lists or arrays."""
    if n == 2:
        e0 = g[0] - 1.0 if g[0] > 1.0 else 0.0
        e1 = g[1] - 1.0 if g[1] > 1.0 else 0.0
        s = e0 + e1
        if s > 0.0:
            w[0], w[1] = e1 / s, e0 / s
        else:
            w[0], w[1] = 0.5, 0.5
        return
    if n == 3 and g[0] > 1.0 and g[1] > 1.0 and g[2] > 1.0:
        a, b, c = g[0] - 1.0, g[1] - 1.0, g[2] - 1.0
        ab, ac, bc = a + b, a + c, b + c
        w[0], w[1], w[2] = b * c / (ab * ac), a * c / (ab * bc), a * b / (ac * bc)
        return
    for k in range(n):
        ek = g[k] - 1.0 if g[k] > 1.0 else 0.0
        prod = 1.0
        for i in range(n):
            if i != k:
                ei = g[i] - 1.0 if g[i] > 1.0 else 0.0
                den = ek + ei
                prod *= ei / den if den > 0.0 else 0.5
        w[k] = prod


def steer(om: float, dist: float, c0: float, c1: float, c2: float, v0: float, v1: float, v2: float) -> Point3:
    """Eq. (O2): b = (1 - omega) v + omega |v| c / |c|, c = g - x at distance ``dist`` = |c|."""
    if om <= 0.0:
        return v0, v1, v2
    sp = om * math.sqrt(v0 * v0 + v1 * v1 + v2 * v2) / (dist if dist > EPS else EPS)
    keep = 1.0 - om
    return keep * v0 + sp * c0, keep * v1 + sp * c1, keep * v2 + sp * c2


def modulate_unit(w: float, g: float, n0: float, n1: float, n2: float, r0: float, r1: float, r2: float,
                  v0: float, v1: float, v2: float, inv_rho: float, square: bool, gamma_floor: float,
                  inside_floor: float) -> Point3:
    """Eqs. (O1), (O3) for one unit of weight w (eta_k w_k): the velocity v (relative to the obstacle)
    with v = a r + t, t orthogonal to the normal n, becomes lambda_r a r + (1 + w / Gamma^(1/rho)) t,
    lambda_r = 1 - w / Gamma^(1/rho) where a < 0, else 1 (no tail effect). Gamma is floored at
    ``gamma_floor``, n . r at 1e-6 outside and ``inside_floor`` inside; ``square``: 1/rho = 2."""
    if w == 0.0:
        return v0, v1, v2
    if g < gamma_floor:
        g = gamma_floor
    inv = w / (g * g) if square else (w / g if inv_rho == 1.0 else w / g ** inv_rho)
    nr = n0 * r0 + n1 * r1 + n2 * r2
    floor = 1e-6 if g >= 1.0 else inside_floor
    a = (n0 * v0 + n1 * v1 + n2 * v2) / (nr if nr > floor else floor)
    lt = 1.0 + inv
    la = (1.0 - inv) * a if a < 0.0 else a
    return la * r0 + lt * (v0 - a * r0), la * r1 + lt * (v1 - a * r1), la * r2 + lt * (v2 - a * r2)


# ---------------------------------------------------------------- the compiled kernels
def pack(units: Sequence[Any], fades: Sequence[float], reactivity: float, steer: bool, band: float,
         goal: Point3, floors: tuple[float, float], two: bool, merge_power: float) -> np.ndarray:
    """The parameters of ``modulate``: head (``HEAD``,), K units (K, ``UNIT``) and their members
    (M, ``MEMBER``); units are ``lfd.obstacles.groups.Unit`` of static members of ``SHAPES``;
    floors: the Gamma floor and the n . r floor inside (``lfd.obstacles.modulation``)."""
    head = [float(len(units)), float(steer), band, 1.0 / band, 1.0 / reactivity, float(1.0 / reactivity == 2.0),
            *goal, *floors, float(two), merge_power]
    rows: list[list[float]] = []
    members: list[list[float]] = []
    for u, rho in zip(units, fades):
        single = len(u.members) == 1
        rows.append([float(len(members)), float(len(u.members)), 1.0 / u.obstacle.size if single else 1.0,
                     1.0 / rho if rho > 0.0 else 0.0, *pad3(u.reference)])
        for o in u.members:
            kind = SHAPES.index(type(o).__name__)
            members.append([float(kind), 1.0 / o.size, *o.point_numbers()])
    members = [m + [0.0] * (MEMBER - len(m)) for m in members]
    return np.array(head + [v for r in rows for v in r] + [v for m in members for v in m], dtype=np.float64)


def _sdf(P: np.ndarray, o: int, y0: float, y1: float, y2: float) -> Point4:  # pragma: no cover - compiled
    """(sdf, n (3)) of the member at P[o:] (its ``point_numbers`` follow kind and 1 / l)."""
    kind, q = P[o], o + 2
    if kind == 0.0:
        return sphere_sdf(P[q], P[q + 1], P[q + 2], P[q + 3], y0, y1, y2)
    if kind == 1.0:
        return box_sdf(P[q], P[q + 1], P[q + 2], P[q + 3], P[q + 4], P[q + 5], P[q + 6], y0, y1, y2)
    return capsule_sdf(P[q], P[q + 1], P[q + 2], P[q + 3], P[q + 4], P[q + 5], P[q + 6], P[q + 7],
                       P[q + 8], P[q + 9], P[q + 10], y0, y1, y2)


def _geometry(P: np.ndarray, k: int, x0: float, x1: float, x2: float
              ) -> tuple[float, float, float, float, float, float, float]:  # pragma: no cover - compiled
    """(Gamma, n (3), r (3)) of unit k at x (``Unit.point_geometry``, static)."""
    K = int(P[0])
    u = HEAD + UNIT * k
    first, count, inv = int(P[u]), int(P[u + 1]), P[u + 2]
    base = HEAD + UNIT * K + MEMBER * first
    if count == 1:
        s, n0, n1, n2 = _sdf(P, base, x0, x1, x2)
    else:   # the smooth minimum of the members' Gammas (``lfd.obstacles.groups``)
        p = P[HEAD - 1]
        acc = 0.0
        for i in range(count):
            o = base + MEMBER * i
            si, a0, a1, a2 = _sdf(P, o, x0, x1, x2)
            g_k = max(1.0 + si * P[o + 1], EPS)
            acc += g_k ** -p
        g = acc ** (-1.0 / p)
        m0 = m1 = m2 = 0.0
        for i in range(count):
            o = base + MEMBER * i
            si, a0, a1, a2 = _sdf(P, o, x0, x1, x2)
            inv_k = P[o + 1]
            g_k = max(1.0 + si * inv_k, EPS)
            w = (g / g_k) ** (p + 1.0) * inv_k
            m0, m1, m2 = m0 + w * a0, m1 + w * a1, m2 + w * a2
        mn = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if mn == 0.0:
            mn = 1.0
        s, n0, n1, n2 = g - 1.0, m0 / mn, m1 / mn, m2 / mn
    q0, q1, q2 = x0 - P[u + 4], x1 - P[u + 5], x2 - P[u + 6]
    qn = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    if qn == 0.0:
        qn = 1.0
    return 1.0 + s * inv, n0, n1, n2, q0 / qn, q1 / qn, q2 / qn


def _modulate(x: np.ndarray, v: np.ndarray, P: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """The avoiding velocity, shape (d,), at x for the nominal velocity v, shape (d,) each, d = 2
    or 3: Eqs. (O1)-(O3) as the Python closure of ``lfd.obstacles.modulation`` computes them
    (static obstacles; P from ``pack``)."""
    two = P[HEAD - 2] != 0.0
    x0, x1 = x[0], x[1]
    v0, v1 = v[0], v[1]
    x2 = 0.0 if two else x[2]
    v2 = 0.0 if two else v[2]
    K = int(P[0])
    geo = np.empty((K, 7))
    for k in range(K):
        g, n0, n1, n2, r0, r1, r2 = _geometry(P, k, x0, x1, x2)
        geo[k, 0], geo[k, 1], geo[k, 2], geo[k, 3] = g, n0, n1, n2
        geo[k, 4], geo[k, 5], geo[k, 6] = r0, r1, r2
    w = np.empty(K)
    kzb_weights(geo[:, 0], w, K)
    if P[1] != 0.0:   # Eq. (O2)
        c0, c1, c2 = P[6] - x0, P[7] - x1, P[8] - x2
        dist = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        gmin = geo[0, 0]
        for k in range(1, K):
            if geo[k, 0] < gmin:
                gmin = geo[k, 0]
        v0, v1, v2 = steer(smoothstep((1.0 + P[2] - gmin) * P[3]), dist, c0, c1, c2, v0, v1, v2)
        for k in range(K):   # Eq. (O3)
            inv_r = P[HEAD + UNIT * k + 3]
            if inv_r > 0.0:
                w[k] *= smoothstep(dist * inv_r)
    inv_rho, square, gamma_floor, inside_floor = P[4], P[5] != 0.0, P[9], P[10]
    for k in range(K):
        v0, v1, v2 = modulate_unit(w[k], geo[k, 0], geo[k, 1], geo[k, 2], geo[k, 3], geo[k, 4], geo[k, 5],
                                   geo[k, 6], v0, v1, v2, inv_rho, square, gamma_floor, inside_floor)
    out = np.empty(2 if two else 3)
    out[0], out[1] = v0, v1
    if not two:
        out[2] = v2
    return out


def _band_weight(x: np.ndarray, P: np.ndarray, hold: float) -> float:  # pragma: no cover - compiled
    """A band weight at x, shape (d,): 1 up to Gamma = 1 + hold from the nearest obstacle, 0 from
    Gamma = 1 + hold + band on (P from ``pack``; the band whether or not the field steers);
    hold = 0 is omega of Eq. (O2)."""
    two = P[HEAD - 2] != 0.0
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
    return smoothstep((1.0 + hold + P[2] - gmin) * P[3])


@functools.cache
def compiled() -> tuple[Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
                        Callable[[np.ndarray, np.ndarray, float], float]]:
    """(modulate, band_weight): ``_modulate`` (x (d,), v (d,), P) -> dx/dt (d,) and ``_band_weight``
    (x (d,), P, hold) -> weight, compiled with numba, every helper of this module inlined."""
    import numba
    from numba.extending import register_jitable

    for helper in (sphere_sdf, box_sdf, capsule_sdf, smoothstep, kzb_weights, steer, modulate_unit, _sdf,
                   _geometry):
        register_jitable(helper)
    jit = numba.njit(cache=True, fastmath=False, nogil=True)
    return jit(_modulate), jit(_band_weight)
