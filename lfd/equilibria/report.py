"""What ``lfd.equilibria.find_equilibria`` found: the equilibria and closed orbits of a field besides its
goal, where the grid starts end, and the verdict they make (``EquilibriumReport.clean``)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

#: an eigenvalue counts as on the imaginary axis when |Re| <= CENTRE_TOL times the largest |eigenvalue|
CENTRE_TOL = 1e-6
TYPES = ("attractor", "saddle", "repeller", "centre-like")


def classify(eigenvalues: np.ndarray) -> str:
    """The type of an equilibrium from its Jacobian's eigenvalues, shape (d,) complex: ``attractor``
    (every Re < 0), ``repeller`` (every Re > 0), ``saddle`` (both signs), else ``centre-like`` (some
    Re within ``CENTRE_TOL`` of 0 and no sign of both kinds: the linearisation does not decide)."""
    re = np.real(np.asarray(eigenvalues))
    if not np.isfinite(re).all():
        return "centre-like"
    tol = CENTRE_TOL * max(float(np.abs(eigenvalues).max(initial=0.0)), 1e-300)
    neg, pos = bool((re < -tol).any()), bool((re > tol).any())
    if neg and pos:
        return "saddle"
    if (re < -tol).all():
        return "attractor"
    if (re > tol).all():
        return "repeller"
    return "centre-like"


@dataclass(frozen=True)
class Equilibrium:
    """A point where f(x) = 0, other than the goal.

    location : (d,) user units; eigenvalues : the Jacobian's, each [Re, Im], 1/s (sorted by Re);
    type : one of ``TYPES`` (``classify``); residual : |f(location)|, user units/s; basin : the fraction
    of the grid starts whose rollouts end within the tolerance of it; in_box : whether it lies in the
    searched box (an attractor outside it is reported when starts from the box end there).
    """

    location: list[float]
    eigenvalues: list[list[float]]
    type: str
    residual: float
    basin: float
    in_box: bool

    @property
    def attracting(self) -> bool:
        """An attractor, or a centre-like point that grid starts end at: a spurious attractor."""
        return self.type == "attractor" or (self.type == "centre-like" and self.basin > 0)


@dataclass(frozen=True)
class ClosedOrbit:
    """A closed orbit (a limit cycle) that rollouts from the box settle on instead of the goal.

    point : (d,) a point on it, user units; period : s, the recurrence time; basin : the fraction of
    grid starts that end on it; size : the largest distance of its points from ``point``, user units;
    path : points along one period, (K, d), user units (for plots).
    """

    point: list[float]
    period: float
    basin: float
    size: float
    path: list[list[float]] = field(repr=False)


@dataclass(frozen=True)
class EquilibriumReport:
    """The outcome of ``find_equilibria``.

    equilibria : every equilibrium found besides the goal (by type: attractors first)
    orbits : closed orbits the rollouts settle on
    goal : (d,); goal_fraction : the fraction of grid starts whose rollouts end within the tolerance of it
    escaped_fraction : the fraction whose rollouts left the box grown by its own size on every side
        (or stopped being finite): the goal does not attract them either
    other_fraction : the fraction that ends nowhere of the above (still moving without recurring, or
        stalled short of any root, after the horizon)
    box : [lo, hi], the searched box; method : the method's parameters (seeds, steps, tolerances)
    elapsed_s : wall time
    """

    equilibria: list[Equilibrium]
    orbits: list[ClosedOrbit]
    goal: list[float]
    goal_fraction: float
    escaped_fraction: float
    other_fraction: float
    box: list[list[float]]
    method: dict[str, Any]
    elapsed_s: float

    @property
    def spurious_attractors(self) -> list[Equilibrium]:
        """The equilibria besides the goal that attract (``Equilibrium.attracting``)."""
        return [e for e in self.equilibria if e.attracting]

    @property
    def clean(self) -> bool:
        """No spurious attractor, no closed orbit and no escaping start: every start the search
        followed can only end at the goal."""
        return not self.spurious_attractors and not self.orbits and self.escaped_fraction == 0

    def failures(self) -> list[str]:
        """Why the report is not ``clean``, one short phrase each (empty when it is)."""
        out = []
        if self.spurious_attractors:
            n = len(self.spurious_attractors)
            out.append(f"{n} spurious attractor{'s' if n > 1 else ''}")
        if self.orbits:
            out.append(f"{len(self.orbits)} closed orbit{'s' if len(self.orbits) > 1 else ''}")
        if self.escaped_fraction > 0:
            out.append(f"{100 * self.escaped_fraction:.1f}% of the starts escape the box")
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-able, with ``clean`` and the count of spurious attractors."""
        return {**asdict(self), "clean": self.clean, "spurious_attractors": len(self.spurious_attractors)}

    def summary(self) -> str:
        """Human-readable lines for the command line."""
        m = self.method
        lo, hi = (np.asarray(c) for c in self.box)
        tiny = 1e-9 * float(np.max(hi - lo))      # round-off about 0 is printed as 0
        head = "no equilibrium or closed orbit besides the goal" if not (self.equilibria or self.orbits) else \
            f"{len(self.equilibria)} equilibri{'a' if len(self.equilibria) != 1 else 'um'} and " \
            f"{len(self.orbits)} closed orbit{'s' if len(self.orbits) != 1 else ''} besides the goal"
        lines = [f"equilibria: {head}; {100 * self.goal_fraction:.1f}% of {m['n_starts']} starts reach the goal, "
                 f"{100 * self.escaped_fraction:.1f}% escape, {100 * self.other_fraction:.1f}% end elsewhere"]
        for e in self.equilibria:
            eig = ", ".join(_complex(v) for v in e.eigenvalues)
            where = "" if e.in_box else " (outside the box)"
            lines.append(f"  {e.type} at ({_point(e.location, tiny)}){where}: eigenvalues {eig} /s; "
                         f"{100 * e.basin:.1f}% of the starts end there; |f| = {e.residual:.2g}")
        for o in self.orbits:
            lines.append(f"  closed orbit through ({_point(o.point, tiny)}), period {o.period:.3g} s, "
                         f"size {o.size:.3g}: {100 * o.basin:.1f}% of the starts end on it")
        lines.append(f"  method: damped Newton from {m['n_seeds']} {m['seeds']} seeds, rollouts of "
                     f"{m['horizon_s']:.3g} s ({m['steps']} RK4 steps) from {m['n_starts']} starts in "
                     f"{_box(self.box)}; tolerance {m['tolerance']:.3g}; {self.elapsed_s:.2f} s")
        return "\n".join(lines)


def _point(v: list[float], tiny: float) -> str:
    return ", ".join(f"{x if abs(x) > tiny else 0.0:.4g}" for x in v)


def _complex(v: list[float]) -> str:
    re, im = v
    if im == 0 or not math.isfinite(im):
        return f"{re:.3g}"
    return f"{re:.3g}{'+' if im > 0 else '-'}{abs(im):.3g}i"


def _box(box: list[list[float]]) -> str:
    return " x ".join(f"[{lo:.4g}, {hi:.4g}]" for lo, hi in zip(*box))
