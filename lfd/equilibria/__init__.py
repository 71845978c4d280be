"""A field's equilibria and closed orbits besides its goal: where its flow stops, or circles, short of the goal.

``find_equilibria(field, lo, hi)`` searches a box with damped Newton from a grid of seeds (Sobol seeds
above 3 dimensions) and with long rollouts from the same seeds, and returns an ``EquilibriumReport``:
each equilibrium's location, type (its Jacobian's eigenvalues) and basin (the fraction of starts that
end there), each closed orbit's point, period and basin, and the fractions that reach the goal or
escape. ``lfd certify`` refuses a field with a spurious attractor, a closed orbit or escaping starts
(``EquilibriumReport.clean``); ``lfd plot`` marks them; ``equilibria_summary`` serves the benchmarks.
The method: docs/equations.md, "Equilibria and closed orbits", Eqs. (E1)-(E4).
"""

from __future__ import annotations

from lfd.equilibria.finder import check_box, equilibria_summary, find_equilibria, search_box
from lfd.equilibria.report import ClosedOrbit, Equilibrium, EquilibriumReport

__all__ = ["ClosedOrbit", "Equilibrium", "EquilibriumReport", "check_box", "equilibria_summary", "find_equilibria",
           "search_box"]
