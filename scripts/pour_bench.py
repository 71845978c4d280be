#!/usr/bin/env python
"""Success rates of the learned pour over randomized episodes, per learner, with 95% Wilson intervals
-> reports/pour.md (``sim.studies.pour_bench``; resumable: a rerun skips the episodes on file).

    python scripts/pour_bench.py [--episodes 20] [--learners tracking,contraction,node,stable_node]
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.studies.pour_bench")
