"""Compiled hot paths of ``sim.scene.collision``: the broad phase over all pairs, and the rows of
Eq. (A1): MuJoCo's ``mj_geomDistance`` called from numba through ctypes for each candidate pair,
and n^T J(p) of MuJoCo's translational Jacobian at a point (written over ``cdof`` as MuJoCo's
``mj_jac`` does).

Imported lazily by ``sim.scene.collision``; ``cache=True`` keeps the machine code beside this file (the
kernels take the function's address as an argument, so no process-specific pointer is compiled in).
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from llvmlite import ir
from numba.core import types as nbtypes
from numba.extending import intrinsic


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _box_point_gap(xpos: np.ndarray, xmat: np.ndarray, g: int, centre: np.ndarray, half: np.ndarray,
                   p0: float, p1: float, p2: float) -> float:  # pragma: no cover - compiled
    """Distance from the point p to geom g's bounding box (its ``geom_aabb``: centre (3,) and half
    sizes (3,) in the geom's frame), world."""
    d0, d1, d2 = p0 - xpos[g, 0], p1 - xpos[g, 1], p2 - xpos[g, 2]
    acc = 0.0
    for k in range(3):   # the point in the geom's frame, minus the box centre, outside the box
        u = xmat[g, k] * d0 + xmat[g, 3 + k] * d1 + xmat[g, 6 + k] * d2 - centre[k]
        e = abs(u) - half[k]
        if e > 0.0:
            acc += e * e
    return np.sqrt(acc)


@numba.njit(cache=True, fastmath=False, nogil=True)
def broadphase(xpos: np.ndarray, xmat: np.ndarray, geoms: np.ndarray, centre: np.ndarray, half: np.ndarray,
               radius: np.ndarray, a: np.ndarray, b: np.ndarray, slab_top: np.ndarray, influence: float,
               out: np.ndarray) -> int:  # pragma: no cover - compiled
    """Write into out (P,) the indices of the pairs that may lie within ``influence`` and return
    their count.

    xpos (ngeom, 3), xmat (ngeom, 9): MuJoCo's geom poses; geoms (G,): the geoms involved;
    centre, half (G, 3): each one's bounding box (``geom_aabb``) in its own frame, radius (G,) the
    sphere around it; a, b (P,): the pairs, as indices into geoms. The bound of a pair is the larger
    of (the distance from a's box to b's sphere) and (from b's box to a's sphere); slab_top (P,):
    NaN, or geom b is a slab whose top face lies this far above its centre (the table): then the
    bound is a's sphere's height over that face.
    """
    G = geoms.shape[0]
    c = np.empty((G, 3))
    for i in range(G):
        g = geoms[i]
        for k in range(3):
            c[i, k] = (xpos[g, k] + xmat[g, 3 * k] * centre[i, 0] + xmat[g, 3 * k + 1] * centre[i, 1]
                       + xmat[g, 3 * k + 2] * centre[i, 2])
    count = 0
    for p in range(a.shape[0]):
        i, j = a[p], b[p]
        if np.isnan(slab_top[p]):
            gap = _box_point_gap(xpos, xmat, geoms[i], centre[i], half[i], c[j, 0], c[j, 1], c[j, 2]) - radius[j]
            if gap < influence:
                gap = max(gap, _box_point_gap(xpos, xmat, geoms[j], centre[j], half[j], c[i, 0], c[i, 1], c[i, 2])
                          - radius[i])
        else:
            gap = c[i, 2] - radius[i] - (xpos[geoms[j], 2] + slab_top[p])
        if gap < influence:
            out[count] = p
            count += 1
    return count


@numba.njit(cache=True, fastmath=False, nogil=True)
def add_row(cdof: np.ndarray, subtree_com: np.ndarray, body_rootid: np.ndarray, body_dofnum: np.ndarray,
            body_dofadr: np.ndarray, body_parentid: np.ndarray, dof_parentid: np.ndarray, body: int,
            p: np.ndarray, n: np.ndarray, sign: float, column: np.ndarray,
            out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out[column[j]] += sign n . J_p[:, j] for every dof j that moves point p (3,) of ``body``
    (column[j] < 0: not an arm joint, skipped); n (3,). J_p[:, j] = cdof_lin + cdof_ang x (p - c),
    c the subtree centre of mass of the body's root (MuJoCo's ``mj_jac``)."""
    root = body_rootid[body]
    o0, o1, o2 = p[0] - subtree_com[root, 0], p[1] - subtree_com[root, 1], p[2] - subtree_com[root, 2]
    while body > 0 and body_dofnum[body] == 0:
        body = body_parentid[body]
    if body <= 0:
        return
    j = body_dofadr[body] + body_dofnum[body] - 1
    while j >= 0:
        col = column[j]
        if col >= 0:
            w0, w1, w2 = cdof[j, 0], cdof[j, 1], cdof[j, 2]
            j0 = cdof[j, 3] + (w1 * o2 - w2 * o1)
            j1 = cdof[j, 4] + (w2 * o0 - w0 * o2)
            j2 = cdof[j, 5] + (w0 * o1 - w1 * o0)
            out[col] += sign * (n[0] * j0 + n[1] * j1 + n[2] * j2)
        j = dof_parentid[j]


def _geom_distance_address() -> int:
    """The address of MuJoCo's ``mj_geomDistance`` in its shared library (the one the ``mujoco``
    package has loaded), for ``_call_geom_distance``."""
    import ctypes
    import glob
    import os

    import mujoco

    libs = sorted(glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*"))
                  + glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco*.dylib")))
    if not libs or ctypes.sizeof(ctypes.c_void_p) != 8:
        from sim.errors import SimError

        raise SimError("whole-arm clearance needs the 64-bit MuJoCo shared library beside the mujoco package")
    return int(ctypes.cast(ctypes.CDLL(libs[0]).mj_geomDistance, ctypes.c_void_p).value or 0)


#: where ``mj_geomDistance`` lies in this process (passed to the kernels, which are then cacheable)
GEOM_DISTANCE = _geom_distance_address()


def _geom_distance_call(typingctx: Any, fn: Any, model: Any, data: Any, g1: Any, g2: Any, distmax: Any,
                        fromto: Any) -> Any:  # pragma: no cover - compiled
    """mj_geomDistance(m, d, g1, g2, distmax, fromto) called at the address fn, all pointers as
    int64 addresses (MuJoCo's signature: two struct pointers, two ints, a double, a double
    pointer; returns the signed distance, distmax if beyond it)."""
    i64 = nbtypes.int64
    sig = nbtypes.float64(i64, i64, i64, i64, i64, nbtypes.float64, i64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        ptr, dptr, i32 = ir.IntType(8).as_pointer(), ir.DoubleType().as_pointer(), ir.IntType(32)
        fnty = ir.FunctionType(ir.DoubleType(), [ptr, ptr, i32, i32, ir.DoubleType(), dptr])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        return builder.call(f, [builder.inttoptr(args[1], ptr), builder.inttoptr(args[2], ptr),
                                builder.trunc(args[3], i32), builder.trunc(args[4], i32), args[5],
                                builder.inttoptr(args[6], dptr)])
    return sig, codegen


_call_geom_distance: Any = intrinsic(_geom_distance_call)


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _pair_normal(ft: np.ndarray, at: int, xpos: np.ndarray, g1: int, g2: int,
                 d: float) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """n of Eq. (A1), unit, from the nearest points p_1 = ft[at:at + 3] (geom g1) and
    p_2 = ft[at + 3:at + 6] (geom g2) that ``mj_geomDistance`` wrote with distance d: along
    p_2 - p_1 (reversed when d < 0, the geoms overlapping); touching (|p_2 - p_1| ~ 0), the
    direction between the geoms' centres xpos (ngeom, 3). One rule for ``pair_rows`` and
    ``guard_check``, which must decide alike."""
    u0, u1, u2 = ft[at + 3] - ft[at], ft[at + 4] - ft[at + 1], ft[at + 5] - ft[at + 2]
    norm = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    if norm < 1e-9:   # touching: the direction between the geoms' centres
        u0 = xpos[g2, 0] - xpos[g1, 0]
        u1 = xpos[g2, 1] - xpos[g1, 1]
        u2 = xpos[g2, 2] - xpos[g1, 2]
        norm = max(np.sqrt(u0 * u0 + u1 * u1 + u2 * u2), 1e-12)
    s = (1.0 if d >= 0.0 else -1.0) / norm
    return u0 * s, u1 * s, u2 * s


@numba.njit(cache=True, fastmath=False, nogil=True)
def pair_rows(fn: int, model: int, data: int, cand: np.ndarray, count: int, g1: np.ndarray, g2: np.ndarray,
              mutual: np.ndarray, reach: float, geom_xpos: np.ndarray, geom_body: np.ndarray, cdof: np.ndarray,
              subtree_com: np.ndarray, body_rootid: np.ndarray, body_dofnum: np.ndarray, body_dofadr: np.ndarray,
              body_parentid: np.ndarray, dof_parentid: np.ndarray, column: np.ndarray, fromto: np.ndarray,
              A: np.ndarray, dist: np.ndarray, which: np.ndarray) -> int:  # pragma: no cover - compiled
    """The damper rows of the candidate pairs cand[:count] (``sim.scene.collision``): for each pair
    within ``reach`` write its row n^T (J(p1) - J(p2)) into A[k], its distance into dist[k] and its
    index into which[k]; return k. fn: ``GEOM_DISTANCE``; ``model``, ``data``: MuJoCo's struct
    addresses; fromto (6,)."""
    k = 0
    addr = fromto.ctypes.data
    n = np.empty(3)
    p1 = np.empty(3)
    p2 = np.empty(3)
    for c in range(count):
        i = cand[c]
        d = _call_geom_distance(fn, model, data, g1[i], g2[i], reach, addr)
        if d >= reach:
            continue
        n[0], n[1], n[2] = _pair_normal(fromto, 0, geom_xpos, g1[i], g2[i], d)
        for j in range(3):
            p1[j] = fromto[j]
            p2[j] = fromto[3 + j]
        for col in range(A.shape[1]):
            A[k, col] = 0.0
        add_row(cdof, subtree_com, body_rootid, body_dofnum, body_dofadr, body_parentid, dof_parentid,
                geom_body[g1[i]], p1, n, 1.0, column, A[k])
        if mutual[i]:
            add_row(cdof, subtree_com, body_rootid, body_dofnum, body_dofadr, body_parentid, dof_parentid,
                    geom_body[g2[i]], p2, n, -1.0, column, A[k])
        dist[k] = d
        which[k] = i
        k += 1
    return k


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _point_rate(cdof: np.ndarray, subtree_com: np.ndarray, tree: np.ndarray, t: np.ndarray, body: int,
                c0: float, c1: float, c2: float, qdot: np.ndarray
                ) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """(v (3,), |omega|): the velocity J(c) qdot of the point c of ``body`` and the body's angular
    speed under the arm's joint velocities qdot (n,) (MuJoCo's ``mj_jac`` over ``cdof``, as
    ``add_row``); tree, t: the packed tree arrays and their offsets (``guard_check``)."""
    root = tree[t[0] + body]
    o0, o1, o2 = c0 - subtree_com[root, 0], c1 - subtree_com[root, 1], c2 - subtree_com[root, 2]
    l0 = l1 = l2 = w0 = w1 = w2 = 0.0
    while body > 0 and tree[t[1] + body] == 0:
        body = tree[t[3] + body]
    if body > 0:
        j = tree[t[2] + body] + tree[t[1] + body] - 1
        while j >= 0:
            col = tree[t[5] + j]
            if col >= 0:
                qd = qdot[col]
                w0 += cdof[j, 0] * qd
                w1 += cdof[j, 1] * qd
                w2 += cdof[j, 2] * qd
                l0 += cdof[j, 3] * qd
                l1 += cdof[j, 4] * qd
                l2 += cdof[j, 5] * qd
            j = tree[t[4] + j]
    return (l0 + (w1 * o2 - w2 * o1), l1 + (w2 * o0 - w0 * o2), l2 + (w0 * o1 - w1 * o0),
            np.sqrt(w0 * w0 + w1 * w1 + w2 * w2))


@numba.njit(cache=True, fastmath=False, nogil=True)
def guard_check(fn: int, model: int, data: int, xpos: np.ndarray, xmat: np.ndarray, cdof: np.ndarray,
                subtree_com: np.ndarray, qdot: np.ndarray, ints: np.ndarray, floats: np.ndarray,
                state: np.ndarray) -> int:  # pragma: no cover - compiled
    """Whether a damper row of Eq. (A1) binds for the joint velocities qdot (n,): 1 if some pair
    within reach has n^T (J_1 - J_2) qdot > k (d - d_s), else 0 (``sim.scene.collision.ArmClearance.check``).

    Each pair that passes the broad phase (``broadphase``) gets a lower bound d_lb on its distance:
    the larger of the broad-phase gap and the pair's cached exact distance less how far any point of
    either geom has moved since (|c - c_0| + ||R - R_0||_F r of the bounding sphere, centre c and
    radius r, and the rotation R). A pair with d_lb >= reach adds no row. A pair whose row cannot
    bind for qdot, k (d_lb - d_s) > |v_1 - v_2| + |w_1| r_1 + |w_2| r_2 (the bounding spheres'
    centre velocities v and the bodies' angular speeds w: a bound on |n^T (J_1 - J_2) qdot| for any
    unit n and points in the spheres), skips ``mj_geomDistance``; the others get the exact distance
    and row, which refresh the cache. A skipped pair whose d_lb lies below the smallest exact
    distance within reach is then measured as well, so that distance (state[0]) is the exact
    minimum over the pairs within reach, as ``pair_rows`` gives it; state[1] its pair (-1: none).
    It returns at the first binding row, with state[0] unset.

    fn: ``GEOM_DISTANCE``; model, data: MuJoCo's struct addresses; xpos (ngeom, 3), xmat (ngeom, 9),
    cdof (nv, 6), subtree_com (nbody, 3): MuJoCo's arrays; ints: the packed integer constants
    (``ArmClearance._pack``: header, geoms, pairs, the tree); floats: k, d_s, reach, then the
    bounding boxes, spheres and slabs; state: outputs, fromto, scratch and the cache (P pairs: d_0
    and both geoms' c_0, R_0); state[2]: the exact distances measured in this call, state[3]: those
    measured because a row could bind."""
    G, P = ints[0], ints[1]
    og, oa, ob, obody = ints[2], ints[3], ints[4], ints[8]
    t = ints[9:15]
    rate, safety, reach = floats[0], floats[1], floats[2]
    fc, fh, fr, fs = 3, 3 + 3 * G, 3 + 6 * G, 3 + 7 * G
    sf, sc, sv, sflag, sd, sp, sl = 4, 10, 10 + 3 * G, 10 + 7 * G, 10 + 8 * G, 10 + 8 * G + P, 10 + 8 * G + 25 * P
    addr = state.ctypes.data + 8 * sf
    for i in range(G):   # the bounding spheres' centres, world
        g = ints[og + i]
        for k in range(3):
            state[sc + 3 * i + k] = (xpos[g, k] + xmat[g, 3 * k] * floats[fc + 3 * i]
                                     + xmat[g, 3 * k + 1] * floats[fc + 3 * i + 1]
                                     + xmat[g, 3 * k + 2] * floats[fc + 3 * i + 2])
        state[sflag + i] = 0.0
    best, which, skipped = np.inf, -1, 0
    state[2] = 0.0
    for p in range(P):
        i, j = ints[oa + p], ints[ob + p]
        gi, gj = ints[og + i], ints[og + j]
        slab = floats[fs + p]
        if np.isnan(slab):
            gap = _box_point_gap(xpos, xmat, gi, floats[fc + 3 * i:fc + 3 * i + 3], floats[fh + 3 * i:fh + 3 * i + 3],
                                 state[sc + 3 * j], state[sc + 3 * j + 1], state[sc + 3 * j + 2]) - floats[fr + j]
            if gap < reach:
                gap = max(gap, _box_point_gap(xpos, xmat, gj, floats[fc + 3 * j:fc + 3 * j + 3],
                                              floats[fh + 3 * j:fh + 3 * j + 3], state[sc + 3 * i],
                                              state[sc + 3 * i + 1], state[sc + 3 * i + 2]) - floats[fr + i])
        else:
            gap = state[sc + 3 * i + 2] - floats[fr + i] - (xpos[gj, 2] + slab)
        if gap >= reach:
            continue
        lb = gap
        d0 = state[sd + p]
        if d0 > -np.inf:   # the cached distance, less how far either geom moved since
            c = sp + 24 * p
            for e in range(2):
                h = i if e == 0 else j
                gh = gi if e == 0 else gj
                u0 = state[sc + 3 * h] - state[c]
                u1 = state[sc + 3 * h + 1] - state[c + 1]
                u2 = state[sc + 3 * h + 2] - state[c + 2]
                rot = 0.0
                for k in range(9):
                    w = xmat[gh, k] - state[c + 3 + k]
                    rot += w * w
                d0 -= np.sqrt(u0 * u0 + u1 * u1 + u2 * u2) + np.sqrt(rot) * floats[fr + h]
                c += 12
            lb = max(lb, d0)
        if lb >= reach:
            continue
        for h in (i, j):   # the spheres' velocity bounds, once per geom and call
            if state[sflag + h] == 0.0:
                v0, v1, v2, w = _point_rate(cdof, subtree_com, ints, t, ints[obody + ints[og + h]],
                                            state[sc + 3 * h], state[sc + 3 * h + 1], state[sc + 3 * h + 2], qdot)
                state[sv + 4 * h], state[sv + 4 * h + 1], state[sv + 4 * h + 2] = v0, v1, v2
                state[sv + 4 * h + 3] = w * floats[fr + h]
                state[sflag + h] = 1.0
        r0 = state[sv + 4 * i] - state[sv + 4 * j]
        r1 = state[sv + 4 * i + 1] - state[sv + 4 * j + 1]
        r2 = state[sv + 4 * i + 2] - state[sv + 4 * j + 2]
        speed = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) + state[sv + 4 * i + 3] + state[sv + 4 * j + 3]
        if rate * (lb - safety) > speed * (1.0 + 1e-9) + 1e-12:   # cannot bind: measured below if needed
            state[sl + 2 * skipped] = p
            state[sl + 2 * skipped + 1] = lb
            skipped += 1
            continue
        best, which, binds = _closer(_exact(fn, model, data, p, ints, floats, state, xpos, xmat, cdof, subtree_com,
                                            qdot, addr, sf, sc, sp, sd), p, best, which)
        if binds:
            return 1
    first = state[2]
    for s in range(1, skipped):   # the skipped pairs by their bound, lowest first (insertion sort)
        p, lb = state[sl + 2 * s], state[sl + 2 * s + 1]
        r = s - 1
        while r >= 0 and state[sl + 2 * r + 1] > lb:
            state[sl + 2 * r + 2], state[sl + 2 * r + 3] = state[sl + 2 * r], state[sl + 2 * r + 1]
            r -= 1
        state[sl + 2 * r + 2], state[sl + 2 * r + 3] = p, lb
    for s in range(skipped):   # measure them while a bound lies below the smallest distance
        lb = state[sl + 2 * s + 1]
        if lb >= best:
            break   # the rest are no lower
        p = int(state[sl + 2 * s])
        best, which, binds = _closer(_exact(fn, model, data, p, ints, floats, state, xpos, xmat, cdof, subtree_com,
                                            qdot, addr, sf, sc, sp, sd), p, best, which)
        if binds:
            return 1
    state[0], state[1], state[3] = best, which, first
    return 0


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _closer(measured: tuple[float, bool], p: int, best: float,
            which: int) -> tuple[float, int, bool]:  # pragma: no cover
    """(best, which, binds) after measuring pair p: its distance replaces the best if smaller."""
    d, binds = measured
    return (d, p, binds) if d < best else (best, which, binds)


@numba.njit(cache=True, fastmath=False, nogil=True)
def _exact(fn: int, model: int, data: int, p: int, ints: np.ndarray, floats: np.ndarray, state: np.ndarray,
           xpos: np.ndarray, xmat: np.ndarray, cdof: np.ndarray, subtree_com: np.ndarray, qdot: np.ndarray,
           addr: int, sf: int, sc: int, sp: int, sd: int) -> tuple[float, bool]:  # pragma: no cover - compiled
    """Pair p's distance by ``mj_geomDistance`` (inf beyond reach) and whether its row of Eq. (A1)
    binds for qdot (as ``pair_rows`` writes it); refreshes the pair's cache (``guard_check``)."""
    oa, ob, o1, o2, om, obody = ints[3], ints[4], ints[5], ints[6], ints[7], ints[8]
    t = ints[9:15]
    rate, safety, reach = floats[0], floats[1], floats[2]
    g1, g2 = ints[o1 + p], ints[o2 + p]
    i, j = ints[oa + p], ints[ob + p]
    d = _call_geom_distance(fn, model, data, g1, g2, reach, addr)
    state[2] += 1.0
    c = sp + 24 * p
    for e in range(2):   # the cache: d and both geoms' sphere centres and rotations now
        h = i if e == 0 else j
        gh = g1 if e == 0 else g2
        for k in range(3):
            state[c + k] = state[sc + 3 * h + k]
        for k in range(9):
            state[c + 3 + k] = xmat[gh, k]
        c += 12
    state[sd + p] = min(d, reach)
    if d >= reach:
        return np.inf, False
    f = sf
    n0, n1, n2 = _pair_normal(state, sf, xpos, g1, g2, d)
    lhs = 0.0
    for e in range(2 if ints[om + p] else 1):
        body = ints[obody + (g1 if e == 0 else g2)]
        sign = 1.0 if e == 0 else -1.0
        v0, v1, v2, _ = _point_rate(cdof, subtree_com, ints, t, body, state[f + 3 * e], state[f + 3 * e + 1],
                                    state[f + 3 * e + 2], qdot)
        lhs += sign * (n0 * v0 + n1 * v1 + n2 * v2)
    return d, lhs > rate * (d - safety)
