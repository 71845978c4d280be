"""Subcommands of the ``lfd`` command line, one module each (see ``lfd.cli``).

This file holds the one step several commands share: reading a model with its demos.
"""

from __future__ import annotations

from lfd.demos import DemoSet, load_demos
from lfd.errors import DemoError
from lfd.field import VelocityField


def model_and_demos(model_path: str, spec: str) -> tuple[VelocityField, DemoSet]:
    """Load a model file and a demo SPEC, and check that their dimensions agree."""
    from lfd.learners import load

    field = load(model_path)
    demos = load_demos(spec)
    if demos.dim != field.dim:
        raise DemoError(f"{demos.name}: demos are {demos.dim}-D but the model {model_path} is "
                        f"{field.dim}-D")
    return field, demos
