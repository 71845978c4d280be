"""The LASA benchmark protocol: which data, which split, which starts, which horizon.

Everything a number in the report depends on, other than the learner and its seed, is a field
of ``LasaProtocol``; its hash keys the result cache, so changing any of them recomputes.

- Data: ``lfd.lasa(shape)``, 7 demos x 1000 samples, 2-D, in mm, goal (mean end point) at the
  origin to 1e-3 mm. No resampling, no filtering beyond ``DemoSet``'s smoothed velocities; the
  learners normalise internally (``lfd.normalization``: x_n = (x - goal) / s, s = max |x - goal|).
- Splits (``lfd.bench.suite``): in-sample (all 7 demos train and are scored) and held-out
  (leave one demo out).
- Starts (the same for every learner and seed): the 7 demo starts; a ring of ``ring_points``
  points at distance ``ring_radius * extent`` around each demo start (extent = the larger side
  of the demos' bounding box); ``box_points`` points uniform in the bounding box grown by
  ``box_grow`` (its size times 1 + box_grow), seeded by (``starts_seed``, crc32 of the shape).
- Convergence: a rollout converges if it ends within ``radius_mm`` of the goal after
  horizon = ``horizon_factor`` x the longest demo's duration.
- Spurious attractors (CONDOR/PUMA): the fraction of a ``spurious_grid`` x ``spurious_grid`` grid
  of starts over the demos' bounding box (not grown) that does not converge.
"""

from __future__ import annotations

import hashlib
import json
import zlib
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np

from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.metrics import grid_starts as metric_grid_starts
from lfd.validate import check_ints

PROTOCOL_VERSION = 3  # 2: dtw_per_sample, chamfer_dtwd_std, lobe-sum swept area, spurious grid; 3: held-out split
N_LASA_DEMOS = 7


@dataclass(frozen=True)
class LasaProtocol:
    """The fixed settings of one benchmark run (see the module docstring).

    Every field is a setting of the protocol, described beside it with its unit; a bad value is a
    ``ConfigError``. ``to_dict`` (with ``PROTOCOL_VERSION``) keys the result cache.
    """

    ring_radius: float = 0.1         # ring starts at ring_radius x extent around each demo start
    ring_points: int = 8             # starts on each ring
    box_points: int = 64             # starts uniform in the demos' bounding box grown by box_grow
    box_grow: float = 0.5            # the box grows by this fraction of its size
    starts_seed: int = 0             # seed of the perturbed starts (independent of the learner's seed)
    radius_mm: float = 1.0           # convergence radius, mm
    horizon_factor: float = 3.0      # convergence horizon, x the longest demo's duration
    horizon_stride: int = 4          # convergence rollouts step this x the demos' mean sample interval
    dtw_step: int = 4                # DTW on every dtw_step-th sample (the LASA convention is 4)
    grid: int = 40                   # streamline grid points per side (for the figures)
    spurious_grid: int = 35          # starts per side of the spurious-attractor grid over the demos' box
    keep_points: int = 200           # samples kept per convergence rollout for the figures
    timing_calls: int = 500          # single-point evaluations timed per repeat (5 repeats, median)

    def __post_init__(self) -> None:
        check_ints(self, (("ring_points", 0, 10_000), ("box_points", 0, 100_000), ("dtw_step", 1, None),
                          ("horizon_stride", 1, None), ("spurious_grid", 2, 1000)), error=ConfigError)
        if not (self.radius_mm > 0 and self.horizon_factor > 0 and self.ring_radius >= 0):
            raise ConfigError("radius_mm and horizon_factor must be positive, ring_radius >= 0")

    def to_dict(self) -> dict[str, Any]:
        """The settings and ``version`` (PROTOCOL_VERSION), plain JSON values (the cache key)."""
        return {"version": PROTOCOL_VERSION, **asdict(self)}


def stable_hash(obj: Any) -> str:
    """sha256 of the canonical JSON of ``obj`` (sorted keys), first 16 hex digits."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def resolve_names(spec: str, known: tuple[str, ...], quick: tuple[str, ...] | None, what: str) -> list[str]:
    """``all`` (``known``, or ``quick`` when given), or a comma list of names from ``known``, in order,
    without repeats; ``ConfigError`` naming ``what`` for an unknown or empty list."""
    if spec == "all":
        return list(known if quick is None else quick)
    names = [s.strip() for s in spec.split(",") if s.strip()]
    unknown = [s for s in names if s not in known]
    if unknown or not names:
        raise ConfigError(f"unknown {what} {', '.join(unknown) or '(none given)'}; known: {', '.join(known)}")
    return list(dict.fromkeys(names))


@dataclass(frozen=True)
class Starts:
    """Rollout starts of one shape, each array of shape (n, 2), in mm."""

    demo: np.ndarray
    ring: np.ndarray
    box: np.ndarray

    @property
    def all(self) -> np.ndarray:
        """demo, ring and box starts stacked, shape (n_demo + n_ring + n_box, 2)."""
        return np.concatenate([self.demo, self.ring, self.box])

    def groups(self) -> dict[str, slice]:
        """Where each kind of start sits in ``all``."""
        a, b = len(self.demo), len(self.demo) + len(self.ring)
        return {"demo": slice(0, a), "ring": slice(a, b), "box": slice(b, b + len(self.box))}


def starts(demos: DemoSet, shape: str, protocol: LasaProtocol) -> Starts:
    """The demo starts x_i(0), shape (N, d); rings x_i(0) + r (cos th_ik, sin th_ik) with
    r = ring_radius * extent, th_ik = 2 pi (k + u_i) / ring_points, u_i ~ U(0, 1); and box points
    ~ U(lo, hi) of ``demos.bounds(box_grow)``. Seeded by (starts_seed, crc32(shape))."""
    rng = np.random.default_rng([protocol.starts_seed, zlib.crc32(shape.encode())])
    x0 = demos.x[:, 0].copy()
    lo, hi = demos.bounds()
    r = protocol.ring_radius * float(np.max(hi - lo))
    k = np.arange(protocol.ring_points)
    th = 2 * np.pi * (k[None, :] + rng.uniform(0, 1, (len(x0), 1))) / max(protocol.ring_points, 1)
    ring = (x0[:, None, :] + r * np.stack([np.cos(th), np.sin(th)], axis=-1)).reshape(-1, 2)
    blo, bhi = demos.bounds(protocol.box_grow)
    box = rng.uniform(blo, bhi, size=(protocol.box_points, 2))
    return Starts(demo=x0, ring=ring, box=box)


class HorizonSettings(Protocol):
    """A protocol's horizon settings (``LasaProtocol``, ``lfd.bench.robottasks.RobotTasksProtocol``)."""

    @property
    def horizon_factor(self) -> float:
        """The horizon, x the longest demo's duration."""
        ...

    @property
    def horizon_stride(self) -> int:
        """The output step, in demo sample intervals."""
        ...


def horizon(demos: DemoSet, protocol: HorizonSettings) -> tuple[float, int]:
    """(H, n): H = horizon_factor * max_i (t_i[-1] - t_i[0]); n samples so that the step
    H / (n - 1) is at most horizon_stride times the demos' mean sample interval."""
    durations = demos.t[:, -1] - demos.t[:, 0]
    h = protocol.horizon_factor * float(durations.max())
    dt = protocol.horizon_stride * float(np.mean(np.diff(demos.t, axis=1)))
    return h, int(np.ceil(h / dt)) + 1


def grid_starts(demos: DemoSet, protocol: LasaProtocol) -> np.ndarray:
    """The spurious-attractor starts: a ``spurious_grid`` x ``spurious_grid`` grid over the demos'
    bounding box ``demos.bounds()``, corners included, shape (spurious_grid^2, 2)
    (``lfd.metrics.grid_starts``)."""
    lo, hi = demos.bounds()
    return metric_grid_starts(lo, hi, protocol.spurious_grid)
