"""What the speed scripts (``scripts/speed_*.py``) share.

* ``run_main``: run a script's ``main`` as the process, Ctrl-C ending it with one line and exit 130;
* ``none_and_push``: the metrics of one field on an experiment unperturbed and under the default push,
  and the push's recovery time as text.

Imported by those scripts as ``_speed`` (Python puts the script's own folder first on ``sys.path``).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, NoReturn


def run_main(main: Callable[[], int], prog: str) -> NoReturn:
    """``sys.exit(main())``; Ctrl-C or SIGTERM prints ``PROG: interrupted`` and exits 130
    (``lfd.interrupts.run_main``)."""
    from lfd.interrupts import run_main as run

    sys.exit(run(prog, lambda: lambda argv: main()))


def none_and_push(exp: Any, field: Any) -> tuple[dict[str, Any], dict[str, Any], str]:
    """(metrics unperturbed, metrics pushed, recovery time as ``'  0.42 s'`` or ``'never'``) of
    ``field`` run by the ``sim.Experiment`` ``exp`` under the scenarios ``none`` and ``push``."""
    a = exp.run(field, "none").metrics
    b = exp.run(field, "push").metrics
    rec = b["recovery_time_s"]
    return a, b, "never" if rec is None else f"{rec:5.2f} s"
