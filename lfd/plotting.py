"""Figures of a learned field with its demos: streamlines or 3-D paths, a pose field's orientations over
time, rollouts, the loss curve, and the field's spurious attractors and closed orbits (``lfd.equilibria``).

Figures are built on ``matplotlib.figure.Figure`` without pyplot, so nothing here touches the
global backend: ``fig.savefig("x.png")`` renders with Agg. Each function takes a field and
demos and draws into an Axes (or returns a Figure), so scripts can reuse any piece.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FormatStrFormatter

from lfd.demos import DemoSet
from lfd.equilibria import EquilibriumReport
from lfd.evaluation import reproduce
from lfd.field import StateSpace, VelocityField
from lfd.pose import PoseChart

if TYPE_CHECKING:
    from mpl_toolkits.mplot3d import Axes3D

DEMO_STYLE: dict[str, Any] = {"color": "0.15", "lw": 1.2, "alpha": 0.8}
ROLLOUT_STYLE: dict[str, Any] = {"color": "tab:red", "lw": 1.6}
PERTURBED_STYLE: dict[str, Any] = {"color": "tab:orange", "lw": 1.1, "ls": "--"}
ATTRACTOR_STYLE: dict[str, Any] = {"marker": "X", "color": "magenta", "mec": "black", "mew": 1.0, "ms": 13,
                                   "ls": "none", "zorder": 6}
ORBIT_STYLE: dict[str, Any] = {"color": "magenta", "lw": 2.2, "ls": "-.", "zorder": 5}


def perturbed_starts(demos: DemoSet, n: int, spread: float = 0.1, seed: int = 0) -> np.ndarray:
    """n starts near the demo starts: x0 = x_{i mod N}[0] + N(0, (spread E)^2 I), with E the largest
    side of the demos' bounding box; seeded. Returns shape (n, d)."""
    lo, hi = demos.bounds()
    rng = np.random.default_rng(seed)
    base = demos.x[np.arange(n) % demos.n_demos, 0]
    return base + rng.normal(0.0, spread * float(np.max(hi - lo)), size=base.shape)


def rollouts(field: VelocityField, demos: DemoSet, n_perturbed: int = 8, spread: float = 0.1,
             seed: int = 0) -> tuple[list[np.ndarray], np.ndarray]:
    """Rollouts from each demo's start over its time grid, list of N arrays of shape (T, d), and
    from ``perturbed_starts`` over 1.5 times the mean demo duration, shape (n_perturbed, T, d)."""
    from_demos = list(reproduce(field, demos))
    with np.errstate(all="ignore"):
        if n_perturbed == 0:
            return from_demos, np.empty((0, demos.n_samples, demos.dim))
        horizon = 1.5 * float(np.mean(demos.t[:, -1] - demos.t[:, 0]))
        t = np.linspace(0.0, horizon, demos.n_samples)
        return from_demos, field.rollout(perturbed_starts(demos, n_perturbed, spread, seed), t)


def draw_field_2d(ax: Axes, field: VelocityField, demos: DemoSet, n_perturbed: int = 8,
                  spread: float = 0.1, seed: int = 0, grid: int = 80,
                  equilibria: EquilibriumReport | None = None) -> None:
    """Streamlines of f over the demos' box grown by 50%, coloured by speed |f(x)|, with the demos,
    rollouts from the demo starts and from perturbed starts, the goal, and the spurious attractors
    and closed orbits of ``equilibria`` (``draw_equilibria``)."""
    lo, hi = demos.bounds(grow=0.5)
    gx, gy = np.linspace(lo[0], hi[0], grid), np.linspace(lo[1], hi[1], grid)
    X, Y = np.meshgrid(gx, gy)
    with np.errstate(all="ignore"):
        V = field(np.stack([X, Y], axis=-1))
    speed = np.linalg.norm(V, axis=-1)
    ok = np.isfinite(speed) & (speed > 0)
    V = np.where(np.isfinite(V), V, 0.0)
    if ok.any():
        norm = LogNorm(vmin=max(float(speed[ok].min()), float(speed[ok].max()) * 1e-3),
                       vmax=float(speed[ok].max()))
        stream = ax.streamplot(X, Y, V[..., 0], V[..., 1], color=np.where(ok, speed, np.nan),
                               cmap="Blues", norm=norm, density=1.4, linewidth=0.7, arrowsize=0.8)
        ax.figure.colorbar(stream.lines, ax=ax, label="speed |f(x)|", shrink=0.8)
    from_demos, perturbed = rollouts(field, demos, n_perturbed, spread, seed)
    for i, x in enumerate(demos.x):
        ax.plot(x[:, 0], x[:, 1], **DEMO_STYLE, label="demos" if i == 0 else None)
    for i, y in enumerate(from_demos):
        ax.plot(y[:, 0], y[:, 1], **ROLLOUT_STYLE, label="rollouts from demo starts" if i == 0 else None)
    for i, y in enumerate(perturbed):
        ax.plot(y[:, 0], y[:, 1], **PERTURBED_STYLE, label="rollouts from perturbed starts" if i == 0 else None)
    starts = np.concatenate([demos.x[:, 0], perturbed[:, 0]]) if len(perturbed) else demos.x[:, 0]
    ax.plot(starts[:, 0], starts[:, 1], "o", color="0.15", ms=4, mfc="white", zorder=4)
    ax.plot(*field.goal, "*", color="gold", mec="black", ms=16, zorder=5, label="goal")
    if equilibria is not None:
        draw_equilibria(ax, equilibria)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x1")
    ax.set_ylabel("x2")
    ax.legend(loc="best", fontsize=8, framealpha=0.85)


def draw_paths_3d(ax: Any, field: VelocityField, demos: DemoSet, n_perturbed: int = 8,
                  spread: float = 0.1, seed: int = 0, equilibria: EquilibriumReport | None = None,
                  paths: tuple[list[np.ndarray], np.ndarray] | None = None) -> None:
    """Demos, rollouts from demo and perturbed starts (``paths``, default ``rollouts``), the goal and the
    spurious attractors and closed orbits of ``equilibria`` on 3-D axes: the first three coordinates
    (a pose field's positions). 3-D axes do not clip: rollouts are drawn up to where they leave the axes."""
    from_demos, perturbed = paths or rollouts(field, demos, n_perturbed, spread, seed)
    lo, hi = demos.bounds(grow=0.3)
    for i, x in enumerate(demos.x):
        ax.plot(x[:, 0], x[:, 1], x[:, 2], **DEMO_STYLE, label="demos" if i == 0 else None)
    for i, y in enumerate(from_demos):
        y = _within(y, lo, hi)
        ax.plot(y[:, 0], y[:, 1], y[:, 2], **ROLLOUT_STYLE,
                label="rollouts from demo starts" if i == 0 else None)
    for i, y in enumerate(perturbed):
        y = _within(y, lo, hi)
        ax.plot(y[:, 0], y[:, 1], y[:, 2], **PERTURBED_STYLE,
                label="rollouts from perturbed starts" if i == 0 else None)
    g = field.goal
    ax.scatter([g[0]], [g[1]], [g[2]], marker="*", s=200, color="gold", edgecolor="black",
               label="goal", depthshade=False)
    if equilibria is not None:
        draw_equilibria(ax, equilibria)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_xlabel("x1")
    ax.set_ylabel("x2")
    ax.set_zlabel("x3")
    ax.legend(loc="upper left", fontsize=8)


def _within(y: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The path y (T, d) up to its first point outside the box [lo, hi] on its first three coordinates
    (NaN from there on)."""
    out = ((y[:, :3] < lo[:3]) | (y[:, :3] > hi[:3])).any(1)
    first = int(np.argmax(out)) if out.any() else len(y)
    y = np.array(y, dtype=np.float64)
    y[first:] = np.nan
    return y


def curriculum_stages(history: dict[str, Any], config: dict[str, Any] | None) -> list[tuple[int, int]]:
    """The stages of a NODE's segment curriculum (``lfd.learners.node.segment_length``) over the
    iterations in ``history``: [(first iteration, 1-based, segment length S)], one per S. Empty
    for a learner without a curriculum (no ``seg``/``seg_start`` in ``config``) or a constant S."""
    if not config or "seg" not in config or "seg_start" not in config:
        return []
    from lfd.learners.node import segment_length  # imports scipy

    n = len(history.get("loss") or [])
    cfg = SimpleNamespace(curriculum=float(config.get("curriculum", 0.0)), iterations=int(config.get("iterations", n)),
                          seg=int(config["seg"]), seg_start=int(config["seg_start"]))
    stages: list[tuple[int, int]] = []
    for k in range(n):
        s = segment_length(cfg, k)
        if not stages or stages[-1][1] != s:
            stages.append((k + 1, s))
    return stages if len(stages) > 1 else []


def draw_equilibria(ax: Any, report: EquilibriumReport) -> None:
    """Each spurious attractor of ``report`` as a magenta X and each closed orbit as a dash-dotted
    magenta line, one legend entry each kind, on 2-D axes (the first two coordinates) or 3-D axes
    (the first three)."""
    n = 3 if ax.name == "3d" else 2
    for i, e in enumerate(report.spurious_attractors):
        ax.plot(*np.reshape(e.location[:n], (n, 1)), **ATTRACTOR_STYLE, label="spurious attractor" if i == 0 else None)
    for i, o in enumerate(report.orbits):
        path = np.asarray(o.path)[:, :n]
        ax.plot(*path.T, **ORBIT_STYLE, label="closed orbit" if i == 0 else None)


def has_loss_curve(history: dict[str, Any]) -> bool:
    """Whether ``history`` holds a loss curve to draw: at least two finite positive values (the
    tracking learner's fit records one)."""
    loss = np.asarray(history.get("loss") or [], dtype=np.float64)
    return int((np.isfinite(loss) & (loss > 0)).sum()) >= 2


def draw_loss(ax: Axes, history: dict[str, Any], config: dict[str, Any] | None = None) -> None:
    """Training loss per iteration, log scale; a note when the history has no loss. With a NODE's
    ``config``, the stages of its segment curriculum are marked (dotted lines, S = samples per
    segment, the ramp shaded): the loss jumps up where the segments lengthen, by design."""
    loss = np.asarray(history.get("loss") or [], dtype=np.float64)
    ok = np.isfinite(loss) & (loss > 0)
    if not ok.any():
        ax.text(0.5, 0.5, "no loss history", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
        return
    it = np.arange(1, len(loss) + 1)
    ax.plot(it[ok], loss[ok], color="tab:blue", lw=1.0)
    ax.set_yscale("log")
    if loss[ok].max() < 10 * loss[ok].min():  # under a decade: label the ticks in plain numbers
        ax.yaxis.set_major_formatter(FormatStrFormatter("%.3g"))
        ax.yaxis.set_minor_formatter(FormatStrFormatter("%.3g"))
    stages = curriculum_stages(history, config)
    if stages:
        ax.axvspan(stages[0][0], stages[-1][0], color="tab:purple", alpha=0.08,
                   label=f"curriculum: segments lengthen S = {stages[0][1]} -> {stages[-1][1]} samples")
        for k, _seg in stages[1:]:
            ax.axvline(k, color="tab:purple", lw=0.7, ls=":")
        for k, seg in stages:
            ax.text(k, 0.98, f"S={seg}", transform=ax.get_xaxis_transform(), rotation=90, va="top",
                    ha="right", fontsize=7, color="tab:purple")
        ax.legend(loc="lower left", fontsize=8)
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss")
    ax.set_title(f"training loss (final {loss[ok][-1]:.3g})", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)


def field_figure(field: VelocityField, demos: DemoSet, n_perturbed: int = 8, spread: float = 0.1,
                 seed: int = 0, title: str | None = None, equilibria: EquilibriumReport | None = None) -> Figure:
    """The field with its demos and rollouts (left; 2-D streamlines or 3-D paths of positions), a pose
    field's orientations over time (``draw_orientations``, middle), and the training loss (right; only
    when there is a loss curve, ``has_loss_curve``). ``equilibria`` (``lfd.equilibria.find_equilibria``)
    marks the spurious attractors and closed orbits. demos must have the field's dimension (2 or 3, or
    a pose field's 6 chart coordinates)."""
    if demos.dim != field.dim:
        raise ValueError(f"demos are {demos.dim}-D but the field is {field.dim}-D")
    pose = field.space is StateSpace.POSE
    loss = has_loss_curve(field.history)
    ratios = [1.6] + [1.1] * pose + [1.0] * loss
    fig = Figure(figsize=(7.5 + 5.0 * pose + 5.5 * loss, 6.5 if pose else 6), layout="constrained")
    gs = fig.add_gridspec(2, len(ratios), width_ratios=ratios)
    if demos.dim == 2:
        ax = fig.add_subplot(gs[:, 0])
        draw_field_2d(ax, field, demos, n_perturbed, spread, seed, equilibria=equilibria)
    else:
        ax = fig.add_subplot(gs[:, 0], projection="3d")
        paths = rollouts(field, demos, n_perturbed, spread, seed)
        draw_paths_3d(ax, field, demos, n_perturbed, spread, seed, equilibria=equilibria, paths=paths)
        if pose:
            draw_orientations(fig.add_subplot(gs[0, 1]), fig.add_subplot(gs[1, 1]), cast(PoseChart, field.chart),
                              demos, paths, equilibria)
    ax.set_title(title or f"{field.learner} field on {demos.name}" + (" (positions)" if pose else ""), fontsize=11)
    if loss:
        draw_loss(fig.add_subplot(gs[:, -1]), field.history, field.config)
    return fig


def draw_orientations(angle_ax: Axes, rot_ax: Axes, chart: PoseChart, demos: DemoSet,
                      paths: tuple[list[np.ndarray], np.ndarray], equilibria: EquilibriumReport | None = None) -> None:
    """A pose field's orientations over time, demos against rollouts: the geodesic angle to the goal
    orientation (``PoseChart.angle_to_goal``, Eq. (P1)) on ``angle_ax`` (with the perturbed rollouts and
    the angle of each spurious attractor), and the rotation vector r = log(R_g' R) (the chart's
    rotation coordinates over l) on ``rot_ax``, in degrees. demos : chart points, x (N, T, 6);
    paths : (rollouts from the demo starts, list of (T, 6); perturbed rollouts, (P, T, 6)), as ``rollouts``."""
    from_demos, perturbed = paths
    t0 = demos.t - demos.t[:, :1]
    horizon = 1.5 * float(np.mean(demos.t[:, -1] - demos.t[:, 0]))
    t_pert = np.linspace(0.0, horizon, perturbed.shape[1]) if len(perturbed) else np.empty(0)
    for i, (t, x) in enumerate(zip(t0, demos.x)):
        angle_ax.plot(t, np.degrees(chart.angle_to_goal(x)), **DEMO_STYLE, label="demos" if i == 0 else None)
    for i, (t, y) in enumerate(zip(t0, from_demos)):
        angle_ax.plot(t, np.degrees(chart.angle_to_goal(y)), **ROLLOUT_STYLE,
                      label="rollouts from demo starts" if i == 0 else None)
    for i, y in enumerate(perturbed):
        angle_ax.plot(t_pert, np.degrees(chart.angle_to_goal(y)), **{**PERTURBED_STYLE, "lw": 0.9, "alpha": 0.7},
                      label="rollouts from perturbed starts" if i == 0 else None)
    for i, e in enumerate(equilibria.spurious_attractors if equilibria is not None else []):
        angle_ax.axhline(float(np.degrees(chart.angle_to_goal(np.asarray(e.location)))), color="magenta", lw=1.2,
                         ls=":", label="spurious attractor's angle" if i == 0 else None)
    angle_ax.set_ylabel("angle to the goal orientation (deg)")
    angle_ax.set_title("orientation: angle to the goal", fontsize=10)
    angle_ax.set_ylim(bottom=0.0)
    angle_ax.grid(True, alpha=0.3)
    angle_ax.legend(loc="upper right", fontsize=7, framealpha=0.85)
    colors = ("tab:blue", "tab:green", "tab:purple")
    for k, c in enumerate(colors):
        for t, x in zip(t0, demos.x):
            rot_ax.plot(t, np.degrees(x[:, 3 + k] / chart.length), color=c, lw=1.0, alpha=0.35)
        for t, y in zip(t0, from_demos):
            rot_ax.plot(t, np.degrees(y[:, 3 + k] / chart.length), color=c, lw=1.4, ls="--")
    handles = [Line2D([], [], color=c, lw=1.4, label=f"r_{a}") for c, a in zip(colors, "xyz")]
    handles += [Line2D([], [], color="0.4", lw=1.0, alpha=0.5, label="demos"),
                Line2D([], [], color="0.4", lw=1.4, ls="--", label="rollouts from demo starts")]
    rot_ax.legend(handles=handles, loc="lower right", fontsize=7, ncol=2, framealpha=0.85)
    rot_ax.set_xlabel("time (s)")
    rot_ax.set_ylabel("rotation vector log(R_g' R) (deg)")
    rot_ax.set_title("orientation: rotation vector from the goal", fontsize=10)
    rot_ax.grid(True, alpha=0.3)


def draw_obstacles(ax: Axes, obstacles: Any, t: float = 0.0) -> None:
    """Obstacles (``lfd.obstacles.Obstacle``, at time t) on 2-D axes as filled outlines of their
    surface Gamma = 1 (margin included), or on 3-D axes as points on that surface."""
    for i, o in enumerate(obstacles):
        pts = o.surface_points(256 if o.dim == 2 else 600) + (o.offset(t) if o.moving else 0.0)
        label = "obstacles" if i == 0 else None
        if o.dim == 2:
            ref = o.reference_point(t)
            order = np.argsort(np.arctan2(pts[:, 1] - ref[1], pts[:, 0] - ref[0]))
            ax.fill(pts[order, 0], pts[order, 1], color="0.35", alpha=0.55, zorder=3, label=label)
            ax.plot(*ref, "+", color="white", ms=6, zorder=3)
        else:
            cast("Axes3D", ax).scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=2, color="0.35", alpha=0.5,
                                       label=label)   # 3-D axes here
