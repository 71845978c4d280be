#!/usr/bin/env python
"""The default job and RoboTasks9 at 1 kHz through the arm's controller and its limiter, against
today's 500 Hz runs -> reports/stream.md (``sim.studies.stream``).

    python scripts/stream_limits.py [--report reports/stream.md]
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.studies.stream")
