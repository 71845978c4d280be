"""Compiled hot paths of ``sim.collision``: the broad phase over all pairs, and the rows of
Eq. (A1): MuJoCo's ``mj_geomDistance`` called from numba through ctypes for each candidate pair,
and n^T J(p) of MuJoCo's translational Jacobian at a point (written over ``cdof`` as MuJoCo's
``mj_jac`` does).

Imported lazily by ``sim.collision``; ``cache=True`` keeps the machine code beside this file.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np


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


def _geom_distance() -> Any:
    """MuJoCo's ``mj_geomDistance`` from its shared library, as a ctypes function numba can call.

    The model and data pointers and the fromto buffer pass as ``size_t`` addresses (the same
    register as a pointer on every 64-bit ABI MuJoCo ships for)."""
    import ctypes
    import glob
    import os

    import mujoco

    libs = sorted(glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*"))
                  + glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco*.dylib")))
    if not libs or ctypes.sizeof(ctypes.c_void_p) != 8:
        from sim.errors import SimError

        raise SimError("whole-arm clearance needs the 64-bit MuJoCo shared library beside the mujoco package")
    fn = ctypes.CDLL(libs[0]).mj_geomDistance
    fn.argtypes = (ctypes.c_size_t, ctypes.c_size_t, ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_size_t)
    fn.restype = ctypes.c_double
    return fn


mj_geom_distance = _geom_distance()


@numba.njit(cache=False, fastmath=False, nogil=True)
def pair_rows(model: int, data: int, cand: np.ndarray, count: int, g1: np.ndarray, g2: np.ndarray,
              mutual: np.ndarray, reach: float, geom_xpos: np.ndarray, geom_body: np.ndarray, cdof: np.ndarray,
              subtree_com: np.ndarray, body_rootid: np.ndarray, body_dofnum: np.ndarray, body_dofadr: np.ndarray,
              body_parentid: np.ndarray, dof_parentid: np.ndarray, column: np.ndarray, fromto: np.ndarray,
              A: np.ndarray, dist: np.ndarray, which: np.ndarray) -> int:  # pragma: no cover - compiled
    """The damper rows of the candidate pairs cand[:count] (``sim.collision``): for each pair
    within ``reach`` write its row n^T (J(p1) - J(p2)) into A[k], its distance into dist[k] and its
    index into which[k]; return k. ``model``, ``data``: MuJoCo's struct addresses; fromto (6,)."""
    k = 0
    addr = fromto.ctypes.data
    n = np.empty(3)
    p1 = np.empty(3)
    p2 = np.empty(3)
    for c in range(count):
        i = cand[c]
        d = mj_geom_distance(model, data, g1[i], g2[i], reach, addr)
        if d >= reach:
            continue
        u0, u1, u2 = fromto[3] - fromto[0], fromto[4] - fromto[1], fromto[5] - fromto[2]
        norm = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        if norm < 1e-9:   # touching: the direction between the geoms' centres
            a, b = g1[i], g2[i]
            u0 = geom_xpos[b, 0] - geom_xpos[a, 0]
            u1 = geom_xpos[b, 1] - geom_xpos[a, 1]
            u2 = geom_xpos[b, 2] - geom_xpos[a, 2]
            norm = max(np.sqrt(u0 * u0 + u1 * u1 + u2 * u2), 1e-12)
        s = (1.0 if d >= 0.0 else -1.0) / norm
        n[0], n[1], n[2] = u0 * s, u1 * s, u2 * s
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
