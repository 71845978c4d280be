"""Kinesthetic recordings as people make them, generated for the tests of ``lfd.demos.recording``.

A recording is the tool's pose sampled at ``rate`` Hz: standing still for ``rest_start`` s, a
minimum-jerk reach of ``motion_s`` s along a bent path (30 cm across, 8 cm of bend) while turning
60 degrees, optionally stopping halfway for ``pause_s`` s, then standing still for ``rest_end`` s;
white noise on positions (m) and orientations (deg) if asked. ``write`` stores recordings as CSV,
NPZ (one array per demo: t0, x0, q0, t1, ...) or one MCAP bag, the demos 100 s apart;
``write_positions`` stores demos of positions alone (CSV demo,t,x1..xd or NPZ t0, x0, ...).
``ode_spiral`` is torchdiffeq's example spiral, a motion that slows down without ever stopping.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from bag_writer import BASE_NS, POSE, STORES, pose, write_bag
from scipy.spatial.transform import Rotation

DEMO_NS = 100 * 10**9             # demo i of a bag starts at BASE_NS + i DEMO_NS
TURN_DEG = 60.0
AXIS = np.array([0.2, 0.3, 1.0]) / np.linalg.norm([0.2, 0.3, 1.0])


@dataclass(frozen=True)
class Recording:
    """One demo: t (T,) s, x (T, 3) m, q (T, 4) (w, x, y, z)."""

    t: np.ndarray
    x: np.ndarray
    q: np.ndarray

    def drop(self, t0: float, t1: float) -> Recording:
        """Without the samples at times in [t0, t1) (a recorder that missed them)."""
        keep = (self.t < t0) | (self.t >= t1)
        return Recording(self.t[keep], self.x[keep], self.q[keep])

    def moved(self, after: float, dx: np.ndarray) -> Recording:
        """With the positions at times from ``after`` on moved by dx (3,) (a jump)."""
        return Recording(self.t, np.where((self.t >= after)[:, None], self.x + dx, self.x), self.q)

    def delayed(self, after: float, dt: float) -> Recording:
        """With the times from ``after`` on later by dt (a recorder that stopped while the arm did too)."""
        return Recording(np.where(self.t >= after, self.t + dt, self.t), self.x, self.q)


def _min_jerk(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return 10 * u**3 - 15 * u**4 + 6 * u**5


def progress(t: np.ndarray, rest_start: float, motion_s: float, pause_s: float) -> np.ndarray:
    """s(t) in [0, 1]: 0 while standing still, a minimum-jerk reach (in two halves around a pause), 1 after."""
    u = t - rest_start
    if pause_s <= 0:
        return _min_jerk(u / motion_s)
    half = motion_s / 2
    later = 0.5 + 0.5 * _min_jerk((u - half - pause_s) / half)
    return np.where(u < half + pause_s / 2, 0.5 * _min_jerk(u / half), later)


def kinesthetic(rate: float = 100.0, rest_start: float = 0.0, rest_end: float = 0.0, motion_s: float = 3.0,
                pause_s: float = 0.0, noise_m: float = 0.0, noise_deg: float = 0.0, seed: int = 0,
                end: tuple[float, float, float] = (0.5, 0.0, 0.3), turn_deg: float = 0.0) -> Recording:
    """One recorded demo (the module's docstring); ``turn_deg`` turns the whole demo about z."""
    rng = np.random.default_rng(seed)
    t = np.arange(round((rest_start + motion_s + pause_s + rest_end) * rate) + 1) / rate
    s = progress(t, rest_start, motion_s, pause_s)[:, None]
    goal = np.asarray(end, dtype=np.float64)
    start = goal + [-0.3, 0.1, 0.15]
    x = start + s * (goal - start) + np.sin(np.pi * s) * [0.0, 0.08, 0.0]
    x = x + rng.normal(0.0, noise_m, x.shape)
    turning = Rotation.from_rotvec(np.radians(TURN_DEG) * (s - 1) * AXIS)
    rot = Rotation.from_euler("z", turn_deg, degrees=True) * turning * Rotation.from_euler("x", 180.0, degrees=True)
    rot = Rotation.from_rotvec(rng.normal(0.0, np.radians(noise_deg), (len(t), 3))) * rot
    return Recording(t, x, rot.as_quat(scalar_first=True))


def ode_spiral() -> tuple[np.ndarray, np.ndarray]:
    """torchdiffeq's examples/ode_demo.py spiral: dy/dt = y^3 A (y a row, the cube elementwise),
    A = [[-0.1, 2.0], [-2.0, -0.1]], y0 = (2, 0), at t = linspace(0, 25, 1000): t (1000,), y (1000, 2)."""
    from scipy.integrate import solve_ivp

    a = np.array([[-0.1, 2.0], [-2.0, -0.1]])
    t = np.linspace(0.0, 25.0, 1000)
    sol = solve_ivp(lambda _t, y: (y ** 3) @ a, (0.0, 25.0), [2.0, 0.0], method="DOP853", t_eval=t,
                    rtol=1e-11, atol=1e-13)
    return t, sol.y.T.copy()


def write_positions(kind: str, path: Path, ts: list[np.ndarray], xs: list[np.ndarray]) -> str:
    """Demos of positions, times ts[i] (T_i,) and positions xs[i] (T_i, d), as a ``kind`` file (csv,
    npz) at ``path`` + suffix; returns its path."""
    if kind == "csv":
        d = xs[0].shape[1]
        lines = ["demo,t," + ",".join(f"x{j + 1}" for j in range(d))]
        lines += [f"{i},{float(tk)!r}," + ",".join(repr(float(v)) for v in xk)
                  for i, (t, x) in enumerate(zip(ts, xs)) for tk, xk in zip(t, x)]
        path = path.with_suffix(".csv")
        path.write_text("\n".join(lines) + "\n")
        return str(path)
    path = path.with_suffix(".npz")
    np.savez(path, **{f"{k}{i}": v for i, (t, x) in enumerate(zip(ts, xs)) for k, v in (("t", t), ("x", x))})
    return str(path)


def write(kind: str, path: Path, demos: list[Recording]) -> str:
    """The demos as a ``kind`` file (csv, npz) or bag (bag) at ``path`` + suffix; returns its spec."""
    if kind == "csv":
        lines = ["demo,t,x,y,z,qw,qx,qy,qz"]
        for i, d in enumerate(demos):
            lines += [f"{i},{float(t)!r}," + ",".join(repr(float(v)) for v in (*x, *q))
                      for t, x, q in zip(d.t, d.x, d.q)]
        path = path.with_suffix(".csv")
        path.write_text("\n".join(lines) + "\n")
        return str(path)
    if kind == "npz":
        path = path.with_suffix(".npz")
        np.savez(path, **{f"{k}{i}": getattr(d, k) for i, d in enumerate(demos) for k in "txq"})
        return str(path)
    ts = STORES["mcap"]
    msgs = [pose(ts, BASE_NS + i * DEMO_NS + round(float(t) * 1e9), x, q)
            for i, d in enumerate(demos) for t, x, q in zip(d.t, d.x, d.q)]
    return f"bag:{write_bag(path, 'mcap', {'/tool': (POSE, msgs)})}:/tool"
