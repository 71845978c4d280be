"""Demo SPECs: the one string that names a demo set, resolved to its source."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from lfd.demos.bags import load_bag
from lfd.demos.demoset import DemoSet
from lfd.demos.files import load_file
from lfd.demos.generators import spiral, spiral3d
from lfd.demos.lasa_handwriting import lasa
from lfd.demos.recording import clean_steps
from lfd.demos.robottasks9 import robottasks
from lfd.errors import DemoError


def load_demos(spec: str, clean: bool | str | Iterable[str] = True) -> DemoSet:
    """Resolve a demo SPEC: ``spiral``, ``spiral3d``, ``lasa:NAME``, ``robottasks:TASK``,
    ``bag:PATH:/topic[:PARENT:CHILD]`` (``lfd.demos.bags``) or a file path (``lfd.demos.files``).
    Bags and files are recordings, cleaned up by the steps ``clean`` names (``lfd.demos.recording``:
    True all, False none, or step names such as "gaps,noise"); the generated and shipped sets are
    taken as they are. An unknown step in ``clean`` is a ConfigError, whatever the spec."""
    clean = clean_steps(clean)
    if spec == "spiral":
        return spiral()
    if spec == "spiral3d":
        return spiral3d()
    if spec.startswith("lasa:"):
        return lasa(spec.split(":", 1)[1])
    if spec.startswith("robottasks:"):
        task = spec.split(":", 1)[1]
        if task == "all":
            raise DemoError("robottasks:all: the nine tasks are nine demo sets with their own goals; "
                            "give one task (robottasks:TASK), or use lfd bench robottasks")
        return robottasks(task)
    if spec.startswith("bag:"):
        return load_bag(spec, clean)
    if spec.endswith((".csv", ".npz", ".CSV", ".NPZ")) or os.path.sep in spec or Path(spec).exists():
        return load_file(spec, clean)
    raise DemoError(f"{spec}: unknown demo spec (use spiral, spiral3d, lasa:NAME, robottasks:TASK, "
                    "bag:FILE:/topic or a .csv/.npz file)")
