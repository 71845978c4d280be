#!/usr/bin/env python
"""Scaling curves of the learners and of the control step -> reports/scaling.md and
reports/figures/scaling_*.png (``sim.studies.scaling``; ``--help`` lists the options).

    python scripts/scaling.py --out reports/scaling.md     # the full run
    python scripts/scaling.py --quick                      # a smoke test (out/scaling-quick/)
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.studies.scaling")
