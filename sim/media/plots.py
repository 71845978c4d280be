"""Figures of arm runs, from their time series (``sim.run.timeseries.arrays``), written beside metrics.json.

* ``run_figure``: tracking error |p - p_ref| and deviation from the unperturbed run over time,
  the push (or hold) window shaded; joint positions against their limits, as the fraction of
  each joint's range (0 = lower limit, 1 = upper limit).
* ``paths_figure``: every run's tool path over the demonstrations in task space (2-D: the
  plane; 3-D: a 3-D axes).
* ``loss_figure``: a learner's training loss, or None when its record holds no curve to draw.

Figures are ``matplotlib.figure.Figure`` without pyplot (no global backend).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from lfd.plotting import draw_loss, has_loss_curve


def _shade(ax: Any, window: np.ndarray, label: str) -> None:
    if np.all(np.isfinite(window)):
        ax.axvspan(float(window[0]), float(window[1]), color="tab:red", alpha=0.15, label=label)


def run_figure(ts: dict[str, np.ndarray], hold_window: tuple[float, float] | None = None) -> Figure:
    """Tracking error and deviation (top), joint positions within their limits (bottom) of one run."""
    t = ts["t"]
    fig = Figure(figsize=(9, 6.5), layout="constrained")
    ax, bx = fig.subplots(2, 1, sharex=True)
    ax.plot(t, 1e3 * ts["tracking_error"], color="tab:orange", lw=1.4, label="tracking error |p - p_ref|")
    if np.isfinite(ts["deviation"]).any():
        ax.plot(t, 1e3 * ts["deviation"], color="tab:blue", lw=1.4, label="deviation from the unpushed run")
    _shade(ax, ts["push_window"], "push")
    if hold_window is not None:
        _shade(ax, np.asarray(hold_window, dtype=float), "hold")
    ax.set_ylabel("mm")
    ax.set_title(f"{ts['learner']} / {ts['scenario']}: tracking error and deviation", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    lo, hi = ts["q_min"], ts["q_max"]
    frac = (ts["q"] - lo) / np.where(hi > lo, hi - lo, 1.0)
    for j, name in enumerate(ts["joint_names"]):
        bx.plot(t, frac[:, j], lw=1.1, label=str(name))
    bx.axhline(0.0, color="black", lw=1.0)
    bx.axhline(1.0, color="black", lw=1.0)
    bx.axhspan(-0.05, 0.0, color="tab:red", alpha=0.15)
    bx.axhspan(1.0, 1.05, color="tab:red", alpha=0.15)
    _shade(bx, ts["push_window"], "push")
    bx.set_ylim(-0.05, 1.05)
    bx.set_ylabel("position in the joint's range\n(0 lower limit, 1 upper)")
    bx.set_xlabel("simulated time (s)")
    bx.grid(True, alpha=0.3)
    bx.legend(fontsize=7, ncol=min(len(ts["joint_names"]), 4), loc="lower right")
    return fig


def paths_figure(demos_x: np.ndarray, runs: Sequence[tuple[str, np.ndarray]], goal: np.ndarray,
                 title: str = "") -> Figure:
    """Tool paths in task space over the demos: demos_x (N, T, d); runs [(label, x (K, d))]; goal (d,)."""
    d = demos_x.shape[2]
    fig = Figure(figsize=(7.5, 6.5), layout="constrained")
    ax = fig.add_subplot(projection="3d" if d == 3 else None)
    for i, x in enumerate(demos_x):
        ax.plot(*x.T, color="0.55", lw=3.0, alpha=0.6, label="demonstrations" if i == 0 else None)
    for label, x in runs:
        ax.plot(*np.asarray(x).T, lw=1.2, label=label)
    ax.plot(*np.asarray(goal).reshape(-1, 1), "*", color="gold", mec="black", ms=14, label="goal")
    if d == 2:
        ax.set_aspect("equal")
    ax.set_xlabel("x1")
    ax.set_ylabel("x2")
    ax.set_title(title or "tool paths in task space", fontsize=10)
    ax.legend(fontsize=7, loc="best")
    return fig


def loss_figure(history: dict[str, Any], config: dict[str, Any] | None) -> Figure | None:
    """The training loss of ``history`` (``lfd.plotting.draw_loss``, a NODE's curriculum marked from its
    ``config``), or None when there is no loss curve (``lfd.plotting.has_loss_curve``: the tracking
    learner's fit records one value)."""
    if not has_loss_curve(history):
        return None
    fig = Figure(figsize=(7, 4.5), layout="constrained")
    draw_loss(fig.add_subplot(), history, config)
    return fig
