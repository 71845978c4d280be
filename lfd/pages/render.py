"""A ``Page`` as one self-contained HTML file, through the Jinja2 template ``templates/page.html.j2``.

Self-contained: the style sheet is inlined, the page has no script and no font of its own (system
fonts), and nothing it loads comes from the network. Videos, images and data files are linked by
their path relative to the page: the page is the index of its folder, and the two travel together
(inlining the figures would store each twice; the videos cannot be inlined at all).
"""

from __future__ import annotations

import math
import os
import platform
from importlib import metadata
from pathlib import Path
from urllib.parse import quote

import jinja2

from lfd.io import atomic_write
from lfd.pages.page import Page

__all__ = ["render", "versions", "write_page"]

TEMPLATES = Path(__file__).parent / "templates"
_ENV = jinja2.Environment(loader=jinja2.FileSystemLoader(TEMPLATES), autoescape=True,
                          undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)


def _href(path: Path, folder: Path) -> str:
    """``path`` relative to ``folder``, as a URL path (percent-encoded)."""
    rel = os.path.relpath(os.path.abspath(path), os.path.abspath(folder))
    return quote(Path(rel).as_posix())


def _size(n: int | None) -> str:
    """A file size in B, kB or MB (a dash when unknown)."""
    if n is None:
        return "—"
    if n < 1000:
        return f"{n} B"
    return f"{n / 1e3:.0f} kB" if n < 1e6 else f"{n / 1e6:.1f} MB"


def _value(v: float | None) -> str:
    """A cell's number for its ``data-value`` attribute: the shortest text that reads back as it."""
    return "" if v is None or not math.isfinite(v) else repr(float(v))


def render(page: Page, where: Path) -> str:
    """The HTML of ``page``, to be saved at ``where`` (links are relative to its folder)."""
    folder = Path(where).parent
    return _ENV.get_template("page.html.j2").render(
        page=page, href=lambda p: _href(Path(p), folder), size=_size, value=_value,
        css=(TEMPLATES / "page.css").read_text(encoding="utf-8"))


def write_page(path: Path, page: Page, where: Path | None = None) -> None:
    """Write ``page`` to ``path`` atomically; ``where`` is where it will be read from (links are
    relative to that folder; default ``path``): a staged page names its final place."""
    html = render(page, Path(where if where is not None else path))
    atomic_write(path, lambda f: f.write(html.encode("utf-8")))


def versions(distributions: tuple[str, ...]) -> dict[str, str]:
    """{name: version} of Python and each installed distribution of ``distributions`` (read from
    the installed metadata; nothing is imported); a missing one is left out."""
    out = {"python": platform.python_version()}
    for name in distributions:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out
