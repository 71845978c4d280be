"""Rotations as unit quaternions (w, x, y, z) and matrices: conversions, continuity, the Karcher mean,
the geodesic angle and spherical interpolation.

Quaternions are scalar first, as in the data sets; q and -q are the same orientation (the double
cover S^3 -> SO(3)). Conversions use SciPy's ``Rotation``, the mean Pinocchio's ``log3`` and ``exp3``;
both are imported on first use, so that importing this module (and ``lfd.demos``) stays cheap. The
log chart built on these maps is ``lfd.pose``; this module imports nothing from ``lfd``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: a quaternion whose norm is further than this from 1 is not a rotation (a near one is renormalised)
UNIT_TOLERANCE = 0.01
#: metres per radian by which a turn weighs against a translation (the pose chart's l, ``lfd.pose``,
#: Eq. (P1)): one degree weighs as much as 1.75 mm
ROTATION_LENGTH = 0.1


def _scipy() -> Any:
    """SciPy's ``scipy.spatial.transform`` (``Rotation``, ``Slerp``), imported on first use: it takes
    a noticeable part of a second, which ``import lfd.demos`` need not pay."""
    from scipy.spatial import transform

    return transform


def quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions (w, x, y, z): q of shape (..., 4) -> shape (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    flat = q.reshape(-1, 4)
    if not len(flat):
        return np.zeros(q.shape[:-1] + (3, 3))
    return _scipy().Rotation.from_quat(flat, scalar_first=True).as_matrix().reshape(q.shape[:-1] + (3, 3))


def matrix_quaternions(rot: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) with w >= 0 of rotation matrices: (..., 3, 3) -> (..., 4)."""
    rot = np.asarray(rot, dtype=np.float64)
    flat = rot.reshape(-1, 3, 3)
    if not len(flat):
        return np.zeros(rot.shape[:-2] + (4,))
    out = _scipy().Rotation.from_matrix(flat).as_quat(canonical=True, scalar_first=True)
    return out.reshape(rot.shape[:-2] + (4,))


def continuous(q: np.ndarray) -> np.ndarray:
    """q, shape (T, 4), with signs flipped so that consecutive quaternions have q_k . q_(k-1) >= 0
    (q and -q are one orientation: the sequence becomes continuous on S^3)."""
    q = np.array(q, dtype=np.float64)
    flips = np.cumsum(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0) % 2
    q[1:][flips == 1] *= -1.0
    return q


def mean_quaternion(q: np.ndarray, iterations: int = 50) -> np.ndarray:
    """The Karcher (geodesic) mean of unit quaternions, q of shape (K, 4): the rotation R_m with
    sum_i log(R_m^T R_i) = 0, found by R_m <- R_m exp(mean_i log(R_m^T R_i)) from the chordal mean (the
    eigenvector of sum q q^T with the largest eigenvalue); w >= 0; shape (4,). So the chart at the
    mean (``lfd.pose``, Eq. (P1)) puts the mean of the rotation coordinates at 0, to round-off."""
    import pinocchio as pin  # slow to import: only sets of poses need it, when they are built

    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    _, vecs = np.linalg.eigh(q.T @ q)
    rm = quaternion_matrices(vecs[:, -1])
    rots = quaternion_matrices(q)
    for _ in range(iterations):
        step = np.mean([pin.log3(rm.T @ r) for r in rots], axis=0)
        rm = rm @ pin.exp3(step)
        if float(np.linalg.norm(step)) < 1e-15:
            break
    return matrix_quaternions(rm)


def geodesic_angle(r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """angle(R_1, R_2) = |log(R_1^T R_2)| [rad] (Eq. (P4) of docs/equations.md): rotations of shape
    (..., 3, 3) -> shape (...)."""
    rel = np.einsum("...ji,...jk->...ik", np.asarray(r1, dtype=np.float64), np.asarray(r2, dtype=np.float64))
    c = np.clip(0.5 * (np.trace(rel, axis1=-2, axis2=-1) - 1.0), -1.0, 1.0)
    s = 0.5 * np.linalg.norm(np.stack([rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0],
                                       rel[..., 1, 0] - rel[..., 0, 1]], axis=-1), axis=-1)
    return np.arctan2(s, c)


def slerp(t: np.ndarray, q: np.ndarray, tn: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of the orientations q (T, 4) (w, x, y, z), near unit, at times t
    (T,) increasing, to the times tn (M,) within [t[0], t[-1]]: shape (M, 4) (SciPy's ``Slerp``; each
    quaternion is normalised first)."""
    transform = _scipy()
    rot = transform.Rotation.from_quat(q / np.linalg.norm(q, axis=1)[:, None], scalar_first=True)
    return transform.Slerp(t, rot)(tn).as_quat(scalar_first=True)


def rotation_vectors(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """log(R_ref^T R(q)) [rad], the rotation vectors of the unit quaternions q (..., 4) seen from the
    reference orientation ref (4,): shape (..., 3); |r| is the geodesic angle from ref (below pi)."""
    rotation = _scipy().Rotation
    q = np.asarray(q, dtype=np.float64)
    flat = rotation.from_quat(q.reshape(-1, 4), scalar_first=True)
    rel = rotation.from_quat(np.asarray(ref, dtype=np.float64), scalar_first=True).inv() * flat
    return rel.as_rotvec().reshape(q.shape[:-1] + (3,))


def from_rotation_vectors(r: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """The inverse of ``rotation_vectors``: R = R_ref exp(r), r (..., 3) -> unit quaternions (..., 4)
    (w, x, y, z), not sign-continuous (``continuous`` makes a sequence so)."""
    rotation = _scipy().Rotation
    r = np.asarray(r, dtype=np.float64)
    rot = rotation.from_quat(np.asarray(ref, dtype=np.float64), scalar_first=True) * rotation.from_rotvec(
        r.reshape(-1, 3))
    return rot.as_quat(scalar_first=True).reshape(r.shape[:-1] + (4,))
