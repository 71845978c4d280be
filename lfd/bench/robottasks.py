"""The RoboTasks9 suite behind ``lfd bench robottasks``: 9 tasks of poses, every learner in one harness.

Everything a number depends on, other than the learner and its seed, is a field of
``RobotTasksProtocol``; its hash keys the result cache (docs/benchmark.md).

- Data: ``lfd.demos.robottasks(task)``, 9 demos of 1000 poses at 60 Hz, positions in m, unit
  quaternions (w, x, y, z); the goal pose is the mean final position and chordal mean final orientation.
- States: poses (``lfd.bench.spaces.POSES``): field learners learn chart points z = (x, l log(R_g^T R))
  (``lfd.pose``) and run in their chart; the DMP baseline is ``CartesianDMP``.
- Per demo: ``dtw_mm`` (DTW of the positions in mm, every ``dtw_step``-th sample), ``dtw_angle_deg``
  (the mean geodesic angle over the pairs of that alignment, ``lfd.metrics.dtw_path``), ``rmse_mm``,
  and ``final_mm``, ``final_deg`` (the reproduction's last pose against the goal it was run toward).
- Convergence (in-sample): from each demo start, ``perturbed_starts`` starts moved
  ``perturb_distance`` m along seeded random directions and turned ``perturb_angle_deg`` degrees about
  seeded random axes (world axes), seeded by (``starts_seed``, crc32 of the task), rolled out for
  ``horizon_factor`` x the longest demo's duration; converged within ``radius_mm`` and ``radius_deg``.
- Times (in-sample): ``step_time_us``, one evaluation of the model's own step (a field on a chart
  point; the DMP one ``step``); ``pose_step_time_us``, a pose in and a twist out (the DMP its step).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lfd import metrics
from lfd.bench.model import Model
from lfd.bench.protocol import horizon
from lfd.bench.report import TRAIN_ROW, TRAIN_SUMMARY, figure_paths, fmt, mean_median, pct, row_value
from lfd.bench.spaces import POSES
from lfd.bench.suite import IN_SAMPLE, Column, Suite
from lfd.bench.summary import stats
from lfd.demos import ROBOTTASKS, DemoSet, robottasks
from lfd.errors import ConfigError
from lfd.pose import geodesic_angle, matrix_quaternions, quaternion_matrices
from lfd.validate import check_ints

# Literals, read by ``lfd --help`` without importing this module: the command's help, the word for a
# unit, the units of --quick, the protocol's command-line options (flag, field, help).
HELP = "the RoboTasks9 pose benchmark (9 tasks, positions and orientations)"
UNIT = "task"
QUICK_UNITS: tuple[str, ...] = ("scoop", "pouring")   # the two shortest paths
PROTOCOL_OPTIONS: tuple[tuple[str, str, str], ...] = (
    ("--perturbed-starts", "perturbed_starts",
     "perturbed starts (5 cm, 30 degrees) around each demo start (default 8)"),)
PROTOCOL_VERSION = 2   # 2: the held-out split; final errors against the goal each reproduction runs toward
N_DEMOS = 9
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


def convergence(x: np.ndarray, q: np.ndarray, goal: np.ndarray, protocol: RobotTasksProtocol) -> dict[str, Any]:
    """Of the last poses x (B, 3), q (B, 4): the fraction within ``radius_mm`` AND ``radius_deg`` of
    the goal pose, shape (7,) (``rate``), within each alone, and the median and largest final errors
    (inf for a diverged rollout)."""
    mm = 1000.0 * np.linalg.norm(x - goal[:3], axis=-1)
    deg = angles_deg(q, goal[3:])
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


class RobotTasksSuite(Suite):
    """The RoboTasks9 pose suite (module docstring); ``protocol`` is a ``RobotTasksProtocol``."""

    name = "robottasks"
    title = "RoboTasks9 benchmark"
    unit = UNIT
    units = ROBOTTASKS
    quick_units = QUICK_UNITS
    protocol_type = RobotTasksProtocol
    quick_options = {"contraction": {"iterations": 60}, "node": {"iterations": 200},
                     "contracting_node": {"iterations": 100},
                     "dmp": {"int_dt": 1 / 60}}   # the DMP's orientation at 60 Hz
    n_demos = N_DEMOS
    space = POSES
    metrics = METRICS
    labels = LABELS
    formats = FORMATS
    headline = ("dtw_mm", "dtw_angle_deg", "final_mm")
    protocol: RobotTasksProtocol

    def demos(self, unit: str) -> DemoSet:
        return robottasks(unit)

    def score(self, y: np.ndarray, v: np.ndarray, demos: DemoSet, scored: list[int],
              goal: np.ndarray) -> dict[str, list[float]]:
        assert demos.q is not None
        step = self.protocol.dtw_step
        per: dict[str, list[float]] = {m: [] for m in METRICS}
        for i, yi in zip(scored, y):
            xi, qi, dx, dq = yi[:, :3], yi[:, 3:], demos.x[i], demos.q[i]
            if not np.isfinite(yi).all():
                for m in METRICS:
                    per[m].append(math.inf)
                continue
            path = metrics.dtw_path(1000.0 * xi[::step], 1000.0 * dx[::step])
            per["dtw_mm"].append(metrics.dtw(1000.0 * xi, 1000.0 * dx, step=step))
            per["dtw_angle_deg"].append(float(np.mean(angles_deg(qi[::step][path[:, 0]], dq[::step][path[:, 1]]))))
            per["rmse_mm"].append(metrics.rmse(1000.0 * xi, 1000.0 * dx))
            per["final_mm"].append(1000.0 * float(np.linalg.norm(xi[-1] - goal[:3])))
            per["final_deg"].append(float(angles_deg(qi[-1], goal[3:])))
        return per

    def in_sample(self, model: Model, demos: DemoSet, unit: str,
                  y: np.ndarray) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """``convergence``, ``step_time_us`` and ``pose_step_time_us``; the arrays ``t`` (K,), ``repro_x``
        (N, K, 3) and ``repro_deg`` (N, K) on the demos' clock, ``horizon_t`` (K',), ``starts_x`` (B, 3),
        ``rollouts_x`` (B, K', 3) and ``rollouts_deg`` (B, K') over the horizon (K, K' <= keep_points;
        angles to the goal orientation, deg)."""
        p = self.protocol
        goal = self.space.goal(demos)
        st = perturbed_starts(demos, unit, p)
        h, n = horizon(demos, p)
        r = model.rollouts(np.concatenate([st.x, st.q], axis=1), np.linspace(0.0, h, n))
        conv = {**convergence(r[:, -1, :3], r[:, -1, 3:], goal, p), "horizon_s": h, "n_steps": n,
                "perturbed_starts": p.perturbed_starts, "distance_m": p.perturb_distance,
                "angle_deg": p.perturb_angle_deg, "radius_mm": p.radius_mm, "radius_deg": p.radius_deg}
        states = self.space.states(demos).reshape(-1, 7)
        states = states[::max(1, len(states) // p.timing_calls)]
        timing = {"step_time_us": model.step_time_us(states, p.timing_calls),
                  "pose_step_time_us": model.state_step_time_us(states, p.timing_calls)}
        keep = np.unique(np.linspace(0, demos.n_samples - 1, p.keep_points).round().astype(int))
        keep_h = np.unique(np.linspace(0, n - 1, p.keep_points).round().astype(int))
        arrays = {"t": demos.t[0, keep] - demos.t[0, 0], "repro_x": y[:, keep, :3],
                  "repro_deg": angles_deg(y[:, keep, 3:], goal[3:]), "horizon_t": np.linspace(0.0, h, n)[keep_h],
                  "starts_x": st.x, "rollouts_x": r[:, keep_h, :3],
                  "rollouts_deg": angles_deg(r[:, keep_h, 3:], goal[3:])}
        return {**timing, "convergence": conv}, arrays

    def unit_row(self, records: list[dict[str, Any]]) -> dict[str, Any]:
        """``converged`` (fraction of the perturbed starts), ``converged_position``,
        ``converged_orientation``, ``n_starts``, ``n_converged``, ``step_time_us``, ``pose_step_time_us``."""
        conv = [r["convergence"] for r in records]
        row: dict[str, Any] = {name: float(np.mean([c[key] if c[key] is not None else math.nan for c in conv]))
                               for key, name in (("rate", "converged"), ("position_rate", "converged_position"),
                                                 ("orientation_rate", "converged_orientation"))}
        row["n_starts"] = int(sum(c["n_starts"] for c in conv))
        row["n_converged"] = int(round(sum((c["rate"] or 0.0) * c["n_starts"] for c in conv)))
        for key in ("step_time_us", "pose_step_time_us"):
            row[key] = float(np.mean([r[key] if r[key] is not None else math.inf for r in records]))
        return row

    def summary_extras(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        """``converged`` (pooled over all perturbed starts of all tasks), ``converged_position``,
        ``converged_orientation`` (means over tasks), ``units_all_converged``, ``step_time_us``,
        ``pose_step_time_us``."""
        return {"converged": sum(v["n_converged"] for v in rows) / max(sum(v["n_starts"] for v in rows), 1),
                "converged_position": stats([v["converged_position"] for v in rows])["mean"],
                "converged_orientation": stats([v["converged_orientation"] for v in rows])["mean"],
                "units_all_converged": sum(v["converged"] == 1.0 for v in rows),
                "step_time_us": stats([v["step_time_us"] for v in rows]),
                "pose_step_time_us": stats([v["pose_step_time_us"] for v in rows])}

    # ---------------------------------------------------------------- report

    def intro(self, units: list[str], run: dict[str, Any]) -> list[str]:
        p = self.protocol
        return [
            f"- {len(units)} task(s), seeds {run['seeds']}; positions in mm, orientations in degrees (geodesic angle). "
            f"DTW = sum of position distances along the best monotone alignment over every {p.dtw_step}th sample; "
            "the angle along DTW is the mean geodesic angle over that alignment's pairs; final = the reproduction's "
            "last pose against the goal pose it was run toward.",
            f"- Convergence (in-sample): {p.perturbed_starts} starts per demo start, {100 * p.perturb_distance:g} cm "
            f"away and turned {p.perturb_angle_deg:g}° about random axes; converged if within {p.radius_mm:g} mm and "
            f"{p.radius_deg:g}° of the goal pose after {p.horizon_factor:g}x the demo duration.",
            "- Step: one single-point evaluation (a field on a chart point; the DMP one step); pose step: a pose in, "
            "a twist out (`pose_velocity`; the DMP its step).",
        ]

    def summary_columns(self) -> list[Column]:
        return [Column("converged (perturbed)", lambda s: s,
                       lambda s: f"{pct(s['converged'])} ({s['units_all_converged']}/{s['units']} tasks all)"),
                TRAIN_SUMMARY, mean_median("step (µs)", "step_time_us", ".1f"),
                mean_median("pose step (µs)", "pose_step_time_us", ".1f")]

    def unit_columns(self) -> list[Column]:
        return [Column("converged", lambda r: r["converged"], pct),
                Column("position ok", lambda r: r["converged_position"], pct),
                Column("orientation ok", lambda r: r["converged_orientation"], pct),
                TRAIN_ROW, row_value("step (µs)", "step_time_us", ".1f"),
                row_value("pose step (µs)", "pose_step_time_us", ".1f")]

    def reading(self, learner: str, summary: dict[str, Any], rows: dict[str, dict[str, Any]],
                run: dict[str, Any]) -> str:
        s, m, p = summary, summary["metrics"], self.protocol
        worst = sorted(rows, key=lambda k: -rows[k]["metrics"]["dtw_mm"])[:3]
        text = (f"**{learner}** reproduces the demos of {s['units']} task(s) with position DTW "
                f"{fmt(m['dtw_mm']['mean'], '.0f')} mm (median {fmt(m['dtw_mm']['median'], '.0f')}) and a mean "
                f"orientation error of {fmt(m['dtw_angle_deg']['mean'], '.2f')}° along the alignment; its "
                f"reproductions end {fmt(m['final_mm']['mean'], '.2f')} mm and {fmt(m['final_deg']['mean'], '.2f')}° "
                f"from the goal pose (means). {pct(s['converged'])} of the perturbed starts "
                f"({100 * p.perturb_distance:g} cm, {p.perturb_angle_deg:g}°) end within {p.radius_mm:g} mm and "
                f"{p.radius_deg:g}° of it after {p.horizon_factor:g}x the demo duration. Largest DTW: "
                + ", ".join(f"{k} ({rows[k]['metrics']['dtw_mm']:.0f})" for k in worst) + ". "
                f"Its cells took {s['cell_s_total'] / 60:.1f} min of worker time in all (training and scoring). ")
        short = [k for k in rows if rows[k]["converged"] < 1.0]
        text += ("Not every perturbed start converges on: " + ", ".join(
            f"{k} ({100 * rows[k]['converged']:.0f}%; position {100 * rows[k]['converged_position']:.0f}%, "
            f"orientation {100 * rows[k]['converged_orientation']:.0f}%)" for k in short) + "." if short
                 else "Every perturbed start converges on every task.")
        fallback = [k for k in rows if rows[k]["fallback"]]
        if fallback:
            text += " dopri5 gave up and the fixed-step rk4 fallback ran on: " + ", ".join(fallback) + "."
        return text

    def closing(self, summary: dict[str, Any]) -> list[str]:
        if "dmp" not in summary:
            return []
        return ["The Cartesian DMP is time-indexed and converges by construction (a spring-damper on position and "
                "orientation once its phase has decayed), so its convergence is not the evidence it is for an "
                "autonomous field; its reproductions are timed by tau = the demo's duration."]

    def figures(self, path: Path, records: list[dict[str, Any]], learners: list[str], units: list[str],
                arrays: Any) -> dict[str, list[tuple[str, Path]]]:
        """Per task with in-sample records: ``<report>_<task>_paths.png`` (``figure_paths_3d``) and
        ``<report>_<task>_angle.png`` (``figure_angles``), at the report's end."""
        from lfd.bench.robottasks_figures import figure_angles, figure_paths_3d, task_records

        ran = [t for t in units if any(r["task"] == t and r["split"] == IN_SAMPLE for r in records)]
        paths = figure_paths(path, [f"{t}_{kind}" for t in ran for kind in ("paths", "angle")])
        shown: list[tuple[str, Path]] = []
        for t in ran:
            recs = task_records(records, t, learners)
            demos = robottasks(t)
            assert demos.q is not None and demos.goal_q is not None
            figure_paths_3d(recs, demos, t, arrays, paths[f"{t}_paths"])
            figure_angles(recs, demos, angles_deg(demos.q, demos.goal_q), t, arrays, paths[f"{t}_angle"],
                          self.protocol.radius_deg)
            shown += [(f"{t} positions", paths[f"{t}_paths"]), (f"{t} angle to the goal", paths[f"{t}_angle"])]
        return {"": shown}


SUITE = RobotTasksSuite
