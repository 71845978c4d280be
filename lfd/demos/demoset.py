"""The demo set: N demos of T samples in d dimensions, validated once, and resampling to one length.

A set is validated at construction: finite values, at least ``MIN_SAMPLES`` samples, strictly
increasing times, one dimension, motion. A set of poses also holds unit quaternions (w, x, y, z)
beside 3-D positions in metres: each near-unit quaternion is renormalised, each sequence made
continuous (q and -q are one orientation), and every orientation must lie within
``MAX_TURN_FROM_GOAL`` of the goal orientation. The demos may end apart: ``goal`` is the mean end
point, ``ends`` the end point of each.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lfd.demos.smoothing import smoothed_velocity
from lfd.errors import DemoError
from lfd.rotations import UNIT_TOLERANCE, continuous, geodesic_angle, mean_quaternion, quaternion_matrices, slerp

MIN_SAMPLES = 10
MIN_TIME_STEP = 1e-9  # s: finer steps are not a recording of a motion (times scaled by mistake)
MAX_DURATION = 1e6    # s (11 days): a longer demo is not a recording of a motion either
MOTION_TOLERANCE = 1e-9   # a demo whose extent is below this fraction of its coordinates' size does not move
GOAL_TOLERANCE = 0.05  # end points further than this fraction of the extent from their mean are spread
GOAL_ANGLE_TOLERANCE = 45.0   # degrees: final orientations further than this from their mean are spread
MAX_TURN_FROM_GOAL = 170.0    # degrees: every orientation of a pose demo must lie within this of the goal's
MAX_DIM = 32          # task dimensions a demo set may have (2-D and 3-D paths, 6-D pose charts, stacked sets)


@dataclass(frozen=True)
class DemoSet:
    """N demonstrations of T samples in d dimensions.

    t : array, shape (N, T)     -- times, strictly increasing per demo
    x : array, shape (N, T, d)  -- positions
    name : str                  -- where the demos came from (used in error messages)
    q : array, shape (N, T, 4), optional -- orientations, unit quaternions (w, x, y, z), for a set
        of poses (then d = 3, positions in metres); stored renormalised and continuous
    frame : str, optional       -- the robot frame the poses were recorded in (the arm's tool frame
        to run them with, unless the user names one)
    end_tolerance : float       -- kept for compatibility; demos that end apart are accepted
        (``lfd.demos.recording`` notes a spread beyond ``GOAL_TOLERANCE``)
    notes : tuple of str        -- what was done to the recording while loading it, one line each
        (``lfd.demos.recording``; the ``lfd`` command prints them)
    goal : array, shape (d,)    -- the mean end point
    goal_q : array, shape (4,), or None -- the mean final orientation (``lfd.rotations.mean_quaternion``)
    """

    t: np.ndarray
    x: np.ndarray
    name: str = "demos"
    q: np.ndarray | None = None
    frame: str | None = None
    end_tolerance: float = field(default=GOAL_TOLERANCE, repr=False)
    notes: tuple[str, ...] = field(default=(), repr=False)
    xd: np.ndarray = field(init=False, repr=False)
    goal: np.ndarray = field(init=False)
    goal_q: np.ndarray | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64)
        x = np.asarray(self.x, dtype=np.float64)
        if x.ndim == 2:
            x = x[None]
        if t.ndim == 1:
            t = np.broadcast_to(t, x.shape[:2]).copy()
        _validate(t, x, self.name)
        if self.q is not None:
            q, goal_q = _orientations(np.asarray(self.q), x.shape, self.name)
            object.__setattr__(self, "q", q)
            object.__setattr__(self, "goal_q", goal_q)
        xd = _velocities(t, x, self.name)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "xd", xd)
        object.__setattr__(self, "goal", x[:, -1].mean(axis=0))
        object.__setattr__(self, "notes", tuple(str(n) for n in self.notes))

    @property
    def has_orientation(self) -> bool:
        """Whether the set holds poses (positions and orientations)."""
        return self.q is not None

    @property
    def n_demos(self) -> int:
        return int(self.x.shape[0])

    @property
    def n_samples(self) -> int:
        return int(self.x.shape[1])

    @property
    def dim(self) -> int:
        return int(self.x.shape[2])

    @property
    def ends(self) -> np.ndarray:
        """The end point of each demo, shape (N, d) (``goal`` is their mean)."""
        return self.x[:, -1]

    @property
    def end_q(self) -> np.ndarray | None:
        """The final orientation of each demo, shape (N, 4) (w, x, y, z), or None for positions
        (``goal_q`` is their Karcher mean)."""
        return None if self.q is None else self.q[:, -1]

    def subset(self, idx: list[int] | np.ndarray) -> DemoSet:
        """The demos at indices ``idx`` as a new set, with this set's notes."""
        idx = np.asarray(idx, dtype=int)
        return DemoSet(self.t[idx], self.x[idx], name=self.name, q=None if self.q is None else self.q[idx],
                       frame=self.frame, end_tolerance=self.end_tolerance, notes=self.notes)

    def bounds(self, grow: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box (lo, hi), each shape (d,), grown by ``grow`` times its size."""
        lo, hi = self.x.reshape(-1, self.dim).min(0), self.x.reshape(-1, self.dim).max(0)
        pad = (hi - lo) * grow / 2
        return lo - pad, hi + pad

    @property
    def extent(self) -> float:
        """The larger side of the demos' bounding box, user units (docs/glossary.md)."""
        lo, hi = self.bounds()
        return float(np.max(hi - lo))


def _validate(t: np.ndarray, x: np.ndarray, name: str) -> None:
    if x.ndim != 3:
        raise DemoError(f"{name}: positions must have shape (N, T, d), got {x.shape}")
    n, T, d = x.shape
    if n == 0:
        raise DemoError(f"{name}: no demonstrations")
    if not 2 <= d <= MAX_DIM:
        raise DemoError(f"{name}: demos must have 2 to {MAX_DIM} dimensions, got d={d}")
    if t.shape != (n, T):
        raise DemoError(f"{name}: times have shape {t.shape}, expected {(n, T)}")
    if T < MIN_SAMPLES:
        raise DemoError(f"{name}: {T} samples per demo, at least {MIN_SAMPLES} are needed")
    _check_values(t, x, name)


def check_demo(t: np.ndarray, x: np.ndarray, q: np.ndarray | None, name: str, index: int) -> None:
    """Refuse one raw demo, before any clean-up, for what a ``DemoSet`` refuses, with the same one-line
    ``DemoError`` naming it ``demo <index>``.

    Parameters
    ----------
    t : array, shape (T,)
        Times [s].
    x : array, shape (T, d)
        Positions.
    q : array, shape (T, 4), or None
        Orientations (w, x, y, z) of a pose demo.
    name, index : str, int
        The set's name and the demo's index, for the messages.
    """
    if x.ndim != 2 or t.shape != x.shape[:1]:
        raise DemoError(f"{name}: demo {index} has times of shape {t.shape} and positions of shape {x.shape}, "
                        "expected (T,) and (T, d)")
    if not 2 <= x.shape[1] <= MAX_DIM:
        raise DemoError(f"{name}: demos must have 2 to {MAX_DIM} dimensions, got d={x.shape[1]}")
    if len(t) < MIN_SAMPLES:
        raise DemoError(f"{name}: demo {index} has {len(t)} samples, at least {MIN_SAMPLES} are needed")
    _check_values(t[None], x[None], name, index)
    if q is not None:
        _check_quaternions(q[None], (1, *x.shape), name, index)
    _velocities(t[None], x[None], name, index)


def _velocities(t: np.ndarray, x: np.ndarray, name: str, first: int = 0) -> np.ndarray:
    """The velocities xd (N, T, d) of demos t (N, T), x (N, T, d) (``smoothed_velocity``), refused with
    one line when they overflow; demos named from ``first`` on."""
    with np.errstate(all="ignore"):
        xd = np.stack([smoothed_velocity(ti, xi) for ti, xi in zip(t, x)])
        speed2 = np.sum(xd * xd, axis=-1)
    if not np.isfinite(speed2).all():
        i = first + int(np.argmax(~np.isfinite(speed2).all(axis=1)))
        raise DemoError(f"{name}: the velocities of demo {i} overflow (positions or times "
                        "out of range); give positions in metres or millimetres and times in seconds")
    return xd


def _check_values(t: np.ndarray, x: np.ndarray, name: str, first: int = 0) -> None:
    """The checks of the values of demos t (N, T), x (N, T, d), named from demo ``first`` on."""
    d = x.shape[2]
    bad = ~np.isfinite(x).all(axis=(1, 2)) | ~np.isfinite(t).all(axis=1)
    if bad.any():
        raise DemoError(f"{name}: NaN or inf in demo {first + int(np.argmax(bad))}")
    with np.errstate(all="ignore"):
        steps = np.diff(t, axis=1)
    if (steps <= 0).any() or not np.isfinite(steps).all():
        i, k = np.argwhere(~(steps > 0) | ~np.isfinite(steps))[0]
        raise DemoError(f"{name}: time is not increasing in demo {first + i} at sample {k + 1} "
                        f"(t={t[i, k + 1]:g} after {t[i, k]:g})")
    if steps.min() < MIN_TIME_STEP:
        i, k = np.unravel_index(int(np.argmin(steps)), steps.shape)
        raise DemoError(f"{name}: time step of {steps[i, k]:.3g} s in demo {first + i} at sample {k + 1}, "
                        f"below {MIN_TIME_STEP:g} s; times must be in seconds")
    duration = float(np.max(t[:, -1] - t[:, 0]))
    if duration > MAX_DURATION:
        raise DemoError(f"{name}: a demo lasts {duration:.3g} s, more than {MAX_DURATION:g} s; "
                        "times must be in seconds")
    with np.errstate(all="ignore"):
        extent = float(np.max(x.reshape(-1, d).max(0) - x.reshape(-1, d).min(0)))
    if not np.isfinite(extent):
        raise DemoError(f"{name}: positions out of range (their extent overflows)")
    _check_motion(x, name, first)


def _orientations(q: np.ndarray, shape: tuple[int, ...], name: str) -> tuple[np.ndarray, np.ndarray]:
    """The validated orientations of a pose set: (q (N, T, 4) renormalised and continuous, the mean
    final orientation (4,)); ``DemoError`` with one line for anything that is not a rotation."""
    q, norm, off = _check_quaternions(q, shape, name)
    # renormalise those not unit to round-off (so a stored set reads back bit for bit)
    near = off <= 8 * np.finfo(np.float64).eps
    q = np.stack([continuous(qi) for qi in np.where(near[..., None], q, q / norm[..., None])])
    goal_q = mean_quaternion(q[:, -1])
    goal = quaternion_matrices(goal_q)
    # the poses are learned in the chart at the goal orientation (lfd.pose), which holds orientations
    # less than a half turn from it: a demo that turns further would jump across the chart
    away = np.degrees(geodesic_angle(goal, quaternion_matrices(q)))                 # (N, T)
    if away.max() > MAX_TURN_FROM_GOAL:
        i, k = np.unravel_index(int(np.argmax(away)), away.shape)
        raise DemoError(f"{name}: demo {i} turns {away[i, k]:.1f} deg away from the goal orientation at sample "
                        f"{k}; poses are learned within {MAX_TURN_FROM_GOAL:g} deg of it (a half turn is the "
                        "chart's edge)")
    return q, goal_q


def _check_quaternions(q: np.ndarray, shape: tuple[int, ...], name: str, first: int = 0
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quaternions q (N, T, 4) of demos of positions ``shape`` (N, T, d), named from demo ``first`` on,
    checked: real, finite, near unit. Returns (q as float64, its norms (N, T), |norm - 1| (N, T))."""
    n, T, d = shape
    if np.iscomplexobj(q) or q.dtype.kind not in "iuf":
        raise DemoError(f"{name}: quaternions must hold real numbers, got dtype {q.dtype}")
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (n, T, 4):
        raise DemoError(f"{name}: quaternions have shape {q.shape}, expected {(n, T, 4)} (w, x, y, z)")
    if d != 3:
        raise DemoError(f"{name}: poses need 3-D positions, got d={d}")
    bad = ~np.isfinite(q).all(axis=(1, 2))
    if bad.any():
        raise DemoError(f"{name}: NaN or inf in the quaternions of demo {first + int(np.argmax(bad))}")
    with np.errstate(all="ignore"):   # a huge quaternion overflows its norm: refused below, silently
        norm = np.linalg.norm(q, axis=-1)
        off = np.abs(norm - 1.0)
    if not np.isfinite(off).all():
        i, k = np.argwhere(~np.isfinite(off))[0]
        raise DemoError(f"{name}: quaternion of demo {first + i} at sample {k} is out of range, not a rotation")
    if off.max() > UNIT_TOLERANCE:
        i, k = np.unravel_index(int(np.argmax(off)), off.shape)
        raise DemoError(f"{name}: quaternion of demo {first + i} at sample {k} has norm {norm[i, k]:.4g}, not a "
                        f"rotation (more than {UNIT_TOLERANCE:g} from 1)")
    return q, norm, off


def check_motion(x: np.ndarray, name: str = "demos") -> None:
    """Refuse demonstrations that do not move: ``DemoError`` with one line when a demo's samples
    are all at one point (its extent, the largest range of a coordinate over its samples, is at
    most ``MOTION_TOLERANCE`` times the size of its coordinates, or 1 if that is smaller).

    Parameters
    ----------
    x : array, shape (N, T, d)
        The demos' positions.
    name : str
        The demos' name, for the message.

    Raises
    ------
    DemoError
        ``<name>: demo <i> does not move (all its <T> samples are at one point); a demonstration
        must move to its goal``.
    """
    _check_motion(x, name)


def _check_motion(x: np.ndarray, name: str, first: int = 0) -> None:
    pos = np.asarray(x, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[1] == 0:
        return
    with np.errstate(all="ignore"):
        extent = np.ptp(pos, axis=1).max(axis=-1)                       # (N,)
        size = np.maximum(np.abs(pos).max(axis=(1, 2)), 1.0)
    still = np.flatnonzero(extent <= MOTION_TOLERANCE * size)
    if len(still):
        raise DemoError(f"{name}: demo {first + int(still[0])} does not move (all its {pos.shape[1]} samples are "
                        "at one point); a demonstration must move to its goal")


def resample(ts: list[np.ndarray], xs: list[np.ndarray], qs: list[np.ndarray] | None, name: str
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Demos of different lengths on one length, the longest T: each demo's times (T_i,), positions
    (T_i, d) and quaternions (T_i, 4) (or None), uniformly resampled over its own time span, positions
    linearly, orientations by Slerp; a demo already of length T is kept as it is (bit for bit).
    Returns t (N, T), x (N, T, d), q (N, T, 4) or None."""
    T = max(len(t) for t in ts)
    to, xo, qo = [], [], []
    for i, (t, x) in enumerate(zip(ts, xs)):
        q = None if qs is None else qs[i]
        if len(t) != T:
            tn = np.linspace(t[0], t[-1], T)
            x = np.stack([np.interp(tn, t, x[:, j]) for j in range(x.shape[1])], axis=1)
            if q is not None:
                with np.errstate(all="ignore"):
                    off = np.abs(np.linalg.norm(q, axis=1) - 1.0)
                if not (off <= UNIT_TOLERANCE).all():    # refused as DemoSet refuses it, before Slerp
                    k = int(np.argmax(~(off <= UNIT_TOLERANCE)))
                    raise DemoError(f"{name}: quaternion of demo {i} at sample {k} has norm "
                                    f"{float(np.linalg.norm(q[k])):.4g}, not a rotation "
                                    f"(more than {UNIT_TOLERANCE:g} from 1)")
                q = slerp(t, q, tn)
            t = tn
        to.append(t)
        xo.append(x)
        if q is not None:
            qo.append(q)
    return np.stack(to), np.stack(xo), (np.stack(qo) if qs is not None else None)
