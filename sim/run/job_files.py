"""The files an arm job writes (``sim.run.pipeline``): planned and checked before any work, written
staged, and moved into place together (``sim.run.outputs.OutputSet``).

Per run ``<learner>_<scenario>``: the video (``.mp4``, unless videos are off), the time series
(``.npz``, ``sim.run.timeseries``) and its figure (``.png``, ``sim.media.plots.run_figure``). Per job:
``paths.png`` (the tool paths over the demos), ``loss_<learner>.png`` (the training loss, for a
learner with a loss curve), the side-by-side and grid videos when asked for, ``metrics.json``,
listing every file, and last the results page ``index.html`` (``sim.media.job_page``) in the output
folder, made from metrics.json's content.
"""

from __future__ import annotations

import datetime as _dt
import io
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lfd.errors import ConfigError
from lfd.field import Field
from lfd.io import atomic_write, same_file, write_json
from lfd.pages import versions, write_page
from sim.media.camera import CameraSpec
from sim.media.job_page import DISTRIBUTIONS, job_page
from sim.run import timeseries
from sim.run.experiment import Experiment, RunResult
from sim.run.job import ArmJob
from sim.run.outputs import OutputSet, fresh_dir

__all__ = ["JobFiles", "run_entry"]


@dataclass
class Plan:
    """Every file of one job, by run (learner, scenario) or by name."""

    videos: dict[tuple[str, str], Path]
    series: dict[tuple[str, str], Path]
    plots: dict[tuple[str, str], Path]
    extra_plots: dict[str, Path]
    side_by_side: Path | None
    grid: Path | None

    def every(self) -> list[Path]:
        """All planned paths."""
        return [*self.videos.values(), *self.series.values(), *self.plots.values(), *self.extra_plots.values(),
                *(p for p in (self.side_by_side, self.grid) if p is not None)]


def run_entry(r: RunResult) -> dict[str, Any]:
    """A run's entry in metrics.json: learner, scenario, its perturbations (each ``describe()``,
    taken from ``RunResult.perturbations``) and its metrics."""
    return {"learner": r.learner, "scenario": r.scenario,
            "perturbations": [p.describe() for p in r.perturbations], "metrics": r.metrics}


def _png(path: Path, fig: Any) -> None:
    """Save a matplotlib Figure as PNG atomically."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    atomic_write(path, lambda f: f.write(buf.getvalue()))


class JobFiles:
    """The planned files of ``job`` for the runs of ``learners`` (checked on construction)."""

    def __init__(self, job: ArmJob, learners: list[str]) -> None:
        self.job = job
        self.out = Path(job.out) if job.out else fresh_dir(
            Path("out") / f"demo_arm_{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}")
        self.json_path = Path(job.json) if job.json else self.out / "metrics.json"
        self.outputs = OutputSet(self.out, job.overwrite, {"model file": job.model, "demo file": job.demo_spec})
        self.outputs.plan([self.json_path], "--json")
        self.plan = self._plan(learners)
        for path in self.plan.every():
            if same_file(path, self.json_path):
                raise ConfigError(f"{path}: an output and --json would be the same file")
        self.outputs.plan(self.plan.every())
        self.page_path = self.out / "index.html"
        self.outputs.plan([self.page_path], "the results page")

    @property
    def n_videos(self) -> int:
        """How many videos the job writes."""
        return len(self.plan.videos) + (self.plan.side_by_side is not None) + (self.plan.grid is not None)

    def _plan(self, learners: list[str]) -> Plan:
        job, out = self.job, self.out
        single = len(learners) * len(job.scenarios) == 1
        beside = self.json_path.parent
        plan = Plan({}, {}, {}, {}, None, None)
        for learner in learners:
            for name in job.scenarios:
                if job.videos:
                    plan.videos[learner, name] = self._video_path(learner, name, single)
                plan.series[learner, name] = beside / f"{learner}_{name}.npz"
                if job.plots:
                    plan.plots[learner, name] = beside / f"{learner}_{name}.png"
        if job.plots:
            plan.extra_plots["paths"] = beside / "paths.png"
            for learner in learners:
                plan.extra_plots[f"loss_{learner}"] = beside / f"loss_{learner}.png"
        if job.side_by_side and job.videos:
            plan.side_by_side = out / f"side_by_side_{job.side_by_side}.mp4"
        if job.grid and job.videos:
            plan.grid = out / f"grid_push_{learners[0]}.mp4"
        return plan

    def _video_path(self, learner: str, name: str, single: bool) -> Path:
        if self.job.video is None:
            return self.out / f"{learner}_{name}.mp4"
        v = Path(self.job.video)
        return v if single else v.with_name(f"{v.stem}_{learner}_{name}{v.suffix or '.mp4'}")

    def write(self, exp: Experiment, results: list[RunResult], side: list[RunResult], grid: list[RunResult],
              fields: dict[str, Field], models: dict[str, dict[str, Any]], t_sim: float, progress: bool,
              settings: dict[str, Any]) -> dict[str, Any]:
        """Write every planned file (staged), then metrics.json, then move them all into place;
        on any failure or interrupt nothing of this job stays. Returns the metrics.json content."""
        try:
            report = self._write(exp, results, side, grid, fields, models, t_sim, progress, settings)
            self.outputs.commit(last=self.json_path)
        except BaseException:
            self.outputs.discard()
            raise
        return report

    def _say(self, text: str) -> None:
        if not self.job.quiet:
            print(text, file=sys.stderr)

    def _write(self, exp: Experiment, results: list[RunResult], side: list[RunResult], grid: list[RunResult],
               fields: dict[str, Field], models: dict[str, dict[str, Any]], t_sim: float, progress: bool,
               settings: dict[str, Any]) -> dict[str, Any]:
        from sim.media.plots import run_figure  # matplotlib: only when a job writes its figures

        job, plan, staged = self.job, self.plan, self.outputs.staged
        camera = job.camera or CameraSpec()
        size = job.size or (640, 480)
        runs: list[dict[str, Any]] = []
        t_video = t_files = 0.0
        for r in results:
            key = (r.learner, r.scenario)
            entry = run_entry(r)
            t0 = time.perf_counter()
            ts = timeseries.arrays(r, exp.placement, exp.robot)
            timeseries.save(staged(plan.series[key]), ts)
            entry["timeseries"] = str(plan.series[key])
            if key in plan.plots:
                _png(staged(plan.plots[key]), run_figure(ts, r.trace.hold_window_s))
                entry["plot"] = str(plan.plots[key])
            t_files += time.perf_counter() - t0
            if key in plan.videos:
                path = plan.videos[key]
                self._say(f"rendering {path}")
                entry["video"] = str(path)
                t0 = time.perf_counter()
                entry["video_frames"] = exp.render(r, staged(path), size[0], size[1], job.fps, progress, camera)
                t_video += time.perf_counter() - t0
            runs.append(entry)
        extra: dict[str, Any] = {}
        if side and plan.side_by_side is not None:
            self._say(f"rendering {plan.side_by_side}")
            w, h = job.size or (1280, 480)
            t0 = time.perf_counter()
            frames = exp.render(side, staged(plan.side_by_side), w, h, job.fps, progress, camera,
                                titles=[f"{r.learner} / {r.scenario}" for r in side])
            extra["side_by_side"] = {"video": str(plan.side_by_side), "video_frames": frames,
                                     "render_s": time.perf_counter() - t0, "runs": [run_entry(r) for r in side]}
            t_video += extra["side_by_side"]["render_s"]
        if grid and plan.grid is not None:
            self._say(f"rendering {plan.grid}")
            w, h = job.size or (960, 720)
            t0 = time.perf_counter()
            seeds = [job.seed + i for i in range(len(grid))]
            frames = exp.render(grid, staged(plan.grid), w, h, job.fps, progress, camera,
                                titles=[f"{r.learner} / push, seed {s}" for r, s in zip(grid, seeds)])
            extra["grid"] = {"video": str(plan.grid), "video_frames": frames, "seeds": seeds,
                             "runs": [{"seed": s, **run_entry(r)} for r, s in zip(grid, seeds)]}
            t_video += time.perf_counter() - t0
        t0 = time.perf_counter()
        if "paths" in plan.extra_plots:
            self._figures(exp, results, fields)
        t_files += time.perf_counter() - t0
        report = {
            "created": _dt.datetime.now().isoformat(timespec="seconds"),
            "command": list(job.command),
            "settings": {**exp.describe(), **settings, "video": {
                "size": list(size), "fps": job.fps, "camera": job.camera.name if job.camera else "auto"}},
            "models": models,
            "runs": runs,
            **extra,
            "timing_s": {"simulation": t_sim, "video": t_video, "series_and_plots": t_files},
        }
        figures = {name: str(path) for name, path in plan.extra_plots.items() if staged(path).exists()}
        report.update(figures=figures, versions=versions(DISTRIBUTIONS), page=str(self.page_path))
        write_json(staged(self.json_path), report)
        write_page(staged(self.page_path), job_page(report, self.json_path, self._size),
                   where=self.page_path)
        return report

    def _size(self, path: Path) -> int | None:
        """The size of the staged file of ``path`` in bytes (None if it was not written)."""
        staged = self.outputs.staged(path)
        return staged.stat().st_size if staged.exists() else None

    def _figures(self, exp: Experiment, results: list[RunResult], fields: dict[str, Field]) -> None:
        """paths.png and the loss_<learner>.png of each learner that has a loss curve (none for one
        without: metrics.json's ``figures`` lists what was written)."""
        from sim.media.plots import loss_figure, paths_figure

        plan, staged = self.plan, self.outputs.staged
        pd = exp.placement.position_dim   # a pose task's figure shows its positions
        goal = np.asarray(next(iter(fields.values())).goal)[:pd]
        label_runs = [(f"{r.learner} / {r.scenario}", exp.task_points(r.trace)[:, :pd]) for r in results]
        _png(staged(plan.extra_plots["paths"]),
             paths_figure(exp.task_demos.x[..., :pd], label_runs, goal, f"tool paths over the demos {exp.demos.name}"))
        for learner in {r.learner for r in results}:
            path = plan.extra_plots.get(f"loss_{learner}")
            fig = None if path is None else loss_figure(fields[learner].history, fields[learner].config)
            if path is not None and fig is not None:
                _png(staged(path), fig)
