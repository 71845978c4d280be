"""Figures for every kind of field (``lfd.plotting``, ``lfd plot``, the arm job's loss figure): a pose
model's orientation panels, no loss panel without a loss curve, and the spurious attractors and closed
orbits of ``lfd.equilibria`` marked; checked through the drawn data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from equilibrium_fields import bistable_field, bistable_node, hopf_field
from known_fields import LinearSink
from matplotlib.axes import Axes
from matplotlib.figure import Figure

import lfd
from lfd.cli import main
from lfd.equilibria import find_equilibria, search_box
from lfd.field import VelocityField
from lfd.normalization import Normalization
from lfd.plotting import draw_paths_3d, field_figure, has_loss_curve
from lfd.pose import chart_demos

pytestmark = pytest.mark.usefixtures("one_thread")
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def poses() -> lfd.DemoSet:
    d = lfd.load_demos("robottasks:pouring")
    return lfd.DemoSet(d.t[:3, ::4], d.x[:3, ::4], name="pouring-small", q=d.q[:3, ::4])


def _loss_axes(fig: Figure) -> list[Axes]:
    return [ax for ax in fig.axes if ax.get_ylabel() == "loss"]


def test_a_pose_model_has_orientation_panels_and_no_loss_without_a_curve(poses: lfd.DemoSet, tmp_path) -> None:
    field = lfd.train("tracking", poses, seed=0)
    assert not has_loss_curve(field.history)                  # the tracking fit records one value
    demos = chart_demos(poses, field.chart)
    fig = field_figure(field, demos, n_perturbed=2)
    assert len(fig.axes) == 3 and not _loss_axes(fig)
    paths_ax, angle_ax, rot_ax = fig.axes
    assert paths_ax.name == "3d" and "(positions)" in paths_ax.get_title()
    n = poses.n_demos
    assert len(angle_ax.lines) == n + n + 2 and len(rot_ax.lines) == 3 * (n + n)
    # the first lines are the demos: the geodesic angle to the goal and the rotation vector, in degrees
    t0 = poses.t[0] - poses.t[0, 0]
    np.testing.assert_allclose(angle_ax.lines[0].get_xdata(), t0)
    np.testing.assert_allclose(angle_ax.lines[0].get_ydata(), np.degrees(field.chart.angle_to_goal(demos.x[0])))
    np.testing.assert_allclose(rot_ax.lines[0].get_ydata(), np.degrees(demos.x[0, :, 3] / field.chart.length))
    # the rollouts from the demo starts end at the goal orientation
    assert max(line.get_ydata()[-1] for line in angle_ax.lines[n:2 * n]) < 1.0
    fig.savefig(tmp_path / "pose.png", dpi=50)
    assert (tmp_path / "pose.png").read_bytes()[:8] == PNG


def test_a_pose_node_has_its_loss_panel_too(poses: lfd.DemoSet) -> None:
    field = lfd.train("node", poses, seed=0, iterations=5, hidden=(8,))
    fig = field_figure(field, chart_demos(poses, field.chart), n_perturbed=0)
    assert len(fig.axes) == 4 and fig.axes[-1] is _loss_axes(fig)[0] and fig.axes[-1].get_yscale() == "log"


def test_a_2d_tracking_field_has_no_loss_panel(spiral: lfd.DemoSet) -> None:
    field = lfd.train("tracking", spiral, seed=0)
    fig = field_figure(field, spiral, n_perturbed=0)
    assert not _loss_axes(fig) and [ax.get_xlabel() for ax in fig.axes] == ["x1", ""]   # the field and its colorbar


def test_the_spurious_attractor_is_marked_where_it_is(spiral: lfd.DemoSet) -> None:
    field = bistable_node(spiral)
    report = find_equilibria(field, *search_box(field), duration=5.0)
    (sink,) = report.spurious_attractors
    ax = field_figure(field, spiral, n_perturbed=0, equilibria=report).axes[0]
    marks = [line for line in ax.lines if line.get_marker() == "X"]
    assert len(marks) == 1 and marks[0].get_label() == "spurious attractor"
    np.testing.assert_allclose([marks[0].get_xdata()[0], marks[0].get_ydata()[0]], sink.location, atol=1e-9)
    assert "spurious attractor" in [t.get_text() for t in ax.get_legend().get_texts()]
    # the same field without the report: no mark
    bare = field_figure(field, spiral, n_perturbed=0).axes[0]
    assert not [line for line in bare.lines if line.get_marker() == "X"]


def test_a_closed_orbit_is_drawn(spiral: lfd.DemoSet) -> None:
    field = hopf_field(0.5)                                    # the attracting circle r = 1 in the spiral's box
    report = find_equilibria(field, *spiral.bounds(0.5), duration=5.0)
    assert len(report.orbits) == 1
    ax = field_figure(field, spiral, n_perturbed=0, equilibria=report).axes[0]
    (orbit,) = [line for line in ax.lines if line.get_label() == "closed orbit"]
    np.testing.assert_allclose(np.hypot(orbit.get_xdata(), orbit.get_ydata()), 1.0, atol=1e-3)


def test_the_attractor_is_marked_on_3d_axes() -> None:
    from matplotlib.figure import Figure

    field = bistable_field(3)
    report = find_equilibria(field, np.array([-3.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]), duration=5.0)
    t = np.linspace(0.0, 1.0, 20)
    x = np.stack([-2.5 + 2.5 * t, 0.5 - 0.5 * t, 0.5 - 0.5 * t], axis=1)
    demos = lfd.DemoSet(t[None], x[None], name="line")
    ax = Figure().add_subplot(projection="3d")
    draw_paths_3d(ax, field, demos, n_perturbed=0, equilibria=report)
    (mark,) = [line for line in ax.lines if line.get_marker() == "X"]
    np.testing.assert_allclose(np.ravel(mark.get_data_3d()), [-2.0, 0.0, 0.0], atol=1e-6)


def test_lfd_plot_marks_and_says_so(spiral: lfd.DemoSet, tmp_path, capsys) -> None:
    model = tmp_path / "bistable.pt"
    bistable_node(spiral).save(model)
    png = tmp_path / "fig.png"
    assert main(["plot", str(model), "--demos", "spiral", "--out", str(png), "--perturbed", "2", "--dpi", "50"]) == 0
    out, err = capsys.readouterr()
    assert out.strip() == f"wrote {png}" and png.read_bytes()[:8] == PNG
    assert "1 spurious attractor" in err and len(err.strip().splitlines()) == 1
    assert main(["plot", str(model), "--demos", "spiral", "--out", str(png), "--no-equilibria", "--dpi", "50"]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("loss, written", [([0.5], False), ([1.0, 0.5, 0.2], True)])
def test_the_arm_job_writes_a_loss_figure_only_for_a_loss_curve(loss: list[float], written: bool, tmp_path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    from sim.media.plots import loss_figure
    from sim.run import cli

    short = lfd.spiral(n_demos=2, n_samples=60, duration=1.0)
    field = VelocityField(LinearSink(2), Normalization.from_points(short.x, short.goal), "node", {}, {"loss": loss})
    assert (loss_figure(field.history, None) is not None) == written
    model = tmp_path / "sink.pt"
    field.save(model)
    monkeypatch.setattr(lfd, "load", lambda path: field)
    monkeypatch.setattr(lfd, "load_demos", lambda spec, clean=True: short)
    out = tmp_path / "out"
    assert cli.main(["--robot", "planar", "--model", str(model), "--perturb", "none", "--no-video",
                     "--out", str(out), "--quiet"]) == 0
    assert (out / "paths.png").read_bytes()[:8] == PNG
    assert (out / "loss_node.png").exists() == written
    report = json.loads((out / "metrics.json").read_text())
    if "figures" in report:                                    # metrics.json lists what was written
        listed = list(report["figures"].values()) if isinstance(report["figures"], dict) else report["figures"]
        assert all(Path(p).exists() for p in listed)
        assert any(str(p).endswith("loss_node.png") for p in listed) == written
