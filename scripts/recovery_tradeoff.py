#!/usr/bin/env python
"""Every learner on accuracy against recovery from a push on the default job, and the contracting
NODE's trade-off over its rate -> reports/contracting_node.md (``sim.studies.recovery``).

    python scripts/recovery_tradeoff.py [--report reports/contracting_node.md]
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.studies.recovery")
