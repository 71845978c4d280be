#!/usr/bin/env python
"""Whole-arm safety on the Panda: seeded obstacle scenes, every learner, with and without a push ->
reports/obstacles_arm.md (``sim.studies.obstacles``; ``--help`` lists the options).

    python scripts/panda_obstacles.py                    # 50 scenes
    python scripts/panda_obstacles.py --placements 5     # a quick look
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.studies.obstacles")
