"""Videos, overlays, plots and saved time series (sim.media.render, sim.media.overlay, sim.media.camera,
sim.media.plots, sim.run.timeseries, scripts/demo_arm.py options).

Videos are read back with imageio_ffmpeg. Colour checks allow +-45 per channel: H.264 (4:2:0
chroma) and software rendering shift pixel values slightly from machine to machine.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from known_fields import sink_field

import lfd
import sim  # noqa: F401  (sets MUJOCO_GL first)
from robots import load_robot
from sim.media import overlay
from sim.media.camera import CameraSpec
from sim.media.render import panel_grid

ROOT = Path(__file__).resolve().parents[1]
TOL = 45


@pytest.fixture(scope="module")
def demos() -> lfd.DemoSet:
    return lfd.spiral(n_demos=2, n_samples=60, duration=1.0)


@pytest.fixture(scope="module")
def exp(demos):
    return sim.Experiment(load_robot("planar", actuation="torque"), demos, settle_s=0.3)


@pytest.fixture(scope="module")
def pushed(exp, demos):
    return exp.run(sink_field(demos), "push", perturbations=(sim.Push(start_s=0.3, duration_s=0.2, seed=1),))


def read_video(path: Path) -> tuple[dict, np.ndarray]:
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    frames = np.stack([np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader])
    return meta, frames


def near(img: np.ndarray, rgb: tuple[int, int, int], tol: int = TOL) -> np.ndarray:
    """Mask (h, w) of pixels within tol of rgb in every channel."""
    return np.all(np.abs(img.astype(np.int16) - np.array(rgb, dtype=np.int16)) <= tol, axis=-1)


# ---------------------------------------------------------------- one video
def test_video_size_frames_rate_motion_legend_and_path_width(exp, pushed, tmp_path):
    path = tmp_path / "run.mp4"
    n = exp.render(pushed, path, 320, 240, fps=10.0)
    meta, frames = read_video(path)
    expected = int(np.floor(pushed.trace.t[-1] * 10.0 + 1e-9)) + 1
    assert n == expected == len(frames)
    assert tuple(meta["size"]) == (320, 240) and meta["fps"] == pytest.approx(10.0)
    first, last = frames[0].astype(np.int16), frames[-1].astype(np.int16)
    # the robot's trace grows over the path: orange pixels appear there, and the path region changes
    trace_last, trace_first = near(frames[-1], overlay.TRACE_RGB), near(frames[0], overlay.TRACE_RGB)
    legend = np.zeros(trace_last.shape, bool)
    legend[:90, :150] = True                                      # the legend box, top left
    assert (trace_last & ~legend).sum() > 60 > (trace_first & ~legend).sum()
    ys, xs = np.nonzero(trace_last & ~legend)
    region = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    assert np.abs(last[region] - first[region]).mean() > 3   # a still frame: 0
    # every legend colour is drawn in the legend box
    for rgb in (overlay.DEMO_RGB, overlay.FIELD_RGB, overlay.TRACE_RGB, overlay.GOAL_RGB):
        assert near(frames[-1][:90, :150], rgb, 60).sum() >= 8, rgb
    # the demonstration lies inside the frame, clear of its edges, and spans at least 8% of its width: the
    # camera keeps the whole planar arm (three times the spiral's size) in view too
    demo = near(frames[-1], overlay.DEMO_RGB) & ~legend
    cols, rows = np.nonzero(demo.sum(0) >= 1)[0], np.nonzero(demo.sum(1) >= 1)[0]
    assert (cols.max() - cols.min()) / 320 >= 0.08 and cols.min() > 16 and cols.max() < 304
    assert rows.min() > 12 and rows.max() < 228


def test_push_arrow_shows_only_while_the_push_acts(exp, pushed, tmp_path):
    path = tmp_path / "run.mp4"
    exp.render(pushed, path, 320, 240, fps=10.0)
    _, frames = read_video(path)
    red = [near(f, overlay.PUSH_RGB, 40).sum() for f in frames]
    t = np.arange(len(frames)) / 10.0
    during = red[int(np.searchsorted(t, 0.35))]
    assert during > 30                               # arrow (plus the push mark) at t = 0.4 s
    assert max(red[:3]) < 5                          # nothing red before the push (t <= 0.2 s)
    assert red[-1] < during / 2                      # only the small mark where it began remains


def test_side_by_side_has_one_labelled_panel_per_run(exp, demos, tmp_path):
    """Its cost against single videos is measured by scripts/speed.py render, not asserted here."""
    push = (sim.Push(start_s=0.3, duration_s=0.2, seed=1),)
    runs = [exp.run(sink_field(demos, name, a), "push", perturbations=push)
            for name, a in (("node", 0.5), ("contraction", 1.5), ("tracking", 4.0))]
    n = exp.render(runs, tmp_path / "sbs.mp4", 480, 160, fps=10.0)
    meta, frames = read_video(tmp_path / "sbs.mp4")
    assert tuple(meta["size"]) == (480, 160) and len(frames) == n
    for k in range(3):                               # a legend in the top left of each 160 px panel
        panel = frames[-1][:, 160 * k:160 * (k + 1)]
        assert near(panel[:60, :80], overlay.DEMO_RGB).sum() >= 4, k
        assert near(panel[:60, :80], overlay.FIELD_RGB).sum() >= 4, k
    # the panels differ (three different fields, same push)
    p = [frames[-1][:, 160 * k:160 * (k + 1)].astype(np.int16) for k in range(3)]
    assert np.abs(p[0] - p[2]).mean() > 0.5


def test_panel_grid_layouts():
    assert [panel_grid(n) for n in (1, 2, 3, 4, 5, 9)] == [(1, 1), (2, 1), (3, 1), (2, 2), (3, 2), (3, 3)]
    a = np.full((4, 6, 3), 7, np.uint8)
    tiled = overlay.tile([a, a, a], 2)
    assert tiled.shape == (8, 12, 3) and tiled[4:, 6:].max() == 0 and tiled[:4].min() == 7


# ---------------------------------------------------------------- camera
def test_camera_spec_parsing_and_errors(exp):
    assert CameraSpec.parse("auto") == CameraSpec()
    assert CameraSpec.parse("120,-30,1.5").orbit == (120.0, -30.0, 1.5)
    CameraSpec.parse("workspace").check(exp.physics.model.ptr)
    for bad, msg in (("1,2", "three numbers"), ("0,-100,1", "elevation"), ("0,0,0", "distance"),
                     ("0,nan,1", "finite")):
        with pytest.raises(ValueError, match=msg):
            CameraSpec.parse(bad)
    with pytest.raises(ValueError, match="unknown camera 'nope'.*workspace"):
        CameraSpec.parse("nope").check(exp.physics.model.ptr)


def test_named_and_orbit_cameras_render(exp, pushed, tmp_path):
    for i, spec in enumerate((CameraSpec.parse("workspace"), CameraSpec.parse("90,-60,0.6"))):
        exp.render(pushed, tmp_path / f"c{i}.mp4", 160, 120, fps=5.0, camera=spec)
        _, frames = read_video(tmp_path / f"c{i}.mp4")
        assert frames.std() > 10


# ---------------------------------------------------------------- data and plots
def test_timeseries_and_plots(exp, pushed, tmp_path):
    from sim.media import plots
    from sim.run import timeseries

    ts = timeseries.arrays(pushed, exp.placement, exp.robot)
    timeseries.save(tmp_path / "run.npz", ts)
    z = np.load(tmp_path / "run.npz")
    k = len(pushed.trace.t)
    assert z["q"].shape == z["qdot"].shape == (k, exp.robot.n) and z["ee"].shape == (k, 3)
    assert z["command"].shape == (k, 2) and z["push_force"].shape == (k, 3)
    rmse = float(np.sqrt(np.mean(z["tracking_error"] ** 2)))
    assert rmse == pytest.approx(pushed.metrics["tracking_rmse_m"], rel=1e-9)
    after = z["t"] >= z["push_window"][0]
    assert z["deviation"][after].max() == pytest.approx(pushed.metrics["max_deviation_m"], rel=1e-9)
    on = np.linalg.norm(z["push_force"], axis=1) > 0
    assert z["t"][on].min() == pytest.approx(0.3, abs=0.003) and z["t"][on].max() < 0.5
    np.testing.assert_allclose(np.linalg.norm(z["push_force"][on], axis=1), 20.0)
    # the command is the field at the measured positions: it points back along the spiral
    v0 = sink_field(exp.demos).single_point_evaluator()(exp.placement.to_task(z["ee"][0]))
    np.testing.assert_allclose(z["command"][0], v0, rtol=1e-9)
    for fig, name in ((plots.run_figure(ts), "run.png"),
                      (plots.paths_figure(exp.demos.x, [("run", exp.placement.to_task(z["ee"]))], exp.demos.goal),
                       "paths.png")):
        fig.savefig(tmp_path / name)
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"


def test_loop_records_qdot_command_and_push_force(exp, demos):
    """The control loop records qdot, the field's command and the applied push force."""
    from sim.run import timeseries

    push = sim.Push(force_n=7.5, duration_s=0.1, start_s=0.25, direction=(1.0, 1.0, 0.0), seed=4)
    result = exp.run(sink_field(demos), "my-push", perturbations=(push,))
    ro = result.trace
    assert result.perturbations == (push,)                       # the very objects it ran with
    dt = float(ro.t[1] - ro.t[0])
    k0 = round(0.25 / dt)
    k1 = k0 + round(0.1 / dt)
    on = np.linalg.norm(ro.applied_force, axis=1) > 0
    assert np.flatnonzero(on).tolist() == list(range(k0, k1))    # exactly the push window's steps
    assert ro.push_window_s == pytest.approx((ro.t[k0], ro.t[k1]))
    np.testing.assert_allclose(np.linalg.norm(ro.applied_force[on], axis=1), 7.5, rtol=1e-12)
    np.testing.assert_allclose(ro.applied_force[on], np.tile([7.5 / np.sqrt(2), 7.5 / np.sqrt(2), 0.0], (k1 - k0, 1)),
                               atol=1e-12)
    # qdot is MuJoCo's joint velocity, read by the loop: it agrees with the differences of q
    dq = np.gradient(ro.q, ro.t, axis=0)
    assert np.abs(ro.qdot - dq)[5:-5].max() < 0.05 * np.abs(ro.qdot).max() + 1e-3
    # the recorded command is the field at the measured positions, as Experiment.command recomputes it
    np.testing.assert_allclose(ro.command, exp.command(sink_field(demos), ro), rtol=1e-9, atol=1e-12)
    ts = timeseries.arrays(result, exp.placement, exp.robot)
    assert ts["qdot"] is not None and np.array_equal(ts["qdot"], ro.qdot)
    assert np.array_equal(ts["push_force"], ro.applied_force) and np.array_equal(ts["command"], ro.command)
    assert json.loads(str(ts["perturbations"])) == json.loads(json.dumps([push.describe()]))
    assert np.allclose(exp.run(sink_field(demos), "none").trace.applied_force, 0.0)


def test_loss_plot_marks_the_curriculum_stages():
    from matplotlib.figure import Figure

    from lfd.plotting import curriculum_stages, draw_loss

    history = {"loss": list(np.linspace(1.0, 0.1, 100))}
    config = {"seg": 10, "seg_start": 2, "curriculum": 0.5, "iterations": 100}
    stages = curriculum_stages(history, config)
    assert [s for _, s in stages] == list(range(2, 11))
    assert stages[0][0] == 1 and 45 <= stages[-1][0] <= 51
    assert curriculum_stages(history, {"rate": 1.0}) == []
    ax = Figure().add_subplot()
    draw_loss(ax, history, config)
    assert sum(t.get_text().startswith("S=") for t in ax.texts) == 9
    assert "curriculum" in ax.get_legend().get_texts()[0].get_text()


# ---------------------------------------------------------------- the arm job (scripts/demo_arm.py)
@pytest.fixture
def demo_arm():
    """The arm job's command line, ``sim.run.cli`` (what scripts/demo_arm.py runs)."""
    from sim.run import cli

    return cli


def test_demo_arm_writes_series_plots_and_video_matching_metrics(demo_arm, tmp_path, monkeypatch):
    short = lfd.spiral(n_demos=2, n_samples=60, duration=1.0)
    model = tmp_path / "sink.pt"
    sink_field(short).save(model)
    monkeypatch.setattr(lfd, "load", lambda path: sink_field(short))
    monkeypatch.setattr(lfd, "load_demos", lambda spec, clean=True: short)
    out = tmp_path / "out"
    rc = demo_arm.main(["--robot", "planar", "--model", str(model), "--perturb", "push", "--push-start", "0.5",
                        "--push-force", "12.5", "--push-duration", "0.1",
                        "--out", str(out), "--quiet", "--size", "160x120", "--fps", "12"])
    assert rc == 0
    report = json.loads((out / "metrics.json").read_text())
    run = report["runs"][0]
    meta, frames = read_video(Path(run["video"]))
    assert tuple(meta["size"]) == (160, 120) and meta["fps"] == pytest.approx(12.0)
    assert len(frames) == run["video_frames"]
    z = np.load(run["timeseries"])
    assert Path(run["timeseries"]).parent == out
    m = run["metrics"]
    assert float(np.sqrt(np.mean(z["tracking_error"] ** 2))) == pytest.approx(m["tracking_rmse_m"], rel=1e-9)
    assert float(np.linalg.norm(z["ee"][-1] - z["goal"])) == pytest.approx(m["final_goal_error_m"], rel=1e-9)
    for name in ("node_push.png", "paths.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    # the custom push is what the run recorded and what both files say
    (described,) = run["perturbations"]
    assert (described["kind"], described["force_n"], described["start_s"], described["duration_s"]) == \
        ("push", 12.5, 0.5, 0.1)
    assert json.loads(str(z["perturbations"])) == run["perturbations"]
    on = np.linalg.norm(z["push_force"], axis=1) > 0
    assert z["t"][on].min() == pytest.approx(0.5, abs=1e-9) and len(z["t"][on]) == round(0.1 / (z["t"][1] - z["t"][0]))
    np.testing.assert_allclose(np.linalg.norm(z["push_force"][on], axis=1), 12.5)
    assert z["qdot"].shape == z["q"].shape and np.isfinite(z["qdot"]).all()


def test_demo_arm_writes_the_perturbations_of_the_result(exp, demos):
    """metrics.json takes a run's perturbations from its result, not from the scenario's name."""
    from sim.run.job_files import run_entry

    push = sim.Push(force_n=3.0, duration_s=0.05, start_s=0.4, seed=7)
    result = exp.run(sink_field(demos), "push", perturbations=(push,))
    entry = run_entry(result)
    assert entry["perturbations"] == [push.describe()]
    assert entry["perturbations"][0]["force_n"] == 3.0 and entry["perturbations"][0]["start_s"] == 0.4
    assert entry["perturbations"] != [p.describe() for p in sim.run.experiment.scenario("push")]
    assert entry["metrics"] is result.metrics


@pytest.mark.parametrize("argv, message", [
    (["--size", "641x480"], "must be even"),
    (["--size", "big"], "expected WIDTHxHEIGHT"),
    (["--size", "8x8"], "32..3840"),
    (["--fps", "0"], "--fps must be a number from 1 to 240"),
    (["--camera", "1,2"], "three numbers"),
    (["--grid", "1"], "--grid must be an integer from 2 to 9"),
    (["--side-by-side", "shove"], "unknown scenario 'shove'"),
    (["--robot", "planar", "--camera", "nope"], "unknown camera 'nope'"),
])
def test_demo_arm_bad_video_options_are_one_line_exit_2(demo_arm, argv, message, tmp_path, capsys):
    out = tmp_path / "out"
    assert demo_arm.main(argv + ["--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and "Traceback" not in err, err
    assert not out.exists()
