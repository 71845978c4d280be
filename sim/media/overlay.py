"""2-D overlays drawn into rendered frames (Pillow): paths, markers, push arrow, legend and labels.

Paths are projected into the image (``sim.media.camera.project``) and drawn on top of the rendered
scene, so the arm never hides them. The three paths differ in colour AND width and are drawn
widest first (demonstration, the field's own rollout, the robot's trace), so each thinner line
runs inside the wider one and none looks dashed. Sizes scale with the frame height
(``Style.scale``) so small test videos and large ones look alike.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

RGB = tuple[int, int, int]

DEMO_RGB: RGB = (120, 170, 255)      # light blue, widest
FIELD_RGB: RGB = (40, 170, 80)       # green, medium
TRACE_RGB: RGB = (255, 120, 0)       # orange, thinnest
GOAL_RGB: RGB = (255, 215, 0)
PUSH_RGB: RGB = (220, 20, 20)
LIMITER_RGB: RGB = (200, 120, 0)   # the 'limiter acting' label
TEXT_RGB: RGB = (20, 20, 20)
PANEL_RGB: RGB = (245, 245, 245)
LEGEND = (("demonstration", DEMO_RGB, 10.0), ("field rollout", FIELD_RGB, 6.0), ("robot trace", TRACE_RGB, 3.0))
ERROR_FULL_SCALE_M = 0.01            # the error bar is full at 10 mm


@lru_cache(maxsize=8)
def font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """DejaVu Sans (shipped with matplotlib, found without importing it) at ``size`` px, else
    Pillow's default font."""
    import importlib.util

    try:
        spec = importlib.util.find_spec("matplotlib")
        folders = list(spec.submodule_search_locations or []) if spec else []
        for folder in folders:
            path = Path(folder) / "mpl-data" / "fonts" / "ttf" / "DejaVuSans.ttf"
            if path.is_file():
                return ImageFont.truetype(str(path), size)
    except (ImportError, OSError, ValueError):
        pass
    return ImageFont.load_default(size)


@dataclass(frozen=True)
class Style:
    """Pixel sizes for a frame ``height`` px tall (the widths in ``LEGEND`` are for 480 px)."""

    height: int

    @property
    def scale(self) -> float:
        return max(self.height / 480.0, 0.25)

    def px(self, value: float, least: int = 1) -> int:
        return max(least, int(round(value * self.scale)))

    @property
    def font_size(self) -> int:
        return max(8, int(round(15 * self.scale)))


@dataclass
class FrameText:
    """The labels of one frame: ``title`` (learner and scenario), simulated time ``t`` (s),
    tracking error ``error_m`` (m, None: not shown), and ``limiter``: whether the joint-velocity
    limiter (``robots.limiter``) held the command back around this frame (labelled when True)."""

    title: str
    t: float
    error_m: float | None = None
    limiter: bool = False


def _polyline(draw: ImageDraw.ImageDraw, uv: np.ndarray, rgb: RGB, width: int) -> None:
    ok = np.isfinite(uv).all(axis=1)
    uv = uv[ok]
    if len(uv) < 2:
        return
    draw.line([tuple(p) for p in uv.tolist()], fill=rgb, width=width)
    r = width / 2.0
    for p in (uv[0], uv[-1]):  # round caps
        draw.ellipse([p[0] - r, p[1] - r, p[0] + r, p[1] + r], fill=rgb)


def _dot(draw: ImageDraw.ImageDraw, p: np.ndarray, radius: float, rgb: RGB, outline: RGB = (0, 0, 0)) -> None:
    if np.isfinite(p).all():
        draw.ellipse([p[0] - radius, p[1] - radius, p[0] + radius, p[1] + radius], fill=rgb, outline=outline,
                     width=max(1, int(radius / 4)))


def arrow(draw: ImageDraw.ImageDraw, tail: np.ndarray, head: np.ndarray, rgb: RGB, width: int) -> None:
    """A 2-D arrow from pixel ``tail`` to ``head`` (2,), head size from ``width``."""
    if not (np.isfinite(tail).all() and np.isfinite(head).all()):
        return
    d = head - tail
    n = float(np.hypot(*d))
    if n < 1:
        return
    d = d / n
    size = min(4.0 * width, 0.6 * n)
    base = head - size * d
    perp = np.array([-d[1], d[0]]) * size * 0.5
    draw.line([tuple(tail), tuple(base)], fill=rgb, width=width)
    draw.polygon([tuple(head), tuple(base + perp), tuple(base - perp)], fill=rgb)


AXIS_RGB: tuple[RGB, RGB, RGB] = ((220, 40, 40), (40, 170, 40), (40, 90, 230))   # x, y, z


def draw_frames(img: Image.Image, origins_uv: np.ndarray, tips_uv: np.ndarray, width: float) -> None:
    """Tool frames as small axes: origins (F, 2) and their x, y, z axis tips (F, 3, 2), pixels; x red,
    y green, z blue."""
    st = Style(img.height)
    draw = ImageDraw.Draw(img)
    w = st.px(width, 1)
    for o, tips in zip(origins_uv, tips_uv):
        if not (np.isfinite(o).all() and np.isfinite(tips).all()):
            continue
        for tip, rgb in zip(tips, AXIS_RGB):
            draw.line([tuple(o), tuple(tip)], fill=rgb, width=w)


def draw_static(img: Image.Image, demo_uv: np.ndarray, field_uv: np.ndarray | None, title: str,
                legend: bool = True) -> None:
    """What stays the same in every frame of a panel: the demonstration and the field's rollout
    (each (K, 2) pixels), the legend (top left) and the title (bottom right)."""
    st = Style(img.height)
    draw = ImageDraw.Draw(img)
    _polyline(draw, demo_uv, DEMO_RGB, st.px(LEGEND[0][2], 6))
    if field_uv is not None:
        _polyline(draw, field_uv, FIELD_RGB, st.px(LEGEND[1][2], 4))
    f = font(st.font_size)
    pad = st.px(6)
    if legend:
        line_len, row = st.px(30), st.px(20)
        names = [n for n, _, _ in LEGEND] + ["goal"]
        w = max(draw.textlength(n, font=f) for n in names) + line_len + 3 * pad
        draw.rectangle([pad, pad, pad + w, pad + row * len(names) + pad], fill=PANEL_RGB, outline=(160, 160, 160))
        for i, (name, rgb, width) in enumerate(LEGEND):
            y = pad + pad + row * i + row // 2
            draw.line([(2 * pad, y), (2 * pad + line_len, y)], fill=rgb, width=st.px(width, 3))
            draw.text((3 * pad + line_len, y), name, fill=TEXT_RGB, font=f, anchor="lm")
        y = pad + pad + row * len(LEGEND) + row // 2
        _dot(draw, np.array([2 * pad + line_len / 2, y]), st.px(6), GOAL_RGB)
        draw.text((3 * pad + line_len, y), "goal", fill=TEXT_RGB, font=f, anchor="lm")
    if title:  # bottom right: the legend and the time take the top corners of narrow panels
        _boxed(draw, (img.width - pad, img.height - pad), title, f, "rb", pad)


def draw_dynamic(img: Image.Image, trace_uv: np.ndarray, goal_uv: np.ndarray,
                 push_uv: tuple[np.ndarray, np.ndarray] | None, push_dot_uv: np.ndarray | None,
                 text: FrameText) -> None:
    """What changes from frame to frame: the robot's trace so far (K, 2), the goal where it is now
    (2,) (it moves with ``lfd.goal``; drawn over the trace, which ends on it), the point where the
    push began, the push arrow (tail, head) while it acts, the time and the tracking error."""
    st = Style(img.height)
    draw = ImageDraw.Draw(img)
    _polyline(draw, trace_uv, TRACE_RGB, st.px(LEGEND[2][2], 2))
    if push_dot_uv is not None:
        _dot(draw, push_dot_uv, st.px(4), PUSH_RGB, PUSH_RGB)
    _dot(draw, goal_uv, st.px(7), GOAL_RGB)
    if len(trace_uv) and np.isfinite(trace_uv[-1]).all():
        _dot(draw, trace_uv[-1], st.px(3.5), TRACE_RGB)
    if push_uv is not None:
        arrow(draw, push_uv[0], push_uv[1], PUSH_RGB, st.px(4))
    draw_labels(img, text)


def draw_labels(img: Image.Image, text: FrameText) -> None:
    """The simulated time (top right; below it "limiter acting" while the limiter holds the command),
    and the tracking error with a bar (bottom left); the title is drawn once, in ``draw_static``."""
    st = Style(img.height)
    draw = ImageDraw.Draw(img)
    f = font(st.font_size)
    pad = st.px(6)
    _boxed(draw, (img.width - pad, pad), f"t = {text.t:5.2f} s", f, "rt", pad)
    if text.limiter:   # below the time: the command is being held at the limits
        xy = (img.width - pad, pad + st.font_size + 3 * pad)
        box = draw.textbbox(xy, "limiter acting", font=f, anchor="rt")
        draw.rectangle([box[0] - pad, box[1] - pad // 2, box[2] + pad, box[3] + pad // 2], fill=LIMITER_RGB)
        draw.text(xy, "limiter acting", fill=(255, 255, 255), font=f, anchor="rt")
    if text.error_m is not None:
        label = f"tracking error {text.error_m * 1e3:5.1f} mm"
        x0, y1 = pad, img.height - pad
        bar_w, bar_h = st.px(120), st.px(8)
        tw = draw.textlength(label, font=f)
        draw.rectangle([x0, y1 - st.font_size - bar_h - 3 * pad, x0 + max(tw, bar_w) + 2 * pad, y1],
                       fill=PANEL_RGB, outline=(160, 160, 160))
        draw.text((x0 + pad, y1 - bar_h - 2 * pad), label, fill=TEXT_RGB, font=f, anchor="ls")
        frac = float(np.clip(text.error_m / ERROR_FULL_SCALE_M, 0.0, 1.0))
        draw.rectangle([x0 + pad, y1 - pad - bar_h, x0 + pad + bar_w, y1 - pad], outline=(90, 90, 90))
        if frac > 0:
            draw.rectangle([x0 + pad, y1 - pad - bar_h, x0 + pad + int(bar_w * frac), y1 - pad], fill=TRACE_RGB)


class StaticLayer:
    """Pixels drawn once (``draw_static``) and stamped onto every frame: colours (h, w, 3) where
    ``mask`` (h, w) is set. Stamping costs a masked copy instead of redrawing lines and text."""

    def __init__(self, width: int, height: int) -> None:
        self.image = Image.new("RGBA", (width, height), (0, 0, 0, 0))

    def freeze(self) -> None:
        a = np.asarray(self.image)
        self.mask = a[..., 3] > 0
        self.index = np.flatnonzero(self.mask)               # the layer's pixels, row-major
        self.values = _pixels(np.ascontiguousarray(a[..., :3]))[self.index].copy()

    def stamp(self, frame: np.ndarray) -> None:
        """Copy the layer into ``frame`` (h, w, 3) uint8, C-contiguous, in place."""
        np.put(_pixels(frame), self.index, self.values)


_PIXEL = np.dtype((np.void, 3))


def _pixels(image: np.ndarray) -> np.ndarray:
    """A view, shape (h w,), of image (h, w, 3) uint8, C-contiguous, with one 3-byte item per pixel:
    a masked copy of whole pixels is then one ``np.put`` (much faster than on (h w, 3))."""
    return image.reshape(-1, 3).view(_PIXEL).reshape(-1)


def _boxed(draw: ImageDraw.ImageDraw, xy: tuple[int, int], text: str, f, anchor: str, pad: int) -> None:
    box = draw.textbbox(xy, text, font=f, anchor=anchor)
    draw.rectangle([box[0] - pad, box[1] - pad // 2, box[2] + pad, box[3] + pad // 2], fill=PANEL_RGB)
    draw.text(xy, text, fill=TEXT_RGB, font=f, anchor=anchor)


def tile(panels: Sequence[np.ndarray], cols: int) -> np.ndarray:
    """Panels (each (h, w, 3) uint8, equal shapes) in a grid of ``cols`` columns, row by row, with
    black where a row is short. Returns (rows h, cols w, 3)."""
    h, w, _ = panels[0].shape
    rows = -(-len(panels) // cols)
    out = np.zeros((rows * h, cols * w, 3), dtype=np.uint8)
    for i, p in enumerate(panels):
        r, c = divmod(i, cols)
        out[r * h:(r + 1) * h, c * w:(c + 1) * w] = p
    return out
