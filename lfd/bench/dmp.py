"""The DMP baselines: one ``movement_primitives`` DMP fitted to the mean demonstration.

A DMP (Ijspeert et al. 2013, Eq. 2.1 of that paper) is the transformation system

    tau^2 ydd = alpha_y (beta_y (g - y) - tau yd) + f(z),   z = exp(-alpha_z t / tau),

with a forcing term f of ``n_weights_per_dim`` radial basis functions of the phase z, fitted by
(ridge) regression to one demonstration. It is time-indexed, not an autonomous field x -> dx/dt,
so the benchmark uses it as follows (docs/benchmark.md):

- Fit: the mean demo m_k = (1/K) sum_i x_i[k] of the K training demos (all LASA demos have the
  same sample count; averaging is per sample index), on a uniform grid over the mean duration.
- Reproduce demo i: start y(0) = x_i[0], yd(0) = 0, goal g = the common goal, tau = demo i's
  duration and step tau / (T - 1), so the T samples line up with the demo's in time.
- Velocity metrics: the rollout's yd against the demo's velocity, sample by sample (a field
  is instead evaluated at the demo's points).
- Perturbed starts: tau = the mean training duration, run for the benchmark horizon.
- No streamlines; the single-step time is one ``DMP.step`` (an rk4 step, in compiled code).

Poses (``lfd bench robottasks``) get the Cartesian DMP of Ude et al. (2014), ``CartesianDMP``:
the position part as above, and for the orientation, a unit quaternion q (w, x, y, z) with the
angular velocity omega,

    tau^2 omega_dot = alpha_y (beta_y 2 log(g_q * conj(q)) - tau omega) + f_rot(z),
    q(t + dt) = exp(dt omega / 2) * q(t),

where 2 log(.) is the rotation vector (axis times angle, the shorter way round) and ``*`` the
quaternion product. It is fitted and run like the position DMP (``fit_cartesian_dmp``): the mean
demo is the per-sample mean position and the per-sample chordal mean quaternion
(``lfd.pose.mean_quaternion``), made sign-continuous (``lfd.pose.continuous``); a reproduction
starts at demo i's start pose at rest with the common goal pose (goal, goal_q) and tau = demo i's
duration.

References
----------
Ijspeert, A. J., Nakanishi, J., Hoffmann, H., Pastor, P., Schaal, S. (2013). Dynamical movement
primitives: learning attractor models for motor behaviors. Neural Computation 25(2), 328-373.
doi:10.1162/NECO_a_00393

Ude, A., Nemec, B., Petric, T., Morimoto, J. (2014). Orientation in Cartesian space dynamic movement
primitives. IEEE International Conference on Robotics and Automation (ICRA), 2997-3004.
doi:10.1109/ICRA.2014.6907291
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from movement_primitives.dmp import DMP, CartesianDMP

from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.pose import continuous, mean_quaternion

TIMING_REPEATS = 5


@dataclass(frozen=True)
class DMPConfig:
    """Options of the DMP baseline.

    n_weights_per_dim : radial basis functions of the forcing term per dimension
    alpha_y, beta_y : spring-damper gains of the transformation system (critically damped
        for beta_y = alpha_y / 4)
    regularization : ridge coefficient of the forcing-term regression
    """

    n_weights_per_dim: int = 50
    alpha_y: float = 25.0
    beta_y: float = 6.25
    regularization: float = 1e-3
    allow_final_velocity: bool = False

    def __post_init__(self) -> None:
        n = self.n_weights_per_dim
        if not isinstance(n, int) or isinstance(n, bool) or n < 1:
            raise ValueError(f"n_weights_per_dim must be a positive integer, got {n!r}")
        if not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0
                   for v in (self.alpha_y, self.beta_y)):
            raise ValueError("alpha_y and beta_y must be positive numbers")
        if not (isinstance(self.regularization, (int, float)) and self.regularization >= 0):
            raise ValueError(f"regularization must be >= 0, got {self.regularization!r}")


@dataclass(frozen=True)
class CartesianDMPConfig(DMPConfig):
    """Options of the Cartesian DMP baseline: those of ``DMPConfig``, and

    int_dt : step of the orientation's internal Euler integration, s (movement_primitives'
        default; each ``CartesianDMP.step`` takes ceil(dt / int_dt) of them)
    """

    int_dt: float = 0.001

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (isinstance(self.int_dt, (int, float)) and not isinstance(self.int_dt, bool)
                and math.isfinite(self.int_dt) and self.int_dt > 0):
            raise ValueError(f"int_dt must be a positive number, got {self.int_dt!r}")


def _make(cls: type[DMPConfig], options: dict[str, Any]) -> Any:
    """``cls(**options)``; unknown names and bad values raise ConfigError."""
    known = set(cls.__dataclass_fields__)
    unknown = sorted(set(options) - known)
    if unknown:
        raise ConfigError(f"dmp: unknown option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    try:
        return cls(**options)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"dmp: {e}") from None


def make_config(**options: Any) -> DMPConfig:
    """DMPConfig from keyword options; unknown names and bad values raise ConfigError."""
    config: DMPConfig = _make(DMPConfig, options)
    return config


def make_cartesian_config(**options: Any) -> CartesianDMPConfig:
    """CartesianDMPConfig from keyword options; unknown names and bad values raise ConfigError."""
    config: CartesianDMPConfig = _make(CartesianDMPConfig, options)
    return config


class DMPModel:
    """A fitted DMP as a benchmark Model (see ``lfd.bench.evaluate``).

    dmp : the movement_primitives DMP, weights fitted
    goal : array, shape (d,); duration : mean training duration tau_0, s
    """

    learner = "dmp"
    # Time-indexed: it reaches the goal by construction, so the benchmark skips its 35 x 35
    # spurious-attractor grid (one Python-level rollout per grid point).
    autonomous = False

    def __init__(self, dmp: DMP, goal: np.ndarray, duration: float, config: DMPConfig,
                 train_time_s: float) -> None:
        self.dmp = dmp
        self.goal = np.asarray(goal, dtype=np.float64)
        self.duration = float(duration)
        self.config = {**asdict(config), "fit": "mean demo"}
        self.train_time_s = float(train_time_s)
        self.history: dict[str, Any] = {}
        self.integrators = {"reproduce": "DMP.step (rk4, compiled), step tau_i / (T - 1)",
                            "rollouts": "DMP.step (rk4, compiled), the horizon grid's step"}

    def _configure(self, x0: np.ndarray, tau: float, dt: float) -> None:
        self.dmp.execution_time_ = tau  # re-times the phase; the weights are kept
        self.dmp.dt_ = dt
        self.dmp.configure(start_y=np.asarray(x0, dtype=np.float64), start_yd=np.zeros_like(self.goal),
                           goal_y=self.goal)
        self.dmp.reset()

    def run(self, x0: np.ndarray, tau: float, dt: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Integrate from x0, shape (d,), at rest, for n samples dt apart with time scale tau.
        Returns y, yd, each shape (n, d)."""
        self._configure(x0, tau, dt)
        y = np.empty((n, len(self.goal)))
        yd = np.empty_like(y)
        y[0], yd[0] = x0, 0.0
        for k in range(1, n):
            y[k], yd[k] = self.dmp.step(y[k - 1], yd[k - 1])
        return y, yd

    def reproduce(self, x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each demo x[i], shape (T, d), with times t[i]: the rollout from x[i][0] with
        tau_i = t[i][-1] - t[i][0] on T uniform samples. Returns y, yd, each (N, T, d)."""
        out = [self.run(xi[0], float(ti[-1] - ti[0]), float(ti[-1] - ti[0]) / (len(ti) - 1), len(ti))
               for xi, ti in zip(x, t)]
        return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])

    def rollouts(self, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
        """From each start x0, shape (B, d), with tau = duration, over the uniform grid t: (B, n, d)."""
        dt = float(t[1] - t[0])
        return np.stack([self.run(p, self.duration, dt, len(t))[0] for p in x0])

    def step_time_us(self, points: np.ndarray, calls: int) -> float:
        """Median microseconds of one ``DMP.step`` over ``calls`` steps from points[0]."""
        per_call = []
        for _ in range(TIMING_REPEATS):
            self._configure(points[0], self.duration, self.duration / max(calls, 1))
            y, yd = points[0].copy(), np.zeros_like(self.goal)
            t0 = time.perf_counter()
            for _ in range(calls):
                y, yd = self.dmp.step(y, yd)
            per_call.append((time.perf_counter() - t0) / calls)
        return float(np.median(per_call) * 1e6)

    def grid(self, gx: np.ndarray, gy: np.ndarray) -> None:
        """A DMP has no velocity field to draw."""
        return None


def fit_dmp(demos: DemoSet, **options: Any) -> DMPModel:
    """Fit one DMP to the mean of ``demos`` (see the module docstring)."""
    config = make_config(**options)
    t0 = time.perf_counter()
    mean_x = demos.x.mean(axis=0)                                   # (T, d)
    duration = float(np.mean(demos.t[:, -1] - demos.t[:, 0]))
    grid = np.linspace(0.0, duration, demos.n_samples)
    dmp = DMP(n_dims=demos.dim, execution_time=duration, dt=duration / (demos.n_samples - 1),
              n_weights_per_dim=config.n_weights_per_dim, alpha_y=config.alpha_y, beta_y=config.beta_y)
    dmp.imitate(grid, mean_x, regularization_coefficient=config.regularization,
                allow_final_velocity=config.allow_final_velocity)
    return DMPModel(dmp, demos.goal, duration, config, time.perf_counter() - t0)


class CartesianDMPModel:
    """A fitted ``CartesianDMP`` (position and orientation) as a robot-tasks pose model
    (``lfd.bench.robottasks.PoseModel``).

    Parameters
    ----------
    dmp : CartesianDMP
        The movement_primitives DMP, weights fitted.
    goal : array, shape (3,)
        The common goal position, m.
    goal_q : array, shape (4,)
        The common goal orientation, a unit quaternion (w, x, y, z).
    duration : float
        tau_0, the mean training duration, s.
    config : CartesianDMPConfig
        Its options.
    train_time_s : float
        Time of the mean-demo computation and ``imitate``, s.
    """

    learner = "dmp"
    autonomous = False   # time-indexed: it reaches the goal by construction

    def __init__(self, dmp: CartesianDMP, goal: np.ndarray, goal_q: np.ndarray, duration: float,
                 config: CartesianDMPConfig, train_time_s: float) -> None:
        self.dmp = dmp
        self.goal = np.asarray(goal, dtype=np.float64)
        self.goal_q = np.asarray(goal_q, dtype=np.float64)
        self.duration = float(duration)
        self.config = {**asdict(config), "fit": "mean demo (positions; chordal mean quaternions)",
                       "model": "CartesianDMP"}
        self.train_time_s = float(train_time_s)
        self.history: dict[str, Any] = {}
        self.integrators = {"reproduce": "CartesianDMP.step (position rk4, orientation Euler at int_dt), "
                                         "step tau_i / (T - 1)",
                            "rollouts": "CartesianDMP.step, the horizon grid's step"}

    def _configure(self, x0: np.ndarray, q0: np.ndarray, tau: float, dt: float) -> np.ndarray:
        """Set the start pose (at rest), the goal pose, tau and the step; returns the start y (7,)."""
        self.dmp.execution_time_ = tau   # re-times the phase; the weights are kept
        self.dmp.dt_ = dt
        q0 = np.asarray(q0, dtype=np.float64)
        y0 = np.concatenate([np.asarray(x0, dtype=np.float64), q0 / np.linalg.norm(q0)])
        self.dmp.configure(start_y=y0, start_yd=np.zeros(6), goal_y=np.concatenate([self.goal, self.goal_q]))
        self.dmp.reset()
        return y0

    def run(self, x0: np.ndarray, q0: np.ndarray, tau: float, dt: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Integrate from the pose x0 (3,), q0 (4,) at rest for n samples dt apart with time scale tau.

        Returns
        -------
        x : array, shape (n, 3)
            Positions, m.
        q : array, shape (n, 4)
            Unit quaternions (w, x, y, z), sign-continuous.
        """
        y = np.empty((n, 7))
        y[0] = self._configure(x0, q0, tau, dt)
        yd = np.zeros(6)
        for k in range(1, n):
            y[k], yd = self.dmp.step(y[k - 1], yd)
        return y[:, :3], continuous(y[:, 3:])

    def reproduce(self, x0: np.ndarray, q0: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """From each demo's start pose x0[i] (N, 3), q0[i] (N, 4), with tau_i = t[i][-1] - t[i][0] on
        the T samples of t[i], t of shape (N, T). Returns x (N, T, 3) and q (N, T, 4)."""
        out = [self.run(xi, qi, float(ti[-1] - ti[0]), float(ti[-1] - ti[0]) / (len(ti) - 1), len(ti))
               for xi, qi, ti in zip(x0, q0, t)]
        return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])

    def rollouts(self, x0: np.ndarray, q0: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """From each start pose x0 (B, 3), q0 (B, 4), with tau = duration, over the uniform grid t (n,).
        Returns x (B, n, 3) and q (B, n, 4)."""
        dt = float(t[1] - t[0])
        out = [self.run(xi, qi, self.duration, dt, len(t)) for xi, qi in zip(x0, q0)]
        return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])

    def step_time_us(self, x: np.ndarray, q: np.ndarray, calls: int) -> float:
        """Median microseconds (over TIMING_REPEATS) of one ``CartesianDMP.step`` over ``calls``
        steps from the pose x[0] (3,), q[0] (4,) (x (P, 3), q (P, 4)), at the demos' pace."""
        per_call = []
        for _ in range(TIMING_REPEATS):
            y, yd = self._configure(x[0], q[0], self.duration, self.duration / max(calls, 1)), np.zeros(6)
            t0 = time.perf_counter()
            for _ in range(calls):
                y, yd = self.dmp.step(y, yd)
            per_call.append((time.perf_counter() - t0) / calls)
        return float(np.median(per_call) * 1e6)

    def step_times_us(self, x: np.ndarray, q: np.ndarray, calls: int) -> tuple[float, float]:
        """(single-point step, pose step) in microseconds, as ``lfd.bench.robottasks.PoseModel``
        asks: both are one ``CartesianDMP.step`` (``step_time_us``), a pose in and the next pose out."""
        us = self.step_time_us(x, q, calls)
        return us, us


def mean_pose_demo(demos: DemoSet) -> tuple[np.ndarray, np.ndarray]:
    """The mean demo of a pose set: positions averaged per sample index, shape (T, 3), and the
    chordal mean quaternion per sample index (``lfd.pose.mean_quaternion``), made sign-continuous
    along the demo, shape (T, 4)."""
    if demos.q is None:
        raise ValueError(f"{demos.name}: the Cartesian DMP needs a set of poses")
    mean_q = np.stack([mean_quaternion(demos.q[:, k]) for k in range(demos.n_samples)])
    return demos.x.mean(axis=0), continuous(mean_q)


def fit_cartesian_dmp(demos: DemoSet, **options: Any) -> CartesianDMPModel:
    """Fit one ``CartesianDMP`` to the mean demo of the pose set ``demos`` (``mean_pose_demo``, the
    module docstring), on a uniform grid over the mean duration; options as ``make_cartesian_config``'s."""
    config = make_cartesian_config(**options)
    if demos.goal_q is None:
        raise ConfigError(f"dmp: {demos.name} holds no orientations; use fit_dmp")
    t0 = time.perf_counter()
    mean_x, mean_q = mean_pose_demo(demos)
    duration = float(np.mean(demos.t[:, -1] - demos.t[:, 0]))
    grid = np.linspace(0.0, duration, demos.n_samples)
    dmp = CartesianDMP(execution_time=duration, dt=duration / (demos.n_samples - 1), int_dt=config.int_dt,
                       n_weights_per_dim=config.n_weights_per_dim, alpha_y=config.alpha_y, beta_y=config.beta_y)
    dmp.imitate(grid, np.concatenate([mean_x, mean_q], axis=1), regularization_coefficient=config.regularization,
                allow_final_velocity=config.allow_final_velocity)
    goal_q = np.asarray(demos.goal_q, dtype=np.float64)
    goal_q = goal_q if float(goal_q @ mean_q[-1]) >= 0 else -goal_q   # the sign the mean demo ends with
    return CartesianDMPModel(dmp, demos.goal, goal_q, duration, config, time.perf_counter() - t0)
