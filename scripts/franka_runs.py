#!/usr/bin/env python
"""The default spiral and a RoboTasks9 pour through libfranka against franka-sim's FR3, with the FCI's
limits enforced, against our own simulation -> reports/franka.md (``sim.studies.franka``).

    python scripts/franka_runs.py [--report reports/franka.md]
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.studies.franka")
