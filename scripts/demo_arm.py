#!/usr/bin/env python
"""Run learned velocity fields on a simulated arm in closed loop, perturb them, score and film them.

With no flags: trains (or takes from the model cache) a NODE and a contraction field on the spiral
demos, runs both on the Panda unperturbed, from a start 2 cm off the demo's and with a 20 N push,
and writes one MP4 per run, its time series (.npz), figures (.png) and metrics.json into a fresh
folder out/demo_arm_YYYYmmdd-HHMMSS/ (see --help). The job is the library's
(``sim.run.pipeline.run_job``); its flags are ``sim.run.cli``'s, also installed as ``lfd-demo-arm``.
"""

if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__, "sim.run.cli")
