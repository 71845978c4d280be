"""Whole-arm clearance: velocity dampers between every collision geom of the arm and the scene.

The field keeps the tool point out of the obstacles (``lfd.obstacles``); this module keeps the rest
of the arm out of them, out of the table and out of itself, through the IK: one velocity damper
(Faverjon and Tournassoud 1987), Eq. (A1) of docs/equations.md, per pair of geoms within the
influence distance, added to the IK QP (``robots.ik.constrained``, Eq. (A2)). ``ArmClearance.check``
decides each control step, measuring a pair with ``mj_geomDistance`` only where a certified lower
bound on its distance leaves its row able to bind, whether any damper binds for the plain IK's
joint velocities; ``ArmClearance.rows`` gives the rows where one does. The pairs: every geom an arm
joint moves against every obstacle (``obstacle_<i>``, ``sim.scene.obstacles``) and the table top (except
the links within ``SELF_SKIP`` links of the world), and the robot's geoms against each other on
bodies more than ``SELF_SKIP`` links apart, leaving out pairs within reach at the home posture.

References
----------
B. Faverjon and P. Tournassoud, "A local based approach for path planning of manipulators with a
high number of degrees of freedom", IEEE ICRA 1987, 1152-1159.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from robots.model import RobotModel
from sim.errors import SimError
from sim.scene.obstacles import PREFIX, robot_geom_ids

__all__ = ["Clearance", "ArmClearance", "TABLE_GEOM", "SELF_SKIP", "TOOL_DEPTH_M", "hand_margin_m"]

#: the table top's geom name (``robots.scene.add_table``)
TABLE_GEOM = "table_top"
#: ``hand_margin_m`` counts the tool's geometry within this distance of the tool point along its axis, m
TOOL_DEPTH_M = 0.03
#: arm bodies within this many links of each other along the chain are not checked against each other
SELF_SKIP = 3


@dataclass(frozen=True)
class Clearance:
    """safety_m: d_s, the distance every damper keeps, m; influence_m: d_i, m; rate: k, 1/s;
    self_collision: also damp arm-arm pairs."""

    safety_m: float = 0.01
    influence_m: float = 0.04
    rate: float = 20.0
    self_collision: bool = True

    def __post_init__(self) -> None:
        for name in ("safety_m", "influence_m", "rate"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise SimError(f"clearance {name} must be a finite number >= 0, got {v!r}")
        if not self.influence_m > self.safety_m:
            raise SimError(f"clearance influence_m ({self.influence_m}) must exceed safety_m ({self.safety_m})")
        if not 0 < self.rate <= 1000:
            raise SimError(f"clearance rate must be in (0, 1000] 1/s, got {self.rate}")


def _scene_geom(name: str) -> bool:
    return name.startswith(PREFIX) or name == TABLE_GEOM


def _geom_points(model: mujoco.MjModel, data: mujoco.MjData, g: int) -> np.ndarray:
    """Points, shape (P, 3), world, that bound a geom: a mesh's vertices, a box's corners, a
    sphere's, capsule's or cylinder's bounding-box corners."""
    if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
        mid = int(model.geom_dataid[g])
        local = model.mesh_vert[model.mesh_vertadr[mid]:model.mesh_vertadr[mid] + model.mesh_vertnum[mid]]
    else:
        c, h = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        local = c + h * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    return data.geom_xpos[g] + local @ data.geom_xmat[g].reshape(3, 3).T


def hand_margin_m(robot: RobotModel) -> float:
    """The hand's size around the tool point, m: the largest distance from the tool's z axis of
    the collision geometry fixed to the last moving link (the hand and fingers, not that link
    itself) that lies within ``TOOL_DEPTH_M`` of the tool point along that axis, at the home
    posture.

    A field that keeps the tool point this far from an obstacle keeps that part of the hand clear
    of it too; the rest of the arm is kept clear by the dampers (``ArmClearance``). 0 for a tool
    without collision geometry there."""
    model = robot.mj_model
    data = mujoco.MjData(model)
    data.qpos[robot.mj_qpos_adr] = robot.q_home
    mujoco.mj_kinematics(model, data)
    site = int(model.site(robot.mj_ee_site).id)
    link = int(model.site_bodyid[site])
    while link > 0 and model.body_jntnum[link] == 0:    # the last moving link
        link = int(model.body_parentid[link])
    p, rot = data.site_xpos[site], data.site_xmat[site].reshape(3, 3)

    def carried(b: int) -> bool:   # fixed below the last moving link, not that link itself
        while b > 0 and b != link:
            if model.body_jntnum[b] > 0:
                return False
            b = int(model.body_parentid[b])
        return b == link and b > 0
    best = 0.0
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        if not (model.geom_contype[g] or model.geom_conaffinity[g]) or b == link or not carried(b):
            continue
        local = (_geom_points(model, data, g) - p) @ rot       # tool frame
        near = np.abs(local[:, 2]) <= TOOL_DEPTH_M
        if near.any():
            best = max(best, float(np.max(np.linalg.norm(local[near, :2], axis=1))))
    return best


def _label(model: mujoco.MjModel, g: int) -> str:
    """A geom's name, or its body's name and index."""
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
    if name:
        return name
    return f"{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[g])) or 'body'}[{g}]"


def _chain_distance(model: mujoco.MjModel, a: int, b: int) -> int:
    """Links between bodies a and b in the kinematic tree."""
    def path(x: int) -> list[int]:
        out = [x]
        while x != 0:
            x = int(model.body_parentid[x])
            out.append(x)
        return out
    pa, pb = path(a), path(b)
    common = next(x for x in pa if x in set(pb))
    return pa.index(common) + pb.index(common)


class ArmClearance:
    """The dampers of one scene (module docstring): ``rows(data, dofs)`` at the current state.

    Parameters
    ----------
    model : mujoco.MjModel
        The scene (the robot with its obstacles and table).
    robot : RobotModel
    spec : Clearance
    """

    def __init__(self, model: mujoco.MjModel, robot: RobotModel, spec: Clearance = Clearance()) -> None:
        self.model, self.spec = model, spec
        self.dofs = np.asarray(robot.mj_dof_adr, dtype=np.intp)
        arm = robot_geom_ids(model)
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "" for g in range(model.ngeom)]
        scene = [g for g in range(model.ngeom) if _scene_geom(names[g])]
        moved = {int(model.jnt_bodyid[model.dof_jntid[d]]) for d in self.dofs}
        def moves(b: int) -> bool:   # an arm joint on the way from the world to body b
            while b > 0:
                if b in moved:
                    return True
                b = int(model.body_parentid[b])
            return False
        arm = np.array([g for g in arm if moves(int(model.geom_bodyid[g]))], dtype=int)   # the base cannot yield
        pairs: list[tuple[int, int, bool]] = []   # (arm geom, other geom, the other is on the arm)
        for o in scene:
            table = names[o] == TABLE_GEOM
            for g in arm:
                if table and _chain_distance(model, int(model.geom_bodyid[g]), 0) <= SELF_SKIP:
                    continue                          # the links next to the base stand on the table
                pairs.append((int(g), o, False))
        data = mujoco.MjData(model)
        data.qpos[robot.mj_qpos_adr] = robot.q_home
        mujoco.mj_forward(model, data)
        if spec.self_collision:
            fromto = np.zeros(6)
            every = robot_geom_ids(model)   # the base too, as the other member of a pair
            for i, g in enumerate(every):
                for h in every[i + 1:]:
                    if not (moves(int(model.geom_bodyid[g])) or moves(int(model.geom_bodyid[h]))):
                        continue
                    if not moves(int(model.geom_bodyid[g])):
                        g, h = h, g
                    if (_chain_distance(model, int(model.geom_bodyid[g]), int(model.geom_bodyid[h])) > SELF_SKIP
                            and mujoco.mj_geomDistance(model, data, int(g), int(h), spec.influence_m, fromto)
                            >= spec.influence_m):
                        pairs.append((int(g), int(h), True))
        self.pairs = pairs
        self.names = [_label(model, g) for g in range(model.ngeom)]
        geoms = sorted({g for p in pairs for g in p[:2]})
        self._geoms = np.array(geoms, dtype=np.int64)
        slot = {g: i for i, g in enumerate(geoms)}
        self._a = np.array([slot[p[0]] for p in pairs], dtype=np.int64)
        self._b = np.array([slot[p[1]] for p in pairs], dtype=np.int64)
        self._slab = np.array([model.geom_size[p[1], 2] if names[p[1]] == TABLE_GEOM else np.nan for p in pairs])
        aabb = model.geom_aabb[self._geoms] if geoms else np.zeros((0, 6))
        self._centre = np.ascontiguousarray(aabb[:, :3])
        self._half = np.ascontiguousarray(aabb[:, 3:])
        self._radius = np.ascontiguousarray(np.linalg.norm(aabb[:, 3:], axis=1))
        self._idx = np.zeros(len(pairs), dtype=np.int64)
        self._body = np.ascontiguousarray(model.geom_bodyid, dtype=np.int64)
        self._column = np.full(model.nv, -1, dtype=np.int64)
        self._column[self.dofs] = np.arange(len(self.dofs))
        self._tree = (np.ascontiguousarray(model.body_rootid, dtype=np.int64),
                      np.ascontiguousarray(model.body_dofnum, dtype=np.int64),
                      np.ascontiguousarray(model.body_dofadr, dtype=np.int64),
                      np.ascontiguousarray(model.body_parentid, dtype=np.int64),
                      np.ascontiguousarray(model.dof_parentid, dtype=np.int64))
        self._fromto = np.zeros(6)
        self._kernels = _kernels()
        self._fn = self._kernels[3]
        self._g1 = np.array([p[0] for p in pairs], dtype=np.int64)
        self._g2 = np.array([p[1] for p in pairs], dtype=np.int64)
        self._mutual = np.array([p[2] for p in pairs], dtype=np.bool_)
        self._A = np.empty((len(pairs), len(self.dofs)))
        self._d = np.empty(len(pairs))
        self._which = np.zeros(len(pairs), dtype=np.int64)
        self._no_rows = (np.zeros((0, len(self.dofs))), np.zeros(0))
        self._ints, self._floats, self._state = self._pack(model)
        self._bound: tuple[Any, ...] | None = None
        self.reset()
        self.min_distance = math.inf
        self._closest: tuple[int, int] | None = None
        self.rows(data)   # compile the kernels now, not in a run's first step
        self.check(data, np.zeros(len(self.dofs)))
        self.reset()

    def _pack(self, model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The constants and state of ``sim.scene._collision_kernel.guard_check``: ints (the header
        G, P and the offsets of the geoms (G,), the pairs' a, b, g1, g2 and mutual (P,), the geoms'
        bodies (ngeom,) and the tree: body_rootid, body_dofnum, body_dofadr, body_parentid (nbody,),
        dof_parentid and the arm column of each dof (nv,)), floats (k, d_s, d_i, the bounding
        boxes' centres and half sizes (G, 3), the spheres' radii (G,), the slab tops (P,)) and the
        state (outputs, fromto (6,), scratch, the cache: d_0 (P,), c_0 and R_0 of both geoms
        (P, 24), the skipped pairs (P, 2))."""
        G, P = len(self._geoms), len(self.pairs)
        parts = [self._geoms, self._a, self._b, self._g1, self._g2, self._mutual.astype(np.int64), self._body,
                 *self._tree[:4], self._tree[4], self._column]
        offsets, at = [], 15
        for part in parts:
            offsets.append(at)
            at += len(part)
        body_off = offsets[6]
        header = np.array([G, P, *offsets[:6], body_off, *offsets[7:13]], dtype=np.int64)
        ints = np.concatenate([header, *[np.asarray(x, dtype=np.int64) for x in parts]])
        spec = self.spec
        floats = np.concatenate([[spec.rate, spec.safety_m, spec.influence_m], self._centre.ravel(),
                                 self._half.ravel(), self._radius, self._slab]).astype(np.float64)
        state = np.zeros(10 + 8 * G + 27 * P)
        return ints, floats, state

    def reset(self) -> None:
        """Forget the cached distances of ``check`` (none is needed for its bounds to hold; a new
        run starts with an empty cache) and ``min_distance``."""
        G, P = len(self._geoms), len(self.pairs)
        self._state[10 + 8 * G:10 + 8 * G + P] = -np.inf
        self.min_distance, self._closest = math.inf, None

    @property
    def n_pairs(self) -> int:
        """The number of pairs checked."""
        return len(self.pairs)

    def candidates(self, data: mujoco.MjData) -> np.ndarray:
        """Indices of the pairs whose broad-phase bound (module docstring) lies within d_i, shape (c,)."""
        if not self.pairs:
            return self._idx[:0]
        count = self._kernels[0](data.geom_xpos, data.geom_xmat, self._geoms, self._centre, self._half,
                                 self._radius, self._a, self._b, self._slab, self.spec.influence_m, self._idx)
        return self._idx[:count]

    def check(self, data: mujoco.MjData, qdot: np.ndarray) -> bool:
        """Whether a damper row binds for the joint velocities qdot, shape (n,), at the state of
        ``data`` (kinematics and ``mj_comPos`` current): True if some pair within d_i has
        n^T (J_1 - J_2) qdot > k (d - d_s), Eq. (A1), exactly as for the rows of ``rows(data)``.

        Cheaper than ``rows``: a pair's exact distance (``mj_geomDistance``) is computed only
        where a certified lower bound on it (the broad phase's, or the distance cached at an earlier
        call less how far either geom has moved since) leaves its row able to bind for this qdot
        (``sim.scene._collision_kernel.guard_check``). Without a binding row it sets ``min_distance`` and
        ``closest`` as ``rows`` does (pairs whose bound lies below the smallest exact distance are
        measured too, so the minimum is exact); with one it leaves them, and the caller takes
        ``rows(data)`` for the QP."""
        if not self.pairs:
            self.min_distance, self._closest = math.inf, None
            return False
        b = self._bound
        if b is None or b[0] is not data:
            b = self._bound = (data, data._address, data.geom_xpos, data.geom_xmat, data.cdof, data.subtree_com)
        st = self._state
        if self._kernels[2](self._fn, self.model._address, b[1], b[2], b[3], b[4], b[5], qdot, self._ints,
                            self._floats, st):
            return True
        self.min_distance = float(st[0])
        self._closest = None if st[1] < 0 else self.pairs[int(st[1])][:2]
        return False

    @property
    def closest(self) -> str:
        """The geom names of the pair at ``min_distance`` in the last ``rows`` or ``check`` call ("" if none)."""
        if self._closest is None:
            return ""
        return f"{self.names[self._closest[0]]} / {self.names[self._closest[1]]}"

    def rows(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """(A (k, n), b (k,)): one damper per pair within d_i at the state of ``data``, whose
        kinematics (``mj_step1``, or ``mj_forward``) are current. Sets ``min_distance`` (the
        smallest d met, inf if none within d_i) and ``closest`` (that pair's geom names)."""
        spec = self.spec
        cand = self.candidates(data)
        if not cand.size:
            self.min_distance, self._closest = math.inf, None
            return self._no_rows
        count = self._kernels[1](self._fn, self.model._address, data._address, cand, cand.size, self._g1, self._g2,
                                 self._mutual, spec.influence_m, data.geom_xpos, self._body, data.cdof,
                                 data.subtree_com, *self._tree, self._column, self._fromto, self._A, self._d,
                                 self._which)
        if not count:
            self.min_distance, self._closest = math.inf, None
            return self._no_rows
        dd = self._d[:count]
        j = int(np.argmin(dd))
        self.min_distance = float(dd[j])
        self._closest = self.pairs[int(self._which[j])][:2]
        return self._A[:count].copy(), spec.rate * (dd - spec.safety_m)


@functools.cache
def _kernels() -> tuple[Any, Any, Any, int]:
    """(broadphase, pair_rows, guard_check, the address of ``mj_geomDistance``) of
    ``sim.scene._collision_kernel`` (numba is imported on first use)."""
    from sim.scene._collision_kernel import GEOM_DISTANCE, broadphase, guard_check, pair_rows

    return broadphase, pair_rows, guard_check, GEOM_DISTANCE
