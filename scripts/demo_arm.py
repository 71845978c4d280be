#!/usr/bin/env python
"""Run learned velocity fields on a simulated arm in closed loop, perturb them, score and film them.

With no flags: trains (or takes from the model cache) a NODE and a contraction field on the spiral
demos, runs both on the Panda unperturbed, from a start 2 cm off the demo's and with a 20 N push,
and writes one MP4 per run, its time series (.npz), figures (.png) and metrics.json into a fresh
folder out/demo_arm_YYYYmmdd-HHMMSS/ (see --help). The job is the library's
(``sim.pipeline.run_job``); its flags are ``sim.cli``'s, also installed as ``lfd-demo-arm``.
"""

from __future__ import annotations

import os
import sys
from typing import Any

EXIT_INTERRUPTED = 130
_PENDING: list[int] = []   # a signal that arrived during the start-up imports


def _defer(signum: int, frame: Any) -> None:
    """During the imports, remember SIGINT / SIGTERM (an interrupt inside an import can surface as
    another error); a second one ends the process at once."""
    if _PENDING:
        print("demo_arm: interrupted", file=sys.stderr)
        os._exit(EXIT_INTERRUPTED)
    _PENDING.append(signum)


if __name__ == "__main__":
    import signal

    for _sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(_sig, _defer)
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    from sim.cli import main

    if _PENDING:
        print("demo_arm: interrupted", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    sys.exit(main())
