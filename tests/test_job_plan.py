"""The arm job in two parts (``sim.run.plan``, ``sim.run.pipeline``): a plan, resolved and checked before
any run, and a short ``run_job`` that executes it; the job reads its recording with the clean-up it asks
for and says what the clean-up removed, even when quiet."""

from __future__ import annotations

import ast
import inspect
import textwrap
from pathlib import Path

import pytest
from recordings import kinesthetic, write_positions

from lfd.demos.recording import loud_note
from sim.run import pipeline
from sim.run.job import ArmJob
from sim.run.plan import plan_job


def _job(tmp_path: Path, demos: str, **options: object) -> ArmJob:
    settings: dict[str, object] = dict(robot="planar", learners=("tracking",), demos=demos, scenarios=("none",),
                                       videos=False, plots=False, out=str(tmp_path / "out"), quiet=True)
    settings.update(options)
    return ArmJob(**settings)  # type: ignore[arg-type]


@pytest.mark.usefixtures("one_thread")
def test_the_job_cleans_its_recording_as_asked_and_says_what_it_removed_when_quiet(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = kinesthetic(rest_start=1.5, rest_end=2.0)                  # 651 samples: 3 s of motion, 3.5 s still
    spec = write_positions("csv", tmp_path / "rec", [rec.t], [rec.x[:, :2]])
    cleaned = plan_job(_job(tmp_path, spec))
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"note: {spec}: demo 0: trimmed 1.4 s standing still at the start "
                                               "and 1.9 s at the end"), err
    assert loud_note(err[0].removeprefix("note: ")) and err[0].endswith("% of its duration removed")
    assert 300 < cleaned.demos.t.shape[1] < 340                   # the motion's 301 samples and a margin
    raw = plan_job(_job(tmp_path, spec, clean=False))
    assert raw.demos.t.shape == (1, len(rec.t)) and capsys.readouterr().err == ""
    still = plan_job(_job(tmp_path, spec, clean=frozenset({"gaps", "noise", "pauses"})))
    assert still.demos.t.shape == (1, len(rec.t))


@pytest.mark.usefixtures("one_thread")
def test_the_plan_holds_every_run_in_order_before_any_runs(tmp_path: Path) -> None:
    """Each main learner under each scenario, then the grid's seeded pushes; the fields of every learner
    they name, trained before any run."""
    job = _job(tmp_path, "spiral", learners=("tracking",), scenarios=("none", "push"), grid=2, seed=5)
    plan = plan_job(job)
    assert [(r.learner, r.scenario, r.seed, r.group) for r in plan.runs] == [
        ("tracking", "none", 5, "main"), ("tracking", "push", 5, "main"),
        ("tracking", "push", 5, "grid"), ("tracking", "push", 6, "grid")]
    assert set(plan.fields) == {"tracking"}
    assert [type(p).__name__ for p in plan.runs[1].perturbations] == ["Push"] and plan.runs[0].perturbations == ()
    assert plan.runs[-1].perturbations != plan.runs[-2].perturbations          # seeded directions


def test_run_job_reads_in_one_screen() -> None:
    """The job's execution is short: planning lives in ``sim.run.plan``."""
    source = textwrap.dedent(inspect.getsource(pipeline.run_job))
    func = ast.parse(source).body[0]
    assert isinstance(func, ast.FunctionDef) and func.end_lineno is not None and func.end_lineno <= 60
