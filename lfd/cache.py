"""A cache of trained fields for the scripts and the arm simulation (``scripts/demo_arm.py``,
``scripts/sweep_arm.py``, the benchmarks): train once per (learner, demos, seed, options).

The file is ``<cache_dir>/<learner>-<key>.pt`` with key the first 16 hex digits of
sha256(JSON of learner, seed, the learner's full config (its defaults filled in, as
``lfd.learners.effective_options`` gives them), the fingerprint of the learner's code
(``lfd.fingerprint``: its module and every lfd module it imports) and the sha256 of the demos' t and
x arrays, and q for poses), so a change to any of them, a changed default or an edit of the
learner's code included, trains a new model. Files are written
atomically by ``VelocityField.save``; a cached file that cannot be read (corrupt, a failed checksum,
an old format) is trained again and replaced. An interrupted training is never stored: Ctrl-C
(or SIGTERM, where the caller turns it into KeyboardInterrupt) propagates as KeyboardInterrupt.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

import lfd
from lfd import DemoSet, ModelError, VelocityField

DEFAULT_CACHE_DIR = Path(".cache") / "models"


def cache_dir() -> Path:
    """``$LFD_CACHE_DIR`` if set, else ``.cache/models`` under the working directory."""
    return Path(os.environ.get("LFD_CACHE_DIR") or DEFAULT_CACHE_DIR)


def cache_key(learner: str, demos: DemoSet, seed: int, options: dict[str, Any]) -> str:
    """16 hex digits identifying a training run (see module docstring)."""
    data = hashlib.sha256()
    data.update(np.ascontiguousarray(demos.t, dtype=np.float64).tobytes())
    data.update(np.ascontiguousarray(demos.x, dtype=np.float64).tobytes())
    if demos.q is not None:   # and the chart the pose field is learned in (its goal orientation)
        data.update(np.ascontiguousarray(demos.q, dtype=np.float64).tobytes())
        data.update(np.ascontiguousarray(demos.goal_q, dtype=np.float64).tobytes())
    from lfd.fingerprint import code_fingerprint
    from lfd.learners import effective_options, learner_module

    config = dataclasses.asdict(lfd.get_learner(learner).make_config(**effective_options(learner, demos, options)))
    spec = {"learner": learner, "seed": int(seed), "config": config, "demos": data.hexdigest(),
            "code": code_fingerprint(learner_module(learner))}
    text = json.dumps(spec, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def cached_field(learner: str, demos: DemoSet, seed: int = 0, options: dict[str, Any] | None = None,
                 directory: str | os.PathLike | None = None,
                 progress: bool = False, verbose: bool = True) -> tuple[VelocityField, Path, bool]:
    """The field of ``lfd.train(learner, demos, seed, **options)``, from the cache when present.

    Parameters
    ----------
    learner : str
        A learner name (``lfd.LEARNERS``).
    demos : DemoSet
        The demonstrations, t (N, T) and x (N, T, d).
    seed : int
    options : dict, optional
        The learner's keyword options.
    directory : path, optional
        The cache folder (default ``cache_dir()``).
    progress : bool
        A training progress bar.
    verbose : bool
        Say on stderr when a cached file is unreadable and trained again.

    Returns
    -------
    (VelocityField, Path, bool)
        The field, its model file, and whether it was trained now.

    Raises
    ------
    KeyboardInterrupt
        Storing nothing, when the training was interrupted (the learner returned a partly trained field).
    """
    options = dict(options or {})
    path = Path(directory or cache_dir()) / f"{learner}-{cache_key(learner, demos, seed, options)}.pt"
    if path.is_file():
        try:
            return lfd.load(str(path)), path, False
        except (ModelError, OSError) as e:
            if verbose:
                print(f"cache: {str(e).splitlines()[0] if str(e) else type(e).__name__}; training again",
                      file=sys.stderr)
    field = lfd.train(learner, demos, seed=seed, progress=progress, **options)
    if field.history.get("interrupted"):
        raise KeyboardInterrupt  # a partly trained model must never enter the cache
    field.save(path)
    return field, path, True
