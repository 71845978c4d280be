#!/usr/bin/env python
"""Success rates of the learned tasks with objects over randomized episodes, per learner, with 95%
Wilson intervals -> reports/<task>.md (``sim.studies.task_bench``; parallel on a process pool or Ray;
resumable: a rerun skips the episodes on file).

    python scripts/task_bench.py --task pour --episodes 50
    python scripts/task_bench.py --task place --episodes 50 --learners tracking,stable_node --workers 2
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.studies.task_bench")
