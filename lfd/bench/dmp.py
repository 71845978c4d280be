"""The DMP baselines as benchmark ``Model`` objects: one ``movement_primitives`` DMP fitted to the mean demo.

A DMP is time-indexed, not an autonomous field x -> dx/dt, so the benchmarks run it thus
(docs/benchmark.md):

- Fit: the mean demo m_k = (1/K) sum_i x_i[k] of the K training demos, each first moved to end at
  the goal as every learner's are (``lfd.demos.relative``, Eqs. (R1)-(R2) of docs/equations.md)
  (averaged per sample index; a pose set's orientations by the chordal mean,
  ``lfd.pose.mean_quaternion``, sign-continuous), on a uniform grid over the mean duration tau_0.
- Reproduce demo i: from its start at rest toward the goal, with tau = demo i's duration and step
  tau / (T - 1), so the T samples line up with the demo's in time; the velocity metrics take the
  rollout's yd. ``toward(end)`` moves the goal (the held-out split).
- Rollouts from other starts: tau = tau_0 on the rollout grid. No streamlines; the single-step time
  is one ``step``.

``DMPModel`` (positions, ``fit_dmp``) is ``movement_primitives.dmp.DMP``; ``CartesianDMPModel``
(poses (x, q), ``fit_cartesian_dmp``) is its ``CartesianDMP``.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from movement_primitives.dmp import DMP, CartesianDMP

from lfd.bench.model import TIMING_REPEATS, Model
from lfd.demos import DemoSet
from lfd.demos.relative import relative_to_ends
from lfd.errors import ConfigError
from lfd.pose import continuous, mean_quaternion

#: the control period of ``control_step``, s (500 Hz)
CONTROL_DT = 0.002


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


class DMPModel(Model):
    """A fitted position DMP as a benchmark ``Model``, according to [1]_, Eq. 2.1:

    .. math:: \\tau^2 \\ddot y = \\alpha_y (\\beta_y (g - y) - \\tau \\dot y) + f(z),
              \\quad z = \\exp(-\\alpha_z t / \\tau),

    a forcing term f of radial basis functions of the phase z, fitted by ridge regression.

    Parameters
    ----------
    dmp : DMP
        The movement_primitives DMP, weights fitted.
    goal : array, shape (D,)
        g, the state it runs toward.
    duration : float
        tau_0, the mean training duration, s.
    config : dict
        Its options and how it was fitted.
    train_time_s : float
        Time of the mean-demo computation and ``imitate``, s.
    integrators : dict of str
        How its ``reproduce`` and ``rollouts`` step.

    References
    ----------
    .. [1] Ijspeert, A. J., Nakanishi, J., Hoffmann, H., Pastor, P., Schaal, S. (2013). Dynamical
       movement primitives: learning attractor models for motor behaviors. Neural Computation
       25(2), 328-373. doi:10.1162/NECO_a_00393
    """

    learner = "dmp"
    autonomous = False   # time-indexed: it reaches the goal by construction
    velocity_dim: int | None = None   # yd's size: the state's (None) or another (a pose's twist: 6)

    def __init__(self, dmp: Any, goal: np.ndarray, duration: float, config: dict[str, Any],
                 train_time_s: float, integrators: dict[str, str]) -> None:
        self.dmp = dmp
        self.goal = np.asarray(goal, dtype=np.float64)
        self.duration = float(duration)
        self.config = config
        self.train_time_s = float(train_time_s)
        self.history: dict[str, Any] = {}
        self.integrators = dict(integrators)

    def _start(self, y0: np.ndarray) -> np.ndarray:
        """The start state the DMP takes for y0."""
        return np.asarray(y0, dtype=np.float64)

    def _finish(self, y: np.ndarray) -> np.ndarray:
        """A run's states, shape (n, D), as the model returns them."""
        return y

    def _zero_velocity(self) -> np.ndarray:
        return np.zeros(self.velocity_dim or len(self.goal))

    def _configure(self, y0: np.ndarray, tau: float, dt: float) -> np.ndarray:
        """Set the start (at rest), the goal, tau and the step; returns the start state."""
        self.dmp.execution_time_ = tau   # re-times the phase; the weights are kept
        self.dmp.dt_ = dt
        start = self._start(y0)
        self.dmp.configure(start_y=start, start_yd=self._zero_velocity(), goal_y=self.goal)
        self.dmp.reset()
        return start

    def run(self, y0: np.ndarray, tau: float, dt: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Integrate from y0, shape (D,), at rest, for n samples dt apart with time scale tau.
        Returns y, shape (n, D), and yd, shape (n, V)."""
        y = np.empty((n, len(self.goal)))
        yd = np.empty((n, len(self._zero_velocity())))
        y[0], yd[0] = self._configure(y0, tau, dt), 0.0
        for k in range(1, n):
            y[k], yd[k] = self.dmp.step(y[k - 1], yd[k - 1])
        return self._finish(y), yd

    def reproduce(self, x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each demo x[i] with times t[i]: the run from x[i][0] with tau_i = t[i][-1] - t[i][0]
        on T uniform samples."""
        out = [self.run(xi[0], float(ti[-1] - ti[0]), float(ti[-1] - ti[0]) / (len(ti) - 1), len(ti))
               for xi, ti in zip(x, t)]
        return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])

    def rollouts(self, x0: np.ndarray, t: np.ndarray, label: str = "rollouts") -> np.ndarray:
        """From each start with tau = duration, over the uniform grid t."""
        dt = float(t[1] - t[0])
        return np.stack([self.run(p, self.duration, dt, len(t))[0] for p in x0])

    def _goal(self, end: np.ndarray) -> np.ndarray:
        return np.asarray(end, dtype=np.float64).copy()

    def toward(self, end: np.ndarray) -> Model:
        """The same weights with goal g = end (the transformation system's goal parameter)."""
        other = copy.copy(self)
        other.goal, other.integrators = self._goal(end), dict(self.integrators)
        return other

    def step_time_us(self, points: np.ndarray, calls: int) -> float:
        """Median microseconds (over ``TIMING_REPEATS``) of one ``step`` over ``calls`` steps from
        points[0], at the demos' pace."""
        per_call = []
        for _ in range(TIMING_REPEATS):
            y, yd = self._configure(points[0], self.duration, self.duration / max(calls, 1)), self._zero_velocity()
            t0 = time.perf_counter()
            for _ in range(calls):
                y, yd = self.dmp.step(y, yd)
            per_call.append((time.perf_counter() - t0) / calls)
        return float(np.median(per_call) * 1e6)

    def simulate(self, x0: np.ndarray, t: np.ndarray, kick_at: int | None = None,
                 kicks: np.ndarray | None = None) -> np.ndarray:
        """Its own step with dt = the grid's step and tau = duration; a kick moves the state."""
        x0 = np.atleast_2d(np.asarray(x0, dtype=np.float64))
        return np.stack([self._kicked(p, t, kick_at, None if kicks is None else kicks[i]) for i, p in enumerate(x0)])

    def _kicked(self, x0: np.ndarray, t: np.ndarray, kick_at: int | None, kick: np.ndarray | None) -> np.ndarray:
        y = np.empty((len(t), len(x0)))
        y[0] = self._configure(x0, self.duration, float(t[1] - t[0]))
        yd = self._zero_velocity()
        for k in range(1, len(t)):
            y[k], yd = self.dmp.step(y[k - 1], yd)
            if kick_at is not None and k == kick_at:
                y[k] = y[k] + kick
        return self._finish(y)

    def simulate_demos(self, demos: DemoSet) -> np.ndarray:
        """``reproduce`` of the demos' positions: already its own step on each demo's clock."""
        return self.reproduce(demos.x, demos.t)[0]

    def control_step(self, x0: np.ndarray) -> Callable[[np.ndarray], Any]:
        """One ``step`` from x0 with tau = duration at ``CONTROL_DT``."""
        self._configure(x0, self.duration, CONTROL_DT)
        yd = self._zero_velocity()
        return lambda x: self.dmp.step(x, yd)


class CartesianDMPModel(DMPModel):
    """A fitted ``CartesianDMP`` (position and orientation) as a benchmark ``Model`` on poses
    (x, y, z, qw, qx, qy, qz), according to [1]_: the position part is ``DMPModel``'s, and the
    orientation, a unit quaternion q with angular velocity omega,

    .. math:: \\tau^2 \\dot\\omega = \\alpha_y (\\beta_y 2 \\log(g_q * \\bar q) - \\tau \\omega) + f_{rot}(z),
              \\quad q(t + dt) = \\exp(dt\\, \\omega / 2) * q(t),

    2 log the rotation vector (the shorter way round), * the quaternion product. Its yd is the
    twist (v, omega), shape (6,); its orientations come back sign-continuous.

    References
    ----------
    .. [1] Ude, A., Nemec, B., Petric, T., Morimoto, J. (2014). Orientation in Cartesian space
       dynamic movement primitives. IEEE International Conference on Robotics and Automation
       (ICRA), 2997-3004. doi:10.1109/ICRA.2014.6907291
    """

    velocity_dim = 6

    def _start(self, y0: np.ndarray) -> np.ndarray:
        y0 = np.asarray(y0, dtype=np.float64)
        return np.concatenate([y0[:3], y0[3:] / np.linalg.norm(y0[3:])])

    def _finish(self, y: np.ndarray) -> np.ndarray:
        return np.concatenate([y[:, :3], continuous(y[:, 3:])], axis=1)

    def _goal(self, end: np.ndarray) -> np.ndarray:
        """end's quaternion signed like the current goal's."""
        goal = super()._goal(end)
        if float(goal[3:] @ self.goal[3:]) < 0:
            goal[3:] *= -1.0
        return goal


def fit_dmp(demos: DemoSet, **options: Any) -> DMPModel:
    """Fit one DMP to the mean of ``demos`` (module docstring)."""
    config = make_config(**options)
    t0 = time.perf_counter()
    demos = relative_to_ends(demos)   # each demo relative to its own end (lfd.demos.relative)
    mean_x = demos.x.mean(axis=0)                                   # (T, d)
    duration = float(np.mean(demos.t[:, -1] - demos.t[:, 0]))
    grid = np.linspace(0.0, duration, demos.n_samples)
    dmp = DMP(n_dims=demos.dim, execution_time=duration, dt=duration / (demos.n_samples - 1),
              n_weights_per_dim=config.n_weights_per_dim, alpha_y=config.alpha_y, beta_y=config.beta_y)
    dmp.imitate(grid, mean_x, regularization_coefficient=config.regularization,
                allow_final_velocity=config.allow_final_velocity)
    return DMPModel(dmp, demos.goal, duration, {**asdict(config), "fit": "mean demo"}, time.perf_counter() - t0,
                    {"reproduce": "DMP.step (rk4, compiled), step tau_i / (T - 1)",
                     "rollouts": "DMP.step (rk4, compiled), the horizon grid's step"})


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
    module docstring); options as ``make_cartesian_config``'s. Its goal is (goal, goal_q), goal_q
    signed like the mean demo's last quaternion."""
    config = make_cartesian_config(**options)
    if demos.goal_q is None:
        raise ConfigError(f"dmp: {demos.name} holds no orientations; use fit_dmp")
    t0 = time.perf_counter()
    demos = relative_to_ends(demos)   # each demo relative to its own end (lfd.demos.relative)
    mean_x, mean_q = mean_pose_demo(demos)
    duration = float(np.mean(demos.t[:, -1] - demos.t[:, 0]))
    grid = np.linspace(0.0, duration, demos.n_samples)
    dmp = CartesianDMP(execution_time=duration, dt=duration / (demos.n_samples - 1), int_dt=config.int_dt,
                       n_weights_per_dim=config.n_weights_per_dim, alpha_y=config.alpha_y, beta_y=config.beta_y)
    dmp.imitate(grid, np.concatenate([mean_x, mean_q], axis=1), regularization_coefficient=config.regularization,
                allow_final_velocity=config.allow_final_velocity)
    goal_q = np.asarray(demos.goal_q, dtype=np.float64)
    goal_q = goal_q if float(goal_q @ mean_q[-1]) >= 0 else -goal_q   # the sign the mean demo ends with
    return CartesianDMPModel(
        dmp, np.concatenate([demos.goal, goal_q]), duration,
        {**asdict(config), "fit": "mean demo (positions; chordal mean quaternions)", "model": "CartesianDMP"},
        time.perf_counter() - t0,
        {"reproduce": "CartesianDMP.step (position rk4, orientation Euler at int_dt), step tau_i / (T - 1)",
         "rollouts": "CartesianDMP.step, the horizon grid's step"})
