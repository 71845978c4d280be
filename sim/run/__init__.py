"""Running one arm job: its options, the experiment, the files it writes and its command line.

- ``sim.run.job``: ``ArmJob``, the options, checked before any work;
- ``sim.run.experiment``: ``Experiment``, one setup run under named scenarios, scored and filmed;
- ``sim.run.plan``: ``plan_job``, the job resolved and checked into one plan (models trained, fields
  wrapped, every run listed) before any run; ``sim.run.pipeline``: ``run_job``, which executes it;
- ``sim.run.obstacle_runs``: ``ObstacleRuns``, the settings of every run among obstacles, in one place;
- ``sim.run.job_files``, ``sim.run.outputs``, ``sim.run.timeseries``: the files of a job, staged and
  moved into place together, and a run's time series;
- ``sim.run.cli``: the ``lfd-demo-arm`` command line; ``sim.run.parsing``: the one-line argument
  errors and option checks of the command lines of ``sim.studies`` and ``sim.speed``.

Above ``sim.media``, ``sim.control`` and ``sim.scene``; below ``sim.studies`` and ``sim.speed``
(pyproject.toml's import contracts).
"""
