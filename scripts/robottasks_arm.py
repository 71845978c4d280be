#!/usr/bin/env python
"""All nine RoboTasks9 tasks on the Panda, where recorded, with the tracking learner ->
reports/robottasks_arm.md (``sim.studies.robottasks``; ``--help`` lists the options).

    python scripts/robottasks_arm.py [--out out/robottasks_arm] [--report reports/robottasks_arm.md]
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.studies.robottasks")
