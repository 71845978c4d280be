"""The RoboTasks9 benchmark behind ``lfd bench robottasks``: poses, every learner in one harness.

Everything a number depends on, other than the learner and its seed, is a field of
``RobotTasksProtocol``; its hash keys the result cache (the LASA suite's cache machinery,
``lfd.bench.runner``, and its executors, ``lfd.bench.executor``).

- Data: ``lfd.demos.robottasks(task)``, 9 kinesthetic demos of 1000 poses at 60 Hz, positions in
  metres, orientations unit quaternions (w, x, y, z); the goal pose is the demos' mean final
  position ``goal`` and their chordal mean final orientation ``goal_q``.
- Split: none, as the LASA suite's default: every learner trains on all 9 demos and is scored on them.
- Field learners (node, contraction, tracking) train on chart points z = (x, l log(R_g^T R)) of
  ``lfd.pose`` (``lfd.train`` does this for a pose set) and are rolled out in the chart; the DMP
  baseline is ``movement_primitives``' ``CartesianDMP`` (``lfd.bench.dmp.fit_cartesian_dmp``). Every
  learner's rollouts come back as poses (x, q) and are scored by the same code.
- Reproduction of demo i: the rollout from demo i's start pose over demo i's time grid. Per demo,
  then the mean over the 9 demos:

  - ``dtw_mm``: DTW (``lfd.metrics.dtw``, the sum of distances along the best monotone alignment)
    between the rollout's and the demo's positions in mm, on every ``dtw_step``-th sample;
  - ``dtw_angle_deg``: the mean geodesic angle (``lfd.pose.geodesic_angle``) between the rollout's
    and the demo's orientations over the pairs of that same alignment (``lfd.metrics.dtw_path``), degrees;
  - ``rmse_mm``: time-aligned position RMSE, mm;
  - ``final_mm``, ``final_deg``: distance and geodesic angle of the rollout's last pose to the
    goal pose (goal, goal_q), mm and degrees.

- Convergence: from each demo start, ``perturbed_starts`` starts moved ``perturb_distance`` metres
  along seeded uniformly random directions and turned ``perturb_angle_deg`` degrees about seeded
  uniformly random axes, R' = exp(theta [u]_x) R (world axes), seeded by (``starts_seed``, crc32 of
  the task); rolled out for ``horizon_factor`` x the longest demo's duration; a start converges if
  its last pose is within ``radius_mm`` and ``radius_deg`` of the goal pose. Reported: the fraction
  (``rate``), and the fractions meeting each of the two bounds alone.
- Times: ``train_time_s`` (the learner's own, ``history["train_time_s"]``; the DMP's mean-demo
  computation and ``imitate``); ``step_time_us``, the median over repeats of one single-point
  evaluation (a field: ``single_point_evaluator`` on a chart point; the DMP: one
  ``CartesianDMP.step``) over ``timing_calls`` demo points; ``pose_step_time_us``, the same for a
  pose in and a twist out (``VelocityField.pose_velocity``; the DMP: its step again).
"""

from __future__ import annotations

import io
import math
import time
import zlib
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any
from typing import Protocol as TypingProtocol

import numpy as np

from lfd import metrics
from lfd.bench.evaluate import TIMING_REPEATS, FieldModel
from lfd.bench.protocol import resolve_names, stable_hash
from lfd.bench.report import figure_paths, fmt, run_line, stats, table
from lfd.bench.runner import BenchResult, run_cells
from lfd.demos import ROBOTTASKS, DemoSet, robottasks
from lfd.errors import ConfigError, LfdError
from lfd.io import atomic_write, finite_or_none
from lfd.pose import PoseChart, geodesic_angle, matrix_quaternions, quaternion_matrices
from lfd.validate import check_ints

PROTOCOL_VERSION = 1
N_DEMOS = 9
QUICK_TASKS: tuple[str, ...] = ("scoop", "pouring")   # the two shortest paths
# Each metric under its own name (the module docstring defines them).
METRICS: tuple[str, ...] = ("dtw_mm", "dtw_angle_deg", "rmse_mm", "final_mm", "final_deg")
LABELS: dict[str, str] = {"dtw_mm": "DTW (sum, mm)", "dtw_angle_deg": "angle along DTW (°)",
                          "rmse_mm": "RMSE (mm)", "final_mm": "final (mm)", "final_deg": "final (°)"}
FORMATS: dict[str, str] = {"dtw_mm": ".0f", "dtw_angle_deg": ".2f", "rmse_mm": ".1f", "final_mm": ".2f",
                           "final_deg": ".2f"}


@dataclass(frozen=True)
class RobotTasksProtocol:
    """The fixed settings of one robot-tasks run (see the module docstring).

    Every field is a setting of the protocol, described beside it with its unit; a bad value is a
    ``ConfigError``. ``to_dict`` (with ``PROTOCOL_VERSION``) keys the result cache.
    """

    perturbed_starts: int = 8         # perturbed starts around each demo start
    perturb_distance: float = 0.05    # m, each perturbed start's distance from its demo start
    perturb_angle_deg: float = 30.0   # degrees, each perturbed start's turn from its demo start
    starts_seed: int = 0              # seed of the perturbations (independent of the learner's seed)
    radius_mm: float = 1.0            # convergence: final position within this of the goal, mm
    radius_deg: float = 1.0           # ... and final orientation within this of the goal orientation, deg
    horizon_factor: float = 3.0       # convergence horizon, x the longest demo's duration
    horizon_stride: int = 4           # convergence rollouts output every horizon_stride demo sample intervals
    dtw_step: int = 4                 # DTW on every dtw_step-th sample (as the LASA suite)
    keep_points: int = 200            # samples kept per rollout for the figures
    timing_calls: int = 500           # single-point evaluations timed per repeat (median of repeats)

    def __post_init__(self) -> None:
        check_ints(self, (("perturbed_starts", 0, None), ("starts_seed", 0, None), ("horizon_stride", 1, None),
                          ("dtw_step", 1, None), ("keep_points", 2, None), ("timing_calls", 1, None)),
                   error=ConfigError)
        positive = ("perturb_distance", "radius_mm", "radius_deg", "horizon_factor")
        if not all(_real(getattr(self, k)) and getattr(self, k) > 0 for k in positive):
            raise ConfigError(f"{', '.join(positive)} must be positive numbers")
        if not (_real(self.perturb_angle_deg) and 0 <= self.perturb_angle_deg < 180):
            raise ConfigError(f"perturb_angle_deg must be in [0, 180), got {self.perturb_angle_deg!r}")

    def to_dict(self) -> dict[str, Any]:
        """The settings and ``version`` (PROTOCOL_VERSION), plain JSON values (the cache key)."""
        return {"version": PROTOCOL_VERSION, "suite": "robottasks", **asdict(self)}


def _real(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def resolve_tasks(spec: str, quick: bool = False) -> list[str]:
    """``all`` (or, with quick, the QUICK_TASKS), or a comma list of RoboTasks9 task names."""
    return resolve_names(spec, ROBOTTASKS, tuple(QUICK_TASKS) if quick else None, "RoboTasks9 task(s)")


# ---------------------------------------------------------------- starts, horizon, alignment

@dataclass(frozen=True)
class PoseStarts:
    """Perturbed start poses of one task, ``perturbed_starts`` per demo start, demo by demo.

    x : array, shape (B, 3), positions, m; q : array, shape (B, 4), unit quaternions (w, x, y, z);
    demo : array of int, shape (B,), the demo each start perturbs.
    """

    x: np.ndarray
    q: np.ndarray
    demo: np.ndarray


def _unit(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Uniformly random unit vectors of R^3, shape (*shape, 3)."""
    v = rng.normal(size=(*shape, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def perturbed_starts(demos: DemoSet, task: str, protocol: RobotTasksProtocol) -> PoseStarts:
    """For each demo start (x_i, R_i), ``perturbed_starts`` poses (x_i + d u_ik, exp(theta [w_ik]_x) R_i)
    with d = ``perturb_distance``, theta = ``perturb_angle_deg`` and u_ik, w_ik uniform unit vectors,
    seeded by (starts_seed, crc32(task)); each quaternion signed like its demo start's."""
    if demos.q is None:
        raise ValueError(f"{demos.name}: perturbed start poses need a set of poses")
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng([protocol.starts_seed, zlib.crc32(task.encode())])
    n, k = demos.n_demos, protocol.perturbed_starts
    u, w = _unit(rng, (n, k)), _unit(rng, (n, k))
    x = (demos.x[:, None, 0] + protocol.perturb_distance * u).reshape(-1, 3)
    turn = Rotation.from_rotvec(np.radians(protocol.perturb_angle_deg) * w.reshape(-1, 3)).as_matrix()
    q0 = np.repeat(demos.q[:, 0], k, axis=0)
    q = matrix_quaternions(turn @ quaternion_matrices(q0))
    q *= np.where(np.einsum("ij,ij->i", q, q0) < 0, -1.0, 1.0)[:, None]
    return PoseStarts(x=x, q=q, demo=np.repeat(np.arange(n), k))


def horizon(demos: DemoSet, protocol: RobotTasksProtocol) -> tuple[float, int]:
    """(H, n): H = horizon_factor x the longest demo's duration, on n uniform samples whose step
    is at most horizon_stride demo sample intervals."""
    longest = float(np.max(demos.t[:, -1] - demos.t[:, 0]))
    interval = float(np.mean(np.diff(demos.t, axis=1)))
    h = protocol.horizon_factor * longest
    return h, int(np.ceil(h / (protocol.horizon_stride * interval))) + 1


# ---------------------------------------------------------------- models

class PoseModel(TypingProtocol):
    """What the benchmark asks of a trained learner, in poses (x (..., 3) m, q (..., 4) w first)."""

    learner: str
    config: dict[str, Any]
    train_time_s: float
    history: dict[str, Any]
    integrators: dict[str, str]

    def reproduce(self, x0: np.ndarray, q0: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x0 : (N, 3), q0 : (N, 4), t : (N, T) (each demo's times). Returns x (N, T, 3), q (N, T, 4)."""

    def rollouts(self, x0: np.ndarray, q0: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x0 : (B, 3), q0 : (B, 4), t : (n,) uniform from 0. Returns x (B, n, 3), q (B, n, 4)."""

    def step_times_us(self, x: np.ndarray, q: np.ndarray, calls: int) -> tuple[float, float]:
        """(single-point step, pose step), median microseconds, over poses x (P, 3), q (P, 4)."""


class PoseFieldModel:
    """A pose field (``lfd.train`` on a pose set) as a ``PoseModel``: rollouts in its chart by the
    LASA suite's ``FieldModel`` or ``PhaseFieldModel`` (same solvers), mapped back to poses.

    inner : FieldModel, whose field has a ``PoseChart``.
    """

    def __init__(self, inner: FieldModel) -> None:
        chart = inner.field.chart
        if chart is None:
            raise ValueError("a PoseFieldModel needs a field trained on poses")
        self.inner = inner
        self.chart: PoseChart = chart
        self.learner = inner.learner
        self.config = inner.config
        self.history = inner.history
        self.train_time_s = inner.train_time_s
        self.integrators: dict[str, str] = {}

    def _run(self, x0: np.ndarray, q0: np.ndarray, t: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
        z = self.inner.rollouts(self.chart.to_chart(x0, q0), t)
        self.integrators[what] = self.inner.integrators.pop("rollouts")
        return chart_poses(self.chart, z)

    def reproduce(self, x0: np.ndarray, q0: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = t - t[:, :1]
        if not np.allclose(rel, rel[0], rtol=0, atol=1e-9):
            raise ValueError("the robot-tasks demos share one time grid")
        return self._run(x0, q0, rel[0], "reproduce")

    def rollouts(self, x0: np.ndarray, q0: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._run(x0, q0, t, "rollouts")

    def step_times_us(self, x: np.ndarray, q: np.ndarray, calls: int) -> tuple[float, float]:
        chart_us = self.inner.step_time_us(self.chart.to_chart(x, q), calls)
        pose = self.inner.field.pose_velocity
        pairs = list(zip(x[:calls], q[:calls]))
        for xi, qi in pairs[:20]:
            pose(xi, qi)
        per_call = []
        for _ in range(TIMING_REPEATS):
            t0 = time.perf_counter()
            for xi, qi in pairs:
                pose(xi, qi)
            per_call.append((time.perf_counter() - t0) / len(pairs))
        return chart_us, float(np.median(per_call) * 1e6)


def chart_poses(chart: PoseChart, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses (x (..., 3), q (..., 4)) of chart points z (..., 6) (``PoseChart.from_chart``); a
    non-finite point (a diverged rollout) gives NaN."""
    flat = np.asarray(z, dtype=np.float64).reshape(-1, 6)
    ok = np.isfinite(flat).all(axis=1)
    x, q = np.full((len(flat), 3), np.nan), np.full((len(flat), 4), np.nan)
    if ok.any():
        x[ok], q[ok] = chart.from_chart(flat[ok])
    return x.reshape(z.shape[:-1] + (3,)), q.reshape(z.shape[:-1] + (4,))


def angles_deg(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Geodesic angles [deg] between quaternions q (..., 4) and ref (4,) or (..., 4), broadcast;
    NaN where q is not finite."""
    q = np.asarray(q, dtype=np.float64)
    ref = np.broadcast_to(np.asarray(ref, dtype=np.float64), q.shape)
    ok = np.isfinite(q).all(axis=-1)
    out = np.full(q.shape[:-1], np.nan)
    if ok.any():
        out[ok] = np.degrees(geodesic_angle(quaternion_matrices(q[ok]), quaternion_matrices(ref[ok])))
    return out


def fit_pose(learner: str, demos: DemoSet, seed: int, options: dict[str, Any]) -> PoseModel:
    """Train ``learner`` (``dmp`` or a registered field learner) on the pose set ``demos``."""
    if learner == "dmp":
        from lfd.bench.dmp import fit_cartesian_dmp

        return fit_cartesian_dmp(demos, **options)
    from lfd.bench.evaluate import fit

    inner = fit(learner, demos, seed, options)
    assert isinstance(inner, FieldModel)
    return PoseFieldModel(inner)


# ---------------------------------------------------------------- scoring one cell

def score(x: np.ndarray, q: np.ndarray, demos: DemoSet, dtw_step: int) -> dict[str, list[float]]:
    """Per-demo metrics {name: [N floats]} (module docstring; inf for a diverged rollout) of the
    reproductions x (N, T, 3), q (N, T, 4) against the demos."""
    assert demos.q is not None and demos.goal_q is not None
    per: dict[str, list[float]] = {m: [] for m in METRICS}
    for xi, qi, dx, dq in zip(x, q, demos.x, demos.q):
        if not (np.isfinite(xi).all() and np.isfinite(qi).all()):
            for m in METRICS:
                per[m].append(math.inf)
            continue
        a, b = 1000.0 * xi[::dtw_step], 1000.0 * dx[::dtw_step]
        path = metrics.dtw_path(a, b)
        per["dtw_mm"].append(metrics.dtw(1000.0 * xi, 1000.0 * dx, step=dtw_step))
        per["dtw_angle_deg"].append(float(np.mean(angles_deg(qi[::dtw_step][path[:, 0]],
                                                             dq[::dtw_step][path[:, 1]]))))
        per["rmse_mm"].append(metrics.rmse(1000.0 * xi, 1000.0 * dx))
        per["final_mm"].append(1000.0 * float(np.linalg.norm(xi[-1] - demos.goal)))
        per["final_deg"].append(float(angles_deg(qi[-1], demos.goal_q)))
    return per


def convergence(x: np.ndarray, q: np.ndarray, demos: DemoSet, protocol: RobotTasksProtocol) -> dict[str, Any]:
    """Of the last poses x (B, 3), q (B, 4): the fraction within ``radius_mm`` AND ``radius_deg`` of
    the goal pose (``rate``), within each alone, and the median and largest final errors (inf for a
    diverged rollout)."""
    assert demos.goal_q is not None
    mm = 1000.0 * np.linalg.norm(x - demos.goal, axis=-1)
    deg = angles_deg(q, demos.goal_q)
    mm, deg = np.where(np.isfinite(mm), mm, np.inf), np.where(np.isfinite(deg), deg, np.inf)
    pos, rot = mm <= protocol.radius_mm, deg <= protocol.radius_deg
    n = len(mm)

    def frac(ok: np.ndarray) -> float | None:
        return float(np.mean(ok)) if n else None

    def stat(v: np.ndarray, f: Callable[[np.ndarray], Any]) -> float | None:
        return float(f(v)) if n else None

    return {"rate": frac(pos & rot), "position_rate": frac(pos), "orientation_rate": frac(rot), "n_starts": n,
            "median_final_mm": stat(mm, np.median), "max_final_mm": stat(mm, np.max),
            "median_final_deg": stat(deg, np.median), "max_final_deg": stat(deg, np.max)}


def evaluate_task(learner: str, task: str, seed: int, options: dict[str, Any],
                  protocol: RobotTasksProtocol) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Train and score one (learner, task, seed). Returns the JSON record and the arrays for the
    figures: ``t`` (K,) and ``repro_x`` (N, K, 3), ``repro_deg`` (N, K) on the demos' clock;
    ``horizon_t`` (K',), ``starts_x`` (B, 3), ``rollouts_x`` (B, K', 3), ``rollouts_deg`` (B, K') over
    the horizon (K, K' <= keep_points samples; angles to the goal orientation, deg)."""
    demos = robottasks(task)
    assert demos.q is not None and demos.goal_q is not None
    model = fit_pose(learner, demos, seed, options)
    if model.history.get("interrupted"):  # the learner swallowed Ctrl-C: never score or cache it
        raise KeyboardInterrupt
    x, q = model.reproduce(demos.x[:, 0], demos.q[:, 0], demos.t)
    per = score(x, q, demos, protocol.dtw_step)

    st = perturbed_starts(demos, task, protocol)
    h, n = horizon(demos, protocol)
    rx, rq = model.rollouts(st.x, st.q, np.linspace(0.0, h, n))
    conv = {**convergence(rx[:, -1], rq[:, -1], demos, protocol), "horizon_s": h, "n_steps": n,
            "perturbed_starts": protocol.perturbed_starts, "distance_m": protocol.perturb_distance,
            "angle_deg": protocol.perturb_angle_deg, "radius_mm": protocol.radius_mm,
            "radius_deg": protocol.radius_deg}

    px, pq = demos.x.reshape(-1, 3), demos.q.reshape(-1, 4)
    stride = max(1, len(px) // protocol.timing_calls)
    step_us, pose_us = model.step_times_us(px[::stride], pq[::stride], protocol.timing_calls)

    keep = np.unique(np.linspace(0, demos.n_samples - 1, protocol.keep_points).round().astype(int))
    keep_h = np.unique(np.linspace(0, n - 1, protocol.keep_points).round().astype(int))
    record = {
        "learner": learner, "task": task, "seed": seed, "config": model.config,
        "train_time_s": model.train_time_s, "step_time_us": step_us, "pose_step_time_us": pose_us,
        "metrics": {m: float(np.mean(v)) for m, v in per.items()}, "per_demo": per, "convergence": conv,
        "history": model.history, "integrators": dict(model.integrators),
    }
    arrays = {
        "t": demos.t[0, keep] - demos.t[0, 0], "repro_x": x[:, keep], "repro_deg": angles_deg(q[:, keep], demos.goal_q),
        "horizon_t": np.linspace(0.0, h, n)[keep_h], "starts_x": st.x, "rollouts_x": rx[:, keep_h],
        "rollouts_deg": angles_deg(rq[:, keep_h], demos.goal_q),
    }
    return record, arrays


# ---------------------------------------------------------------- cells, cache, parallel runs

def resolve_config(learner: str, options: dict[str, Any]) -> dict[str, Any]:
    """The learner's full config for ``options`` (defaults filled in); ConfigError if invalid. The
    DMP here is the Cartesian one (``lfd.bench.dmp.CartesianDMPConfig``)."""
    if learner == "dmp":
        from lfd.bench.dmp import make_cartesian_config

        return asdict(make_cartesian_config(**options))
    from lfd.bench.runner import resolve_config as field_config

    return field_config(learner, options)


@dataclass(frozen=True)
class TaskCell:
    """One unit of work: one learner trained with one seed on one task, and scored.

    Build it with ``make``, which computes ``hash``; each field is described beside it.
    """

    learner: str                                      # a name of lfd.learners.LEARNERS, or "dmp"
    task: str                                         # a RoboTasks9 task
    seed: int                                         # the learner's seed
    options: dict[str, Any] = field(hash=False)       # the learner's keyword options, as for lfd.train
    protocol: RobotTasksProtocol = field(hash=False)  # the suite's fixed settings
    hash: str = ""                                    # the cache key: protocol, learner, full config, task, seed

    @classmethod
    def make(cls, learner: str, task: str, seed: int, options: dict[str, Any],
             protocol: RobotTasksProtocol) -> TaskCell:
        key = {"protocol": protocol.to_dict(), "learner": learner,
               "config": resolve_config(learner, options), "task": task, "seed": seed}
        return cls(learner, task, seed, dict(options), protocol, stable_hash(key))

    @property
    def stem(self) -> str:
        return cell_stem(self.learner, self.task, self.seed)


def cell_stem(learner: str, task: str, seed: int) -> str:
    """The cache file stem of a cell: ``<learner>__<task>__seed<seed>``."""
    return f"{learner}__{task}__seed{seed}"


def compute_task_cell(cell: TaskCell) -> tuple[dict[str, Any], bytes]:
    """Train and score one cell in a worker (one torch thread): its record (with ``hash`` and
    ``cell_s``) and its figure arrays as NPZ bytes; writes nothing. A learner that refuses the
    task (an ``LfdError``, e.g. demos it cannot train on) gives ``({"error": one line}, b"")``."""
    import torch

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    try:
        record, arrays = evaluate_task(cell.learner, cell.task, cell.seed, cell.options, cell.protocol)
    except LfdError as e:
        text = str(e).strip()
        return {"error": (text.splitlines()[0] if text else type(e).__name__)[:300]}, b""
    record = finite_or_none({"hash": cell.hash, **record, "cell_s": time.perf_counter() - t0})
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]
    return record, buf.getvalue()


def run_task_cells(cells: list[TaskCell], cache: str | Path, workers: int = 1, fresh: bool = False,
                   progress: bool = True, executor: str = "local", address: str | None = None) -> BenchResult:
    """Run every cell not already in ``cache`` (all with ``fresh``) through ``lfd.bench.runner.run_cells``,
    as the LASA suite does: the same cache entries, executors and retries; a cell whose learner refuses
    its task is listed in ``failed`` and not cached. Returns records in the order of ``cells``."""
    return run_cells(cells, cache, workers, fresh, progress, executor, address, compute=compute_task_cell,
                     desc="robottasks")


def load_task_arrays(cache: str | Path, record: dict[str, Any]) -> dict[str, np.ndarray]:
    """The figure arrays of a record (``evaluate_task``) from its cache entry."""
    with np.load(Path(cache) / f"{cell_stem(record['learner'], record['task'], record['seed'])}.npz",
                 allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


# ---------------------------------------------------------------- aggregates

def _num(v: Any) -> float:
    return float(v) if v is not None else math.inf


def per_task(records: list[dict[str, Any]], learner: str) -> dict[str, dict[str, Any]]:
    """{task: values} for one learner, averaged over seeds: each metric, ``converged`` (fraction of
    the perturbed starts), ``converged_position``, ``converged_orientation``, ``n_starts``,
    ``n_converged``, ``train_time_s``, ``step_time_us``, ``pose_step_time_us``, ``cell_s`` (summed),
    ``fallback`` (a rollout needed the fixed-step rk4 fallback of ``lfd.bench.evaluate.FieldModel``)."""
    by: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        if r["learner"] == learner:
            by.setdefault(r["task"], []).append(r)
    out: dict[str, dict[str, Any]] = {}
    for task, rs in by.items():
        row: dict[str, Any] = {m: float(np.mean([_num(r["metrics"][m]) for r in rs])) for m in METRICS}
        conv = [r["convergence"] for r in rs]
        for key, name in (("rate", "converged"), ("position_rate", "converged_position"),
                          ("orientation_rate", "converged_orientation")):
            row[name] = float(np.mean([c[key] if c[key] is not None else math.nan for c in conv]))
        row["n_starts"] = int(sum(c["n_starts"] for c in conv))
        row["n_converged"] = int(round(sum((c["rate"] or 0.0) * c["n_starts"] for c in conv)))
        for key in ("train_time_s", "step_time_us", "pose_step_time_us"):
            row[key] = float(np.mean([_num(r[key]) for r in rs]))
        row["cell_s"] = float(np.sum([_num(r.get("cell_s")) for r in rs]))
        row["fallback"] = any(str(v).startswith("rk4 (") for r in rs for v in r.get("integrators", {}).values())
        out[task] = row
    return out


def summarize(records: list[dict[str, Any]], learners: list[str]) -> dict[str, Any]:
    """{learner: {"tasks", each metric {mean, median} over tasks, "converged" (pooled over all
    perturbed starts of all tasks), "converged_position", "converged_orientation" (means over tasks),
    "tasks_all_converged", "train_time_s" (mean, median, total), "step_time_us", "pose_step_time_us",
    "cell_s_total"}}."""
    out: dict[str, Any] = {}
    for learner in learners:
        rows = per_task(records, learner)
        if not rows:
            continue
        vals = list(rows.values())
        s: dict[str, Any] = {"tasks": len(rows)}
        for m in METRICS:
            s[m] = stats([v[m] for v in vals])
        s["converged"] = sum(v["n_converged"] for v in vals) / max(sum(v["n_starts"] for v in vals), 1)
        s["converged_position"] = stats([v["converged_position"] for v in vals])["mean"]
        s["converged_orientation"] = stats([v["converged_orientation"] for v in vals])["mean"]
        s["tasks_all_converged"] = sum(v["converged"] == 1.0 for v in vals)
        s["train_time_s"] = {**stats([v["train_time_s"] for v in vals]),
                             "total": float(sum(v["train_time_s"] for v in vals))}
        s["step_time_us"] = stats([v["step_time_us"] for v in vals])
        s["pose_step_time_us"] = stats([v["pose_step_time_us"] for v in vals])
        s["cell_s_total"] = float(sum(v["cell_s"] for v in vals))
        out[learner] = s
    return out


# ---------------------------------------------------------------- report

COLORS: dict[str, str] = {"node": "tab:purple", "contraction": "tab:red", "tracking": "tab:green", "dmp": "tab:orange"}


def summary_table(summary: dict[str, Any]) -> str:
    """One row per learner, each metric 'mean / median' over tasks."""
    header = (["learner", "tasks"] + [LABELS[m] for m in METRICS]
              + ["converged (perturbed)", "train (s)", "step (µs)", "pose step (µs)"])
    rows = []
    for learner, s in summary.items():
        row = [learner, str(s["tasks"])]
        row += [f"{fmt(s[m]['mean'], FORMATS[m])} / {fmt(s[m]['median'], FORMATS[m])}" for m in METRICS]
        row += [f"{100 * s['converged']:.1f}% ({s['tasks_all_converged']}/{s['tasks']} tasks all)",
                f"{fmt(s['train_time_s']['mean'], '.2f')} / {fmt(s['train_time_s']['median'], '.2f')}",
                f"{fmt(s['step_time_us']['mean'], '.1f')} / {fmt(s['step_time_us']['median'], '.1f')}",
                f"{fmt(s['pose_step_time_us']['mean'], '.1f')} / {fmt(s['pose_step_time_us']['median'], '.1f')}"]
        rows.append(row)
    return table(header, rows)


def task_table(rows: dict[str, dict[str, Any]], tasks: list[str]) -> str:
    """One row per task, then the Mean and Median rows over tasks."""
    tasks = [t for t in tasks if t in rows]
    pct = lambda v: "—" if math.isnan(v) else f"{100 * v:.1f}%"
    cols: list[tuple[str, str, Callable[[float], str]]] = [
        (LABELS[m], m, (lambda spec: lambda v: fmt(v, spec))(FORMATS[m])) for m in METRICS]
    cols += [("converged", "converged", pct), ("position ok", "converged_position", pct),
             ("orientation ok", "converged_orientation", pct),
             ("train (s)", "train_time_s", lambda v: fmt(v, ".2f")),
             ("step (µs)", "step_time_us", lambda v: fmt(v, ".1f")),
             ("pose step (µs)", "pose_step_time_us", lambda v: fmt(v, ".1f"))]
    body = [[t] + [fmt(rows[t][key]) for _, key, fmt in cols] for t in tasks]
    for name, agg in (("**Mean**", np.mean), ("**Median**", np.median)):
        with np.errstate(invalid="ignore"):
            body.append([name] + [fmt(float(agg([rows[t][key] for t in tasks]))) for _, key, fmt in cols])
    return table(["task"] + [c[0] for c in cols], body)


def reading(summary: dict[str, Any], rows_by: dict[str, dict[str, dict[str, Any]]], protocol: dict[str, Any],
            failed: list[dict[str, Any]]) -> str:
    """A paragraph per learner generated from the numbers."""
    parts = []
    for learner, s in summary.items():
        rows = rows_by[learner]
        worst = sorted(rows, key=lambda k: -rows[k]["dtw_mm"])[:3]
        text = (f"**{learner}** reproduces the demos of {s['tasks']} task(s) with position DTW "
                f"{fmt(s['dtw_mm']['mean'], '.0f')} mm (median {fmt(s['dtw_mm']['median'], '.0f')}) and a mean "
                f"orientation error of {fmt(s['dtw_angle_deg']['mean'], '.2f')}° along the alignment; its "
                f"reproductions end {fmt(s['final_mm']['mean'], '.2f')} mm and {fmt(s['final_deg']['mean'], '.2f')}° "
                f"from the goal pose (means). {100 * s['converged']:.1f}% of the perturbed starts "
                f"({100 * protocol['perturb_distance']:g} cm, {protocol['perturb_angle_deg']:g}°) "
                f"end within {protocol['radius_mm']:g} mm and {protocol['radius_deg']:g}° of it after "
                f"{protocol['horizon_factor']:g}x the demo duration. Largest DTW: "
                + ", ".join(f"{k} ({rows[k]['dtw_mm']:.0f})" for k in worst) + ". "
                f"Its cells took {s['cell_s_total'] / 60:.1f} min of worker time in all (training and scoring). ")
        short = [k for k in rows if rows[k]["converged"] < 1.0]
        if short:
            text += ("Not every perturbed start converges on: " + ", ".join(
                f"{k} ({100 * rows[k]['converged']:.0f}%; position {100 * rows[k]['converged_position']:.0f}%, "
                f"orientation {100 * rows[k]['converged_orientation']:.0f}%)" for k in short) + ".")
        else:
            text += "Every perturbed start converges on every task."
        fallback = [k for k in rows if rows[k]["fallback"]]
        if fallback:
            text += (" dopri5 gave up and the fixed-step rk4 fallback ran on: " + ", ".join(fallback) + ".")
        parts.append(text)
    if "dmp" in summary:
        parts.append("The Cartesian DMP is time-indexed and converges by construction (a spring-damper on "
                     "position and orientation once its phase has decayed), so its convergence is not the "
                     "evidence it is for an autonomous field; its reproductions are timed by tau = the "
                     "demo's duration.")
    if failed:
        parts.append("Cells missing from the tables, their learner refused the task (not cached; a later run "
                     "tries them again): "
                     + "; ".join(f"{f['cell']} ({f['reason']})" for f in failed) + ".")
    return "\n\n".join(parts)


def _task_records(records: list[dict[str, Any]], task: str, learners: list[str]) -> dict[str, dict[str, Any]]:
    """{learner: its record of ``task`` with the lowest seed}."""
    out: dict[str, dict[str, Any]] = {}
    for r in sorted(records, key=lambda r: r["seed"]):
        if r["task"] == task and r["learner"] in learners:
            out.setdefault(r["learner"], r)
    return {k: out[k] for k in learners if k in out}


def figure_paths_3d(records: list[dict[str, Any]], task: str, learners: list[str],
                    arrays: Callable[[dict[str, Any]], dict[str, np.ndarray]], path: Path) -> None:
    """One 3-D panel per learner, equal axis scales, viewed across the demos' thinnest horizontal
    extent: the task's demos (wide, grey-black), the reproductions from the demo starts (the
    learner's colour) and the rollouts from the perturbed starts (light grey, cut off outside the
    demos' bounding box grown by 15%), positions in m."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    recs = _task_records(records, task, learners)
    demos = robottasks(task)
    lo, hi = demos.bounds(0.15)
    ext = np.maximum(hi - lo, 1e-3)
    n = max(len(recs), 1)
    cols = 2 if n == 4 else n                  # four learners as 2 x 2: the panels stay readable
    rows = -(-n // cols)
    fig = Figure(figsize=(4.6 * cols, 3.4 * rows + 0.4))
    for i, (learner, r) in enumerate(recs.items()):
        a = arrays(r)
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        inside = ((a["rollouts_x"] >= lo) & (a["rollouts_x"] <= hi)).all(axis=-1, keepdims=True)
        for traj in np.where(inside, a["rollouts_x"], np.nan):
            ax.plot(*traj.T, color="0.7", lw=0.4, alpha=0.6)
        for x in demos.x:
            ax.plot(*x.T, color="0.15", lw=1.8, alpha=0.45)
        for y in a["repro_x"]:
            ax.plot(*y.T, color=COLORS.get(learner, "tab:blue"), lw=0.9)
        ax.scatter(*demos.goal, marker="*", s=70, color="gold", edgecolor="k", zorder=5)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(tuple(ext), zoom=1.25)
        ax.view_init(elev=25, azim=-20 if ext[0] < ext[1] else -70)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(3))
        ax.tick_params(labelsize=6, pad=0)
        ax.set_xlabel("x", fontsize=7, labelpad=-8)
        ax.set_ylabel("y", fontsize=7, labelpad=-8)
        ax.set_zlabel("z", fontsize=7, labelpad=-8)
        ax.set_title(f"{learner}  DTW {fmt(r['metrics']['dtw_mm'], '.0f')} mm", fontsize=9)
    fig.suptitle(f"{task}: demos (wide, dark), reproductions from the demo starts (colour),\n"
                 "rollouts from the perturbed starts (light grey); m", fontsize=9, y=0.99)
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.02, top=1.0 - 0.5 / (3.4 * rows + 0.4), wspace=0.05,
                        hspace=0.12)
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=90))


def figure_angles(records: list[dict[str, Any]], task: str, learners: list[str],
                  arrays: Callable[[dict[str, Any]], dict[str, np.ndarray]], path: Path,
                  radius_deg: float) -> None:
    """One panel per learner: the geodesic angle to the goal orientation over time (log scale), of
    the demos (black), the reproductions (the learner's colour) and the perturbed rollouts over the
    horizon (grey), with the convergence bound (dashed)."""
    from matplotlib.figure import Figure

    recs = _task_records(records, task, learners)
    demos = robottasks(task)
    assert demos.q is not None and demos.goal_q is not None
    demo_deg = angles_deg(demos.q, demos.goal_q)
    fig = Figure(figsize=(3.4 * max(len(recs), 1), 2.9))
    floor = 1e-3
    axes: list[Any] = []
    for i, (learner, r) in enumerate(recs.items()):
        a = arrays(r)
        ax = fig.add_subplot(1, max(len(recs), 1), i + 1, sharey=axes[0] if axes else None)
        axes.append(ax)
        for v in a["rollouts_deg"]:
            ax.plot(a["horizon_t"], np.maximum(v, floor), color="0.6", lw=0.4, alpha=0.5)
        for ti, v in zip(demos.t, demo_deg):
            ax.plot(ti - ti[0], np.maximum(v, floor), color="k", lw=0.9, alpha=0.8)
        for v in a["repro_deg"]:
            ax.plot(a["t"], np.maximum(v, floor), color=COLORS.get(learner, "tab:blue"), lw=1.0)
        ax.axhline(radius_deg, color="k", ls="--", lw=0.7)
        ax.set_yscale("log")
        ax.set_ylim(floor, 200.0)
        ax.set_xlabel("t (s)", fontsize=7)
        ax.tick_params(labelsize=6)
        conv = r["convergence"]["rate"]
        ax.set_title(f"{learner}  converged {'—' if conv is None else f'{100 * conv:.0f}%'}", fontsize=8)
    if axes:
        axes[0].set_ylabel("angle to goal (°)", fontsize=7)
    fig.suptitle(f"{task}: geodesic angle to the goal orientation; demos (black), reproductions (colour), "
                 f"perturbed starts (grey), {radius_deg:g}° (dashed)", fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=90))


def write_report(path: str | Path, records: list[dict[str, Any]], learners: list[str], tasks: list[str],
                 protocol: dict[str, Any], run: dict[str, Any],
                 arrays: Callable[[dict[str, Any]], dict[str, np.ndarray]], notes: str | None = None) -> list[Path]:
    """Write the markdown report and its figures, ``figures/<report stem>_<task>_paths.png`` and
    ``..._angle.png`` beside it (``lfd.bench.report.figure_paths``). Returns the figure paths."""
    path = Path(path)
    summary = summarize(records, learners)
    rows_by = {learner: per_task(records, learner) for learner in summary}
    ran = [t for t in tasks if any(t in rows for rows in rows_by.values())]
    paths = figure_paths(path, [f"{t}_{kind}" for t in ran for kind in ("paths", "angle")])
    for t in ran:
        figure_paths_3d(records, t, list(summary), arrays, paths[f"{t}_paths"])
        figure_angles(records, t, list(summary), arrays, paths[f"{t}_angle"], float(protocol["radius_deg"]))
    p = protocol
    failed = run.get("failed") or []
    md = [
        "# RoboTasks9 benchmark",
        "",
        f"Generated by `{run['command']}`. Protocol: [docs/benchmark.md](../docs/benchmark.md) "
        f"(robot tasks, version {p['version']}).",
        "",
        f"- {len(tasks)} task(s), seeds {run['seeds']}, every learner trained on all {N_DEMOS} demos and scored on "
        f"them; positions in mm, orientations in degrees (geodesic angle). DTW = sum of position distances along the "
        f"best monotone alignment over every {p['dtw_step']}th sample; the angle along DTW is the mean geodesic "
        "angle over that alignment's pairs; final = the reproduction's last pose against the goal pose.",
        f"- Convergence: {p['perturbed_starts']} starts per demo start, {100 * p['perturb_distance']:g} cm away "
        f"and turned {p['perturb_angle_deg']:g}° about random axes; converged if within {p['radius_mm']:g} mm and "
        f"{p['radius_deg']:g}° of the goal pose after {p['horizon_factor']:g}x the demo duration.",
        "- Step: one single-point evaluation (a field on a chart point; the DMP one step); pose step: a pose in, "
        "a twist out (`pose_velocity`; the DMP its step).",
        run_line({**run, "failed": [f for f in failed if not f.get("refused")]}),
        "",
        "## Summary (mean / median over tasks)",
        "",
        summary_table(summary),
        "",
        "## Reading",
        "",
        reading(summary, rows_by, protocol, [f for f in failed if f.get("refused")]),
        "",
    ]
    if notes:
        md += [notes.strip(), ""]
    for learner in summary:
        md += [f"## Per task: {learner}", "", task_table(rows_by[learner], tasks), ""]
    md += ["## Figures", ""]
    for t in ran:
        for kind, what in (("paths", "positions"), ("angle", "angle to the goal")):
            md += [f"![{t} {what}]({paths[f'{t}_{kind}'].relative_to(path.parent).as_posix()})", ""]
    text = "\n".join(md)
    atomic_write(path, lambda f: f.write(text.encode()))
    return [paths[k] for k in paths]
