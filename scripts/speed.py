#!/usr/bin/env python
"""Speed measurements of the stack, one command: ``python scripts/speed.py NAME [options]``, NAME one
of field, pose, node, ik, loop, obstacles, arm-clearance, render (``sim.speed``; ``--help`` lists them).

    python scripts/speed.py loop --skip-actuation --learner node,contraction --repeats 8
    python scripts/speed.py render --repeats 5
    python scripts/speed.py field --quick            # any of them in seconds, numbers meaningless
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.speed.cli")
