"""Obstacles from command-line text: ``parse_obstacle("sphere:x,y,r;margin=M;velocity=vx,vy")``."""

from __future__ import annotations

import math
from typing import Any

from lfd.errors import ConfigError
from lfd.obstacles.shapes import Box, Capsule, Obstacle, Sphere

__all__ = ["parse_obstacle"]

_FORMS = "sphere:x,y[,z],r | box:x,y[,z],hx,hy[,hz] | capsule:x1,y1[,z1],x2,y2[,z2],r"
_COUNTS = {"sphere": {3: 2, 4: 3}, "box": {4: 2, 6: 3}, "capsule": {5: 2, 7: 3}}


def parse_obstacle(text: str, dim: int | None = None) -> Obstacle:
    """An obstacle from command-line text, in task units.

    ``sphere:x,y,z,r``, ``box:x,y,z,hx,hy,hz``, ``capsule:x1,y1,z1,x2,y2,z2,r`` (2-D forms with two
    coordinates per point), optionally followed by ``;margin=M`` and ``;velocity=vx,vy[,vz]``.
    Raises ``ConfigError`` (one line) on bad text, or when the dimension is not ``dim``.
    """
    def bad(why: str) -> ConfigError:
        return ConfigError(f"bad obstacle '{text[:80]}': {why} (use {_FORMS})")

    kind, sep, rest = str(text).strip().partition(":")
    kind = kind.strip().lower()
    if not sep or kind not in _COUNTS:
        raise bad(f"unknown shape '{kind[:20]}'" if sep else "missing 'shape:'")
    parts = rest.split(";")
    opts: dict[str, Any] = {}

    def numbers(s: str, what: str) -> list[float]:
        try:
            vals = [float(v) for v in s.split(",")]
        except ValueError:
            raise bad(f"{what} must be comma-separated numbers, got '{s[:40]}'") from None
        if not all(math.isfinite(v) for v in vals):
            raise bad(f"{what} must be finite numbers")
        return vals

    vals = numbers(parts[0], "the shape")
    for opt in parts[1:]:
        key, eq, value = opt.partition("=")
        key = key.strip().lower()
        if not eq or key not in ("margin", "velocity"):
            raise bad(f"unknown option '{opt[:30]}' (options: ;margin=M ;velocity=vx,vy[,vz])")
        v = numbers(value, key)
        if key == "margin":
            if len(v) != 1:
                raise bad("margin must be one number")
            opts["margin"] = v[0]
        else:
            opts["velocity"] = v
    d = _COUNTS[kind].get(len(vals))
    if d is None:
        want = " or ".join(str(k) for k in _COUNTS[kind])
        raise bad(f"{kind} takes {want} numbers, got {len(vals)}")
    if dim is not None and d != dim:
        raise bad(f"a {d}-D {kind} for a {dim}-D field")
    if "velocity" in opts and len(opts["velocity"]) != d:
        raise bad(f"velocity must have {d} numbers")
    try:
        if kind == "sphere":
            return Sphere(vals[:d], vals[d], **opts)
        if kind == "box":
            return Box(vals[:d], vals[d:], **opts)
        return Capsule(vals[:d], vals[d:2 * d], vals[2 * d], **opts)
    except ConfigError as e:
        raise bad(str(e)) from None
