"""One benchmark cell: train a learner on one LASA shape with one seed, and score it.

Every learner is wrapped as a ``Model`` with the same four questions, so the scoring code is
shared by the velocity-field learners and the time-indexed DMP baseline:

- ``reproduce(x, t)``: the rollout y from the demo's start x[0] over the demo's times t, and the
  model's velocities v to compare with the demo's; for a field v = f(x) at the demo points.
- ``rollouts(x0, t)``: rollouts from many starts over a long horizon (convergence, figures).
- ``step_time_us(points, calls)``: median time of one single-point evaluation.
- ``grid(gx, gy)``: the field on a grid for streamlines (None for a time-indexed model).

Per demo i (N demos, x_i of shape (T, d), each reproduced on its own time grid t_i): rmse(y_i, x_i),
dtw(y_i, x_i, step), dtw_per_sample (all samples, / T), chamfer_dtwd, chamfer_dtwd_std (on data
divided by the shape's per-coordinate std, dimensionless), frechet, swept_area, velocity_rmse(v_i, xd_i),
cosine_error(v_i, xd_i), in mm, mm², mm/s. Per shape: the spurious-attractor fraction of the
35 x 35 grid of starts over the demos' bounding box.
"""

from __future__ import annotations

import time
from typing import Any
from typing import Protocol as TypingProtocol

import numpy as np
import torch

from lfd import integrate, metrics
from lfd.bench import protocol as proto
from lfd.demos import DemoSet, lasa
from lfd.field import Field, PhasedField, VelocityField, is_phased

METRICS: tuple[str, ...] = ("rmse", "dtw", "dtw_per_sample", "chamfer_dtwd", "chamfer_dtwd_std", "frechet",
                            "swept_area", "velocity_rmse", "cosine_error")
TIMING_REPEATS = 5


class Model(TypingProtocol):
    """What the benchmark asks of a trained learner (see the module docstring)."""

    learner: str
    autonomous: bool   # False: time-indexed (DMP), no spurious-attractor grid
    config: dict[str, Any]
    train_time_s: float
    history: dict[str, Any]
    integrators: dict[str, str]

    def reproduce(self, x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x : array, shape (N, T, d) (demos); t : array, shape (N, T). Returns y, v, each (N, T, d)."""

    def rollouts(self, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
        """x0 : array, shape (B, d); t : array, shape (n,). Returns shape (B, n, d)."""

    def step_time_us(self, points: np.ndarray, calls: int) -> float:
        """Median microseconds of one single-point evaluation, over points of shape (P, d)."""

    def grid(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray | None:
        """The velocity at (gx[j], gy[i]), shape (len(gy), len(gx), 2), or None."""


class FieldModel:
    """A ``VelocityField`` as a benchmark Model, integrated accurately rather than on a grid.

    Rollouts solve dx_n/dt = f_n(x_n) in normalised units with torchdiffeq's adaptive dopri5
    (rtol = atol = ``TOL``), all starts in one batch, with outputs at the requested times (dense
    output, so a demo's 1000 sample times cost no extra steps). If dopri5 fails (step underflow
    on a blow-up, or more than ``MAX_STEPS`` steps) the batch is redone with fixed-step rk4 at
    (about) the demos' sample interval; ``integrators`` records which solver ran.
    """

    TOL = 1e-6
    MAX_STEPS = 2_000
    autonomous = True
    FALLBACK_SUBSTEPS = 4

    def __init__(self, field: VelocityField) -> None:
        self.field = field
        self.learner = field.learner
        self.config = dict(field.config)
        self.history = {k: v for k, v in field.history.items()
                        if k in ("iterations", "best_loss", "interrupted", "epochs", "train_cpu_s")}
        self.train_time_s = float(field.history.get("train_time_s", float("nan")))
        self.integrators: dict[str, str] = {}

    def _solve(self, x0: np.ndarray, t: np.ndarray, what: str, fallback_step: float) -> np.ndarray:
        """x(t) from x0, shape (B, d), at times t, shape (n,) (t[0] = 0): shape (B, n, d).

        ``lfd.integrate.solve`` in normalised units: dopri5, then rk4 at ``fallback_step``."""
        norm, module = self.field.norm, self.field.module
        xn0 = torch.tensor(norm.to_norm(x0))
        tt = torch.tensor(np.asarray(t, dtype=np.float64))

        def f(_t: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
            return module(y)

        with torch.no_grad(), np.errstate(all="ignore"):
            try:
                yn = integrate.solve(f, xn0, tt, **integrate.odeint_kwargs(
                    "dopri5", rtol=self.TOL, atol=self.TOL, max_steps=self.MAX_STEPS))
                self.integrators[what] = "dopri5"
            except (AssertionError, RuntimeError):
                yn = integrate.solve(f, xn0, tt, **integrate.odeint_kwargs("rk4", step=fallback_step))
                self.integrators[what] = f"rk4 (step {fallback_step:.3g} s, dopri5 failed)"
            return norm.from_norm(yn.numpy()).transpose(1, 0, 2)

    def reproduce(self, x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = t - t[:, :1]
        union = np.unique(rel.ravel())
        step = float(np.mean(np.diff(t, axis=1)))
        y_all = self._solve(x[:, 0], union, "reproduce", step)        # (N, len(union), d)
        idx = np.searchsorted(union, rel)                              # (N, T)
        y = np.stack([y_all[i, idx[i]] for i in range(len(x))])
        with np.errstate(all="ignore"):
            return y, self.field(x)

    def rollouts(self, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The fallback step is t's interval / FALLBACK_SUBSTEPS: the horizon grid is
        ``LasaProtocol.horizon_stride`` (4) demo sample intervals apart."""
        return self._solve(x0, t, "rollouts", float(t[1] - t[0]) / self.FALLBACK_SUBSTEPS)

    def step_time_us(self, points: np.ndarray, calls: int) -> float:
        f = self.field.single_point_evaluator()
        pts = [np.array(p) for p in points[:calls]]
        for p in pts[:20]:
            f(p)
        per_call = []
        for _ in range(TIMING_REPEATS):
            t0 = time.perf_counter()
            for p in pts:
                f(p)
            per_call.append((time.perf_counter() - t0) / len(pts))
        return float(np.median(per_call) * 1e6)

    def grid(self, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        xx, yy = np.meshgrid(gx, gy)
        with np.errstate(all="ignore"):
            return self.field(np.stack([xx, yy], axis=-1))


def fit(learner: str, demos: DemoSet, seed: int, options: dict[str, Any]) -> Model:
    """Train ``learner`` (``dmp`` or a registered field learner) on ``demos`` with ``seed``."""
    if learner == "dmp":
        from lfd.bench.dmp import fit_dmp

        return fit_dmp(demos, **options)
    from lfd.learners import train

    field: Field = train(learner, demos, seed=seed, progress=False, **options)
    if is_phased(field):
        return PhaseFieldModel(field)
    assert isinstance(field, VelocityField)
    return FieldModel(field)


class PhaseFieldModel(FieldModel):
    """A ``FieldKind.PHASED`` field (``lfd.learners.tracking``) as a benchmark Model: its rollouts
    integrate (x, s) jointly from s = 0 with fixed-step RK4 (the phase stops at 1, a kink adaptive
    steps dislike): reproductions at the demos' mean sample interval, rollouts on their output grid
    (K dt <= 0.05 there for K <= 3/s)."""

    def __init__(self, field: PhasedField) -> None:
        assert isinstance(field, VelocityField)
        super().__init__(field)
        self.phased = field

    def _solve(self, x0: np.ndarray, t: np.ndarray, what: str, fallback_step: float) -> np.ndarray:
        step = fallback_step if what == "reproduce" else float(t[1] - t[0])
        self.integrators[what] = f"rk4 on (x, s), step {step:.3g} s"
        with np.errstate(all="ignore"):
            return self.phased.rollout_with_phase(x0, t, method="rk4", step=step)[0]


def score(model: Model, demos: DemoSet, dtw_step: int) -> tuple[dict[str, list[float]], np.ndarray]:
    """Per-demo metrics {name: [N floats]} (non-finite for a diverged rollout) and the
    reproductions y, shape (N, T, d)."""
    per: dict[str, list[float]] = {m: [] for m in METRICS}
    ys, vs = model.reproduce(demos.x, demos.t)
    std = demos.x.reshape(-1, demos.dim).std(axis=0)   # (d,): the shape's data, all demos
    for x, xd, y, v in zip(demos.x, demos.xd, ys, vs):
        finite = bool(np.isfinite(y).all())
        row = {
            "rmse": metrics.rmse(y, x) if finite else np.inf,
            "dtw": metrics.dtw(y, x, step=dtw_step) if finite else np.inf,
            "dtw_per_sample": metrics.dtw_per_sample(y, x) if finite else np.inf,
            "chamfer_dtwd": metrics.chamfer_dtwd(y, x) if finite else np.inf,
            "chamfer_dtwd_std": metrics.chamfer_dtwd_std(y, x, std) if finite else np.inf,
            "frechet": metrics.frechet(y, x) if finite else np.inf,
            "swept_area": metrics.swept_area(y, x) if finite else np.inf,
            "velocity_rmse": metrics.velocity_rmse(v, xd) if np.isfinite(v).all() else np.inf,
            "cosine_error": metrics.cosine_error(v, xd) if np.isfinite(v).all() else np.inf,
        }
        for m in METRICS:
            per[m].append(float(row[m]))
    return per, ys


def _mean(per: dict[str, list[float]], idx: list[int]) -> dict[str, float] | None:
    if not idx:
        return None
    return {m: float(np.mean([v[i] for i in idx])) for m, v in per.items()}


def convergence(final: np.ndarray, goal: np.ndarray, st: proto.Starts, radius: float) -> dict[str, Any]:
    """Fractions of rollouts ending within ``radius`` of ``goal``: of all starts (``rate``) and
    of each group (``demo``, ``ring``, ``box``; None for an empty group), with the group sizes
    and the median and largest final distance (inf for a diverged rollout).
    final : array, shape (B, d), the rollouts' end points in the order of ``st.all``."""
    dist = np.linalg.norm(final - goal, axis=1)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    out: dict[str, Any] = {"rate": metrics.convergence_rate(final, goal, radius)}
    for name, sl in st.groups().items():
        out[name] = metrics.convergence_rate(final[sl], goal, radius) if len(dist[sl]) else None
    out.update(n_starts=len(dist), n_demo=len(st.demo), n_ring=len(st.ring), n_box=len(st.box),
               radius_mm=radius, median_final_mm=float(np.median(dist)), max_final_mm=float(np.max(dist)))
    return out


def spurious_grid(model: Model, demos: DemoSet, protocol: proto.LasaProtocol) -> float | None:
    """The spurious-attractor fraction of CONDOR/PUMA: of the ``protocol.spurious_grid`` squared
    starts of ``proto.grid_starts`` (over the demos' bounding box), the fraction whose rollout
    over the convergence horizon (``proto.horizon``) does not end within ``radius_mm`` of the
    goal. None for a time-indexed model (``autonomous`` False: the DMP reaches the goal by
    construction)."""
    if not model.autonomous:
        return None
    h, n = proto.horizon(demos, protocol)
    before = model.integrators.get("rollouts")
    final = model.rollouts(proto.grid_starts(demos, protocol), np.linspace(0.0, h, n))[:, -1]
    if "rollouts" in model.integrators:            # record the grid's solver under its own name
        model.integrators["grid"] = model.integrators.pop("rollouts")
        if before is not None:
            model.integrators["rollouts"] = before
    return metrics.spurious_attractor_fraction(final, demos.goal, protocol.radius_mm)


def evaluate_cell(learner: str, shape: str, seed: int, options: dict[str, Any],
                  protocol: proto.LasaProtocol) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Train and score one (learner, shape, seed). Returns the JSON record and the arrays for
    the figures: ``demo_rollouts`` (N, T, 2), ``starts`` (B, 2), ``rollouts`` (B, keep, 2),
    ``final`` (B, 2), ``grid_x`` (G,), ``grid_y`` (G,), ``grid_v`` (G, G, 2) or (0,)."""
    demos = lasa(shape)
    train, _ = proto.split(demos, protocol.train_demos)
    model = fit(learner, train, seed, options)
    if model.history.get("interrupted"):  # the learner swallowed Ctrl-C: never score or cache it
        raise KeyboardInterrupt
    per, demo_rollouts = score(model, demos, protocol.dtw_step)
    train_idx = list(range(protocol.train_demos))
    test_idx = list(range(protocol.train_demos, demos.n_demos))

    st = proto.starts(demos, shape, protocol)
    h, n = proto.horizon(demos, protocol)
    traj = model.rollouts(st.all, np.linspace(0.0, h, n))
    conv = {**convergence(traj[:, -1], demos.goal, st, protocol.radius_mm), "horizon_s": h, "n_steps": n}
    conv["spurious_grid"] = spurious_grid(model, demos, protocol)
    conv["n_grid"] = 0 if conv["spurious_grid"] is None else protocol.spurious_grid ** 2

    points = train.x.reshape(-1, train.dim)
    stride = max(1, len(points) // protocol.timing_calls)
    step_us = model.step_time_us(points[::stride], protocol.timing_calls)

    lo, hi = demos.bounds(protocol.box_grow)
    gx, gy = np.linspace(lo[0], hi[0], protocol.grid), np.linspace(lo[1], hi[1], protocol.grid)
    gv = model.grid(gx, gy)
    keep = np.unique(np.linspace(0, n - 1, protocol.keep_points).round().astype(int))

    record = {
        "learner": learner, "shape": shape, "seed": seed, "config": model.config,
        "train_demos": train_idx, "test_demos": test_idx,
        "train_time_s": model.train_time_s, "step_time_us": step_us,
        "train": _mean(per, train_idx), "test": _mean(per, test_idx),
        "per_demo": per, "convergence": conv, "history": model.history,
        "integrators": dict(model.integrators),
    }
    arrays = {
        "demo_rollouts": demo_rollouts, "starts": st.all, "rollouts": traj[:, keep], "final": traj[:, -1],
        "grid_x": gx, "grid_y": gy, "grid_v": gv if gv is not None else np.zeros(0),
        "n_demo": np.array(len(st.demo)), "n_ring": np.array(len(st.ring)),
    }
    return record, arrays
