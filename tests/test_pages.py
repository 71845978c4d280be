"""Results pages (``lfd.pages``; the arm job's ``sim.media.job_page``, the sweep's
``sim.studies.sweep_page``, ``lfd bench``'s ``lfd.bench.report_page``), opened in headless Chromium
(tests/browser.py): no console error, no request beyond the page's folder, every video plays, every
image loads, every number in the tables equals its data file's and is shown rounded right, the best
of each group marked, every failure said.

Small real runs: the planar arm with a 1.5 s demo and tiny trainings, videos at 160x120; a sweep of
6 runs; ``lfd bench robottasks`` on one task with two cheap learners. One browser for the module.
Without Chromium (Debian's ``chromium`` package, which .ci/run installs) the browser tests skip, and
fail under CI (``$CI`` true).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import pytest
from browser import Browser, find_chromium, unavailable

import sim
from lfd.bench.lasa import LasaSuite
from lfd.bench.protocol import LasaProtocol
from lfd.bench.report_page import bench_failures
from lfd.cli import main as lfd_main
from lfd.demos import save_file, spiral
from lfd.pages import Cell, DataFile, Media, MediaGroup, Page, Table, mark_best, number, pointer, render, text
from sim.media.job_page import run_problems
from sim.run.job import ArmJob, PushSpec
from sim.studies import sweep
from sim.studies.sweep_page import failure_sentence

pytestmark = pytest.mark.usefixtures("one_thread")

HEADLINE = ("final_goal_error_m", "tracking_rmse_m", "imitation_dtw_m", "recovery_time_s")


# ---------------------------------------------------------------- checking a page

def resolve(data: Any, where: str) -> Any:
    """The value at the JSON pointer ``where`` (RFC 6901) in ``data``."""
    for part in where.split("/")[1:]:
        key = part.replace("~1", "/").replace("~0", "~")
        data = data[int(key)] if isinstance(data, list) else data[key]
    return data


def check_numbers(cells: list[dict[str, Any]], data: dict[str, Any]) -> None:
    """Each sourced cell: its number is the data file's, and its text that number rounded as shown."""
    assert cells
    for c in cells:
        v = resolve(data, c["source"])
        if c["value"] == "":      # no number: missing, or non-finite (null in strict JSON)
            assert v is None or not math.isfinite(v), c
            continue
        assert float(c["value"]) == v, c
        decimals = len(c["text"].split(".")[1]) if "." in c["text"] else 0
        assert abs(float(c["text"]) - v * float(c["scale"])) <= 0.5 * 10.0 ** -decimals + 1e-12, c


def check_page(found: dict[str, Any], page: Path, videos: int, images: int) -> None:
    """What every page must be: no error, nothing fetched from outside its folder, no script, every
    video playing, every image loaded, every link to an existing file."""
    assert found["errors"] == [], found["errors"]
    assert found["requests"] and all(u.startswith(("file://", "data:")) for u in found["requests"]), found["requests"]
    assert found["scripts"] == 0
    assert len(found["videos"]) == videos and len(found["images"]) == images
    for v in found["videos"]:
        assert v["played"] and v["readyState"] >= 2 and v["currentTime"] > 0 and v["mediaError"] is None, v
        assert v["width"] > 0 and v["height"] > 0, v
    for i in found["images"]:
        assert i["complete"] and i["width"] > 0 and i["height"] > 0, i
    for href in found["links"]:
        assert "://" not in href and (page.parent / unquote(href)).exists(), href


def static_check(html: str) -> None:
    """The page as text: no script, no style sheet or font fetched, every src and href relative."""
    assert "<script" not in html.lower() and "@import" not in html and "@font-face" not in html
    refs = re.findall(r'(?:src|href)="([^"]*)"', html)
    assert refs and all("://" not in r and not r.startswith("//") for r in refs), refs
    assert re.findall(r"url\(", html) == []


@pytest.fixture(scope="module")
def browser() -> Any:
    exe = find_chromium()
    if exe is None:
        unavailable("Chromium is not installed (.ci/run installs Debian's chromium package)")
    b = Browser(exe)
    yield b
    b.close()


# ---------------------------------------------------------------- the arm job

@pytest.fixture(scope="module")
def arm(model_cache: str, tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("arm")
    save_file(spiral(n_demos=2, n_samples=40, duration=1.5), d / "demos.npz")
    job = ArmJob(robot="planar", learners=("node", "contraction"), demos=str(d / "demos.npz"),
                 scenarios=("none", "push"), out=str(d / "run dir"), size=(160, 120), fps=10.0, iters=5, quiet=True,
                 push=PushSpec(start_s=0.5, duration_s=0.2), side_by_side="push", grid=2,
                 command=("demo_arm.py", "--robot", "planar", "--out", str(d / "run dir")))
    sim.run_job(job)
    return d / "run dir"


def test_arm_page_plays_every_video_loads_every_image_and_shows_metrics_json(browser: Browser, arm: Path) -> None:
    report = json.loads((arm / "metrics.json").read_text())
    page = arm / "index.html"
    assert report["page"] == str(page)
    found = browser.visit(page)
    # 4 runs, the side-by-side and the grid video; 4 run figures, the paths and 2 losses
    check_page(found, page, videos=6, images=7)
    assert {v["src"] for v in found["videos"]} == {Path(p).name for p in [
        *(r["video"] for r in report["runs"]), report["side_by_side"]["video"], report["grid"]["video"]]}
    runs = {Path(r["video"]).name for r in report["runs"]}
    assert {(v["width"], v["height"]) for v in found["videos"] if v["src"] in runs} == {(160, 120)}
    check_numbers(found["cells"], report)
    sources = {c["source"] for c in found["cells"]}
    for i, r in enumerate(report["runs"]):          # every run's headline metrics are in the table
        assert {pointer("runs", i, "metrics", k) for k in HEADLINE if k in r["metrics"]} <= sources
    # every file of metrics.json is linked from the page, and it exists
    files = [report["runs"][0]["timeseries"], *(p for r in report["runs"] for p in (r["video"], r["plot"])),
             *report["figures"].values(), report["side_by_side"]["video"], report["grid"]["video"]]
    linked = {unquote(h) for h in found["links"]}
    assert {Path(p).name for p in files} | {"metrics.json"} <= linked
    assert all(Path(p).exists() for p in files)
    static_check(page.read_text())


def test_arm_page_marks_the_best_of_each_scenario(browser: Browser, arm: Path) -> None:
    report = json.loads((arm / "metrics.json").read_text())
    cells = browser.visit(arm / "index.html")["cells"]
    main = [c for c in cells if c["source"].startswith("/runs/")]
    for scenario in ("none", "push"):
        for key in HEADLINE:
            mine = [c for c in main if c["source"].endswith("/" + key)
                    and report["runs"][int(c["source"].split("/")[2])]["scenario"] == scenario]
            values = [float(c["value"]) for c in mine if c["value"]]
            if len(values) < 2:
                assert not any(c["best"] for c in mine)
                continue
            assert [c["best"] for c in mine] == [float(c["value"]) == min(values) if c["value"] else False
                                                 for c in mine], (scenario, key, mine)


def test_arm_page_is_written_without_videos_too(model_cache: str, tmp_path: Path) -> None:
    save_file(spiral(n_demos=2, n_samples=40, duration=1.5), tmp_path / "demos.npz")
    out = tmp_path / "run"
    sim.run_job(ArmJob(robot="planar", learners=("contraction",), demos=str(tmp_path / "demos.npz"),
                       scenarios=("none",), out=str(out), videos=False, plots=False, iters=5, quiet=True,
                       json=str(tmp_path / "elsewhere" / "m.json")))
    html = (out / "index.html").read_text()
    static_check(html)
    assert "<video" not in html and 'href="../elsewhere/m.json"' in html and 'id="videos"' not in html
    assert json.loads((tmp_path / "elsewhere" / "m.json").read_text())["page"] == str(out / "index.html")


# ---------------------------------------------------------------- the sweep

@pytest.fixture(scope="module")
def sweep_out(model_cache: str, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sweep")
    # 2 learners x (1 direction x 2 forces + 1 offset); a 400 N push throws the planar arm off its goal
    argv = ["--out", str(out), "--workers", "1", "--robots", "planar", "--directions", "1", "--forces", "20,400",
            "--offsets", "0.05", "--kinds", "push,offset", "--option", "node.iterations=30",
            "--option", "node.hidden=[16,16]", "--option", "contraction.iterations=10",
            "--option", "contraction.layers=1", "--option", "contraction.hidden=8"]
    assert sweep.main(argv) == 0
    return out


def test_sweep_page_shows_summary_json_and_says_each_failure(browser: Browser, sweep_out: Path) -> None:
    summary = json.loads((sweep_out / "summary.json").read_text())
    records = [json.loads(p.read_text()) for p in sorted((sweep_out / "runs").glob("*.json"))]
    page = sweep_out / "index.html"
    found = browser.visit(page)
    check_page(found, page, videos=0, images=2)                         # heatmap and basin
    check_numbers(found["cells"], summary)
    assert {c["source"] for c in found["cells"]} >= {pointer("summary", k, "success_rate") for k in summary["summary"]}
    failed = [r for r in records if not r["success"]]
    assert failed and len(found["failures"]) == len(failed)
    for r in failed:
        assert failure_sentence(r) in found["failures"]
    assert all("mm from its goal" in f or "joint limits" in f or "diverged" in f for f in found["failures"])
    linked = set(found["links"])
    assert {"summary.json", "heatmap.png", "basin.png"} | {f"runs/{r['name']}.json" for r in records} <= linked
    assert summary["command"][:3] == ["sweep_arm", "--out", str(sweep_out)] and "python" in summary["versions"]
    static_check(page.read_text())


# ---------------------------------------------------------------- lfd bench

@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bench")
    argv = ["bench", "robottasks", "--learner", "tracking,dmp", "--quick", "--tasks", "scoop", "--perturbed-starts",
            "1", "--split", "in-sample", "--workers", "1", "--json", str(out / "r.json"),
            "--report", str(out / "rt.md")]
    assert lfd_main(argv) == 0
    return out


def test_bench_page_beside_the_report_shows_the_results_json(browser: Browser, bench: Path) -> None:
    results = json.loads((bench / "r.json").read_text())
    page = bench / "rt.html"
    found = browser.visit(page)
    figures = sorted(p.name for p in (bench / "figures").glob("rt_*.png"))
    check_page(found, page, videos=0, images=len(figures))
    assert figures and {f"figures/{f}" for f in figures} | {"rt.md", "r.json"} <= set(found["links"])
    check_numbers(found["cells"], results)
    expected = {pointer("summary", lr, "in-sample", "metrics", m, "mean") for lr in ("tracking", "dmp")
                for m in ("dtw_mm", "dtw_angle_deg", "final_mm")}
    assert expected <= {c["source"] for c in found["cells"]}
    for m in ("dtw_mm", "dtw_angle_deg", "final_mm"):      # the lower mean of the two is the one marked
        pair = [c for c in found["cells"] if c["source"].endswith(f"/{m}/mean")]
        low = min(float(c["value"]) for c in pair)
        assert [c["best"] for c in pair] == [float(c["value"]) == low for c in pair]
    static_check(page.read_text())


# ---------------------------------------------------------------- the parts, without a browser

def test_mark_best_per_group_and_per_row_with_ties_and_directions() -> None:
    lo = lambda v: number(v, ".1f", better="lower")
    hi = lambda v: number(v, ".1f", better="higher")
    t = mark_best(Table("t", ("name", "err", "rate", "alone"), (
        (text("a"), lo(1.0), hi(0.5), lo(3.0)), (text("b"), lo(1.0), hi(0.9), text("—")),
        (text("c"), lo(2.0), hi(0.1), number(None, ".1f", better="lower")),
        (text("d"), lo(5.0), hi(0.2), lo(1.0))), ("g1", "g1", "g1", "g2")))
    best = [[c.best for c in r[1:]] for r in t.rows]
    assert best == [[True, False, False], [True, True, False], [False, False, False], [False, False, False]]
    rows = mark_best(Table("t", ("u", "x", "y"), ((text("u1"), lo(2.0), lo(1.0)), (text("u2"), lo(1.0), lo(1.0)))),
                     along="rows")
    assert [[c.best for c in r[1:]] for r in rows.rows] == [[False, True], [True, True]]


def test_numbers_cells_and_pointers() -> None:
    assert number(0.0123456, ".2f", scale=1e3).text == "12.35" and number(0.0123456, ".2f").value == 0.0123456
    assert number(math.inf, ".2f").text == "inf" and number(math.inf, ".2f").value is None
    assert number(None, ".2f", missing="never").text == "never"
    assert pointer("summary", "panda/node/push", "x~y", 0) == "/summary/panda~1node~1push/x~0y/0"


def test_failures_are_sentences() -> None:
    base = {"final_goal_error_m": 0.0123, "joint_limit_violations": 0}
    assert run_problems("node / push", {"final_goal_error_m": 0.001, "joint_limit_violations": 0,
                                        "recovery_time_s": 0.5}, 3.0) == []
    said = run_problems("node / push", {**base, "blocked": True, "final_clearance_m": 0.012}, 3.0)
    assert said == ["node / push was blocked 12.3 mm from its goal: a collision damper held the arm back, "
                    "12 mm clear of what is in its way."]
    said = run_problems("c / none", {**base, "stopped_short": True, "blocked": False}, 6.5)
    assert said == ["c / none stopped short, 12.3 mm from its goal with nothing holding it back: the field did "
                    "not bring it there in the run's 6.5 s."]
    said = run_problems("n / push", {**base, "joint_limit_violations": 7, "recovery_time_s": None,
                                     "max_deviation_m": 0.05, "obstacle_steps_in_contact": 3}, 3.0)
    assert said == ["n / push ended 12.3 mm from its goal, more than 5 mm.",
                    "n / push left its joint limits in 7 control steps.",
                    "n / push never came back within 5 mm of its unpushed path after the push (it was pushed up "
                    "to 50.0 mm away).", "n / push touched an obstacle in 3 control steps."]
    rec = {"robot": "panda", "learner": "node", "kind": "push", "magnitude": 80.0, "angle_rad": math.pi / 2,
           "seed": 1, "goal_tol_m": 0.005}
    assert failure_sentence({**rec, "error": "simulation diverged at t = 1.234 s (qacc)"}) == \
        "panda / node / push 80 N at 90°, seed 1: simulation diverged at t = 1.234 s (qacc)."
    assert failure_sentence({**rec, "error": None, "metrics": {**base, "recovery_time_s": None}}) == (
        "panda / node / push 80 N at 90°, seed 1: ended 12.3 mm from its goal, beyond the tolerance of 5 mm; "
        "never came back within 5 mm of its unpushed path.")


def test_bench_failures_are_sentences() -> None:
    suite = LasaSuite(LasaProtocol())
    ok, diverged = {"metrics": {"dtw": 1.0, "rmse": 2.0}}, {"metrics": {"dtw": math.inf, "rmse": 2.0}}
    rows = {"node": {"in-sample": {"Angle": ok, "Sshape": diverged, "Snake": diverged}, "held-out": {}}}
    run = {"failed": [{"cell": "node__Worm__seed0", "attempts": 3, "reason": "worker died"},
                      {"cell": "dmp__Angle__seed0", "refused": True, "reason": "3-D demos"}]}
    assert bench_failures(suite, rows, run) == [
        "Cell node__Worm__seed0 was given up after 3 tries (worker died); it is not in the tables.",
        "Cell dmp__Angle__seed0 was refused by its learner (3-D demos); it is not in the tables.",
        "node diverged on 2 shape(s), in-sample: Sshape, Snake (a reproduction left every bound; its metrics "
        "are infinite)."]
    assert bench_failures(suite, {"node": {"in-sample": {"Angle": ok}}}, {"failed": []}) == []


def test_render_escapes_text_and_links_relative_to_the_page(tmp_path: Path) -> None:
    page = Page(title="<script>alert(1)</script>", subtitle="s & t", command="run 'x'", facts=(("seed", "0"),),
                verdict=("v",), failures=("a <b> failed",),
                tables=(Table("t", ("n", "x"), ((text("r"), Cell("1.00", 1.0, 1.0, "/x")),)),),
                videos=(MediaGroup("g", (Media(tmp_path / "sub dir" / "a b.mp4", "cap"),)),),
                files=(DataFile(tmp_path / "m.json", "metrics", 2048),), data_file=tmp_path / "m.json")
    html = render(page, tmp_path / "index.html")
    static_check(html)
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html and "a &lt;b&gt; failed" in html
    assert 'src="sub%20dir/a%20b.mp4"' in html and 'href="m.json"' in html and ">2 kB<" in html
    assert 'data-source="/x" data-value="1.0" data-scale="1.0">1.00</td>' in html
    assert "1 problem</strong>" in html and 'class="passed"' not in html


def test_the_browser_check_catches_a_broken_page(browser: Browser, tmp_path: Path) -> None:
    """The checks are not vacuous: a console error, a missing image, a video that is no video and a
    request to the network are all seen."""
    (tmp_path / "bad.mp4").write_bytes(b"not a video")
    (tmp_path / "p.html").write_text('<!doctype html><html><head><link rel="icon" href="data:,"></head><body>'
                                     '<img src="missing.png"><video src="bad.mp4" muted></video>'
                                     '<img src="http://127.0.0.1:9/x.png"><script>console.error("boom")</script>'
                                     '</body></html>')
    found = browser.visit(tmp_path / "p.html")
    assert any("boom" in e for e in found["errors"]) and len(found["errors"]) >= 3
    assert [i["width"] for i in found["images"]] == [0, 0]
    assert not found["videos"][0]["played"] and found["videos"][0]["mediaError"] is not None
    assert "http://127.0.0.1:9/x.png" in found["requests"]


@pytest.mark.parametrize("ci", ["true", ""])
def test_a_browser_test_without_chromium_fails_under_ci_and_skips_elsewhere(ci: str,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CI", ci)
    outcome = pytest.fail.Exception if ci else pytest.skip.Exception
    with pytest.raises(outcome, match="Chromium is not installed"):
        unavailable("Chromium is not installed")
