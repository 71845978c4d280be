#!/usr/bin/env python
"""The arm's robustness sweep: robots x learners x seeded pushes, start offsets and goal shifts, on a
process pool or on Ray, resumable (``sim.studies.sweep``; ``--help`` lists the options).

    python scripts/sweep_arm.py --out out/sweep --workers 2
    python scripts/sweep_arm.py --out out/sweep --executor ray --address 10.0.0.5:6379   # on a cluster
    python scripts/sweep_arm.py --out /tmp/tp --throughput 2     # runs/s with 1 and 2 workers
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.studies.sweep")
