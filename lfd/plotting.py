"""Figures of a learned field with its demos: streamlines or 3-D paths, rollouts, the loss curve.

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
from matplotlib.ticker import FormatStrFormatter

from lfd.demos import DemoSet
from lfd.evaluation import reproduce
from lfd.field import VelocityField

if TYPE_CHECKING:
    from mpl_toolkits.mplot3d import Axes3D

DEMO_STYLE: dict[str, Any] = {"color": "0.15", "lw": 1.2, "alpha": 0.8}
ROLLOUT_STYLE: dict[str, Any] = {"color": "tab:red", "lw": 1.6}
PERTURBED_STYLE: dict[str, Any] = {"color": "tab:orange", "lw": 1.1, "ls": "--"}


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
                  spread: float = 0.1, seed: int = 0, grid: int = 80) -> None:
    """Streamlines of f over the demos' box grown by 50%, coloured by speed |f(x)|, with the demos,
    rollouts from the demo starts and from perturbed starts, and the goal."""
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
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x1")
    ax.set_ylabel("x2")
    ax.legend(loc="best", fontsize=8, framealpha=0.85)


def draw_paths_3d(ax: Any, field: VelocityField, demos: DemoSet, n_perturbed: int = 8,
                  spread: float = 0.1, seed: int = 0) -> None:
    """Demos, rollouts from demo and perturbed starts, and the goal on 3-D axes."""
    from_demos, perturbed = rollouts(field, demos, n_perturbed, spread, seed)
    for i, x in enumerate(demos.x):
        ax.plot(x[:, 0], x[:, 1], x[:, 2], **DEMO_STYLE, label="demos" if i == 0 else None)
    for i, y in enumerate(from_demos):
        ax.plot(y[:, 0], y[:, 1], y[:, 2], **ROLLOUT_STYLE,
                label="rollouts from demo starts" if i == 0 else None)
    for i, y in enumerate(perturbed):
        ax.plot(y[:, 0], y[:, 1], y[:, 2], **PERTURBED_STYLE,
                label="rollouts from perturbed starts" if i == 0 else None)
    g = field.goal
    ax.scatter([g[0]], [g[1]], [g[2]], marker="*", s=200, color="gold", edgecolor="black",
               label="goal", depthshade=False)
    lo, hi = demos.bounds(grow=0.3)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_xlabel("x1")
    ax.set_ylabel("x2")
    ax.set_zlabel("x3")
    ax.legend(loc="upper left", fontsize=8)


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
        s = segment_length(cfg, k)  # type: ignore[arg-type]
        if not stages or stages[-1][1] != s:
            stages.append((k + 1, s))
    return stages if len(stages) > 1 else []


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
                 seed: int = 0, title: str | None = None) -> Figure:
    """The field with its demos and rollouts (left; 2-D streamlines or 3-D paths) and the training
    loss (right). demos must have the field's dimension (2 or 3)."""
    if demos.dim != field.dim:
        raise ValueError(f"demos are {demos.dim}-D but the field is {field.dim}-D")
    fig = Figure(figsize=(13, 6), layout="constrained")
    gs = fig.add_gridspec(1, 2, width_ratios=[1.6, 1.0])
    if demos.dim == 2:
        ax = fig.add_subplot(gs[0, 0])
        draw_field_2d(ax, field, demos, n_perturbed, spread, seed)
    else:
        ax = fig.add_subplot(gs[0, 0], projection="3d")
        draw_paths_3d(ax, field, demos, n_perturbed, spread, seed)
    ax.set_title(title or f"{field.learner} field on {demos.name}", fontsize=11)
    draw_loss(fig.add_subplot(gs[0, 1]), field.history, field.config)
    return fig


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
