"""Subcommands of the ``lfd`` command line, one module each (see ``lfd.cli``).

This file holds what several commands share: their model and demo arguments, and reading a
model with its demos.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

from lfd.errors import DemoError
from lfd.interrupts import say

if TYPE_CHECKING:  # imported when a command runs, so that ``lfd --help`` stays fast
    import argparse

    from lfd.demos import DemoSet
    from lfd.field import VelocityField
    from lfd.pose import PoseChart

MODEL_HELP = "model file written by 'lfd train'"
DEMOS_HELP = ("spiral, spiral3d, lasa:NAME, robottasks:TASK, bag:PATH:/topic[:PARENT:CHILD] "
              "or a .csv/.npz file")


def add_model_and_demos(p: argparse.ArgumentParser) -> None:
    """The arguments of a command that reads a model with its demos (``model_and_demos``): the
    model file, positional, ``--demos SPEC``, required, and the clean-up's ``--clean``/``--no-clean``."""
    p.add_argument("model", help=MODEL_HELP)
    p.add_argument("--demos", required=True, metavar="SPEC", help=DEMOS_HELP)
    add_clean(p)


def clean_steps(text: str) -> frozenset[str]:
    """argparse type of ``--clean``: ``all``, ``none`` or comma-separated steps of
    ``lfd.demos.recording.CLEAN_STEPS`` (read without importing numpy)."""
    import argparse

    steps = tuple(source_constant("lfd.demos.recording", "CLEAN_STEPS"))
    words = [w.strip() for w in text.split(",")]
    if words in (["all"], ["none"]):
        return frozenset(steps) if words == ["all"] else frozenset()
    unknown = [w for w in words if w not in steps]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown clean-up step '{unknown[0][:40]}'; give all, none or steps "
                                         f"from {','.join(steps)}")
    return frozenset(words)


def add_clean(p: argparse.ArgumentParser) -> None:
    """``--clean STEPS`` and ``--no-clean`` (one of them), the clean-up steps run on the recordings of
    ``--demos`` (``demo_clean`` gives the ``clean`` argument of ``lfd.load_demos``)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--clean", type=clean_steps, metavar="STEPS",
                   help="the clean-up steps run on a recording (a file or a bag; docs/recordings.md): all "
                        "(default), none, or some of gaps,noise,still,pauses, e.g. --clean gaps,noise")
    g.add_argument("--no-clean", dest="clean", action="store_const", const=frozenset(),
                   help="read a recording as it is, with no clean-up (same as --clean none)")


def demo_clean(args: argparse.Namespace) -> bool | frozenset[str]:
    """The ``clean`` argument of ``lfd.load_demos`` that ``--clean``/``--no-clean`` ask for (True: all steps)."""
    clean = getattr(args, "clean", None)
    return True if clean is None else frozenset(clean)


GOAL_HELP = ("run the model toward this goal instead of its demos' mean end (the field's toward): task "
             "coordinates, or a pose's x,y,z[,qw,qx,qy,qz]; write --goal=-1,2 when it starts with a minus")


def goal_vector(text: str) -> tuple[float, ...]:
    """argparse type of ``--goal``: comma-separated finite numbers (the field checks their count)."""
    import argparse
    import math

    try:
        v = tuple(float(s) for s in text.split(","))
    except ValueError:
        v = ()
    if not v or not all(math.isfinite(c) for c in v):
        raise argparse.ArgumentTypeError(f"expected finite numbers X,Y[,Z] or X,Y,Z,QW,QX,QY,QZ, got '{text[:60]}'")
    return v


def add_goal(p: argparse.ArgumentParser) -> None:
    """The ``--goal`` option of a command that runs a model (``model_and_demos``' ``goal``)."""
    p.add_argument("--goal", type=goal_vector, metavar="X,Y[,Z[,QW,QX,QY,QZ]]", help=GOAL_HELP)


def model_and_demos(model_path: str, spec: str, allow_nonfinite: bool = False,
                    goal: tuple[float, ...] | None = None,
                    clean: bool | frozenset[str] = True) -> tuple[VelocityField, DemoSet]:
    """Load a model file and a demo SPEC (a recording cleaned up by the steps ``clean`` names,
    ``lfd.load_demos``), and check that their dimensions agree. Demos of poses for a
    pose model come back as the model's chart points (``lfd.pose.chart_demos``, shape (N, T, 6): metres,
    and metres per ``ROTATION_LENGTH`` of turn), which is what the model's field maps. With ``goal``
    the field is the model's run toward it (``VelocityField.toward``; a pose's chart moved to the
    goal's orientation, in which the demos are then given); a goal of the wrong size is a ConfigError."""
    import numpy as np

    from lfd.demos import load_demos
    from lfd.field import StateSpace
    from lfd.learners import load
    from lfd.pose import chart_demos

    field = load(model_path, allow_nonfinite)
    if goal is not None:
        field = field.toward(np.asarray(goal, dtype=np.float64))
    demos = load_demos(spec, clean=clean)
    say_notes(demos)
    poses = field.space is StateSpace.POSE
    if poses != demos.has_orientation:
        raise DemoError(f"{demos.name}: the model {model_path} is trained on {'poses' if poses else 'positions'}, "
                        f"the demos are {'poses' if demos.has_orientation else 'positions'}")
    if poses:
        demos = chart_demos(demos, cast("PoseChart", field.chart))
    if demos.dim != field.dim:
        raise DemoError(f"{demos.name}: demos are {demos.dim}-D but the model {model_path} is "
                        f"{field.dim}-D")
    return field, demos


def say_notes(demos: DemoSet, quiet: bool = False) -> None:
    """Each line of ``demos.notes`` (what the clean-up of a recording did) on stderr, ``lfd: note: ...``;
    ``quiet``: only those of a step that removed, filled or moved more than ``LOUD_SHARE`` of a demo's
    duration (``lfd.demos.recording.loud_note``)."""
    from lfd.demos.recording import loud_note

    for note in demos.notes:
        if not quiet or loud_note(note):
            say(f"lfd: note: {note}")


def seed(text: str) -> int:
    """argparse type of ``--seed``: an integer in [0, ``lfd.learners.MAX_SEED``] = [0, 2^63 - 1]."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got '{text[:40]}'") from None
    if not 0 <= value <= source_constant("lfd.learners", "MAX_SEED"):  # read without importing torch
        raise argparse.ArgumentTypeError(f"must be between 0 and 2^63 - 1, got {text[:40]}")
    return value


def source_constant(module: str, name: str) -> Any:
    """The literal value of ``name = <literal>`` in ``module``'s source, read without importing it
    (so that ``lfd --help`` does not import torch through a module that defines a default)."""
    import ast
    import importlib
    from pathlib import Path

    # find_spec("a.b.c") would import the packages a and a.b: locate the file from the top package
    top, *rest = module.split(".")
    base = Path(importlib.import_module(top).__file__ or "").parent.joinpath(*rest)
    origin = base / "__init__.py" if base.is_dir() else base.with_suffix(".py")
    if origin.is_file():
        with open(origin, encoding="utf-8") as f:
            tree = ast.parse(f.read())
        for node in tree.body:
            target = node.target if isinstance(node, ast.AnnAssign) else (
                node.targets[0] if isinstance(node, ast.Assign) and len(node.targets) == 1 else None)
            if (isinstance(target, ast.Name) and target.id == name
                    and isinstance(node, (ast.AnnAssign, ast.Assign)) and node.value is not None):
                try:
                    return ast.literal_eval(node.value)
                except ValueError:
                    break
    return getattr(importlib.import_module(module), name)  # not a literal: import after all


def check_output(path: str, what: str, inputs: dict[str, str | None] | None = None) -> None:
    """Before any long work: refuse an output ``path`` that names one of ``inputs`` ({what: path})
    or cannot be written (``OutputError``, exit 2)."""
    from lfd.errors import OutputError
    from lfd.io import check_writable, same_file

    for name, other in (inputs or {}).items():
        if other and same_file(path, other):
            raise OutputError(f"{path}: {what} would overwrite the {name}; choose another path")
    check_writable(path, what)
