"""The DMP baseline: one ``movement_primitives.dmp.DMP`` fitted to the mean demonstration.

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

References
----------
Ijspeert, A. J., Nakanishi, J., Hoffmann, H., Pastor, P., Schaal, S. (2013). Dynamical movement
primitives: learning attractor models for motor behaviors. Neural Computation 25(2), 328-373.
doi:10.1162/NECO_a_00393
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from movement_primitives.dmp import DMP

from lfd.demos import DemoSet
from lfd.errors import ConfigError

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


def make_config(**options: Any) -> DMPConfig:
    """DMPConfig from keyword options; unknown names and bad values raise ConfigError."""
    known = set(DMPConfig.__dataclass_fields__)
    unknown = sorted(set(options) - known)
    if unknown:
        raise ConfigError(f"dmp: unknown option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    try:
        return DMPConfig(**options)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"dmp: {e}") from None


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
