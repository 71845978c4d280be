"""Studies of the arm that write records and reports, each a module with ``main(argv) -> exit code``
run by one thin script in ``scripts/``:

- ``sim.studies.sweep`` (``scripts/sweep_arm.py``): the robustness sweep, robots x learners x seeded
  perturbations on a process pool or Ray, resumable records, heatmap and basin plot
  (``sim.studies.sweep_figures``);
- ``sim.studies.obstacles`` (``scripts/panda_obstacles.py``): seeded obstacle scenes on the Panda,
  every learner, with and without a push -> reports/obstacles_arm.md;
- ``sim.studies.robottasks`` (``scripts/robottasks_arm.py``): the nine RoboTasks9 tasks on the Panda,
  where recorded -> reports/robottasks_arm.md;
- ``sim.studies.scaling`` (``scripts/scaling.py``): the learners' and the control step's scaling
  curves -> reports/scaling.md (the control step's measurement: ``sim.studies.scaling_control``; text
  and figures: ``sim.studies.scaling_report``).

Above ``sim.run`` (a study runs jobs) and below ``sim.speed`` (pyproject.toml's import contracts).

The report commands take ``--quick``: a smoke test that writes its report under ``out/`` (not ``reports/``).
"""
