"""Demonstrations: the demo set and its sources (generators, LASA, RoboTasks9, files, bags, specs).

``DemoSet`` (``lfd.demos.demoset``) holds N demos of T samples; ``load_demos(SPEC)`` makes one from
a spec (``lfd.demos.spec``). Files and bags are recordings and pass through the clean-up of
``lfd.demos.recording``, which says what it did in ``DemoSet.notes``.
"""

from lfd.demos.bags import load_bag
from lfd.demos.demoset import (
    GOAL_ANGLE_TOLERANCE,
    GOAL_TOLERANCE,
    MAX_DIM,
    MAX_DURATION,
    MAX_TURN_FROM_GOAL,
    MIN_SAMPLES,
    MIN_TIME_STEP,
    MOTION_TOLERANCE,
    DemoSet,
    check_motion,
    resample,
)
from lfd.demos.files import POSE_HEADER, load_file, save_file
from lfd.demos.generators import spiral, spiral3d
from lfd.demos.lasa_handwriting import LASA_SHAPES, lasa
from lfd.demos.plausibility import demo_warnings
from lfd.demos.recording import recorded_set
from lfd.demos.robottasks9 import ROBOTTASKS, ROBOTTASKS_RATE_HZ, robottasks
from lfd.demos.smoothing import smoothed_velocity
from lfd.demos.spec import load_demos

__all__ = [
    "GOAL_ANGLE_TOLERANCE", "GOAL_TOLERANCE", "LASA_SHAPES", "MAX_DIM", "MAX_DURATION", "MAX_TURN_FROM_GOAL",
    "MIN_SAMPLES", "MIN_TIME_STEP", "MOTION_TOLERANCE", "POSE_HEADER", "ROBOTTASKS", "ROBOTTASKS_RATE_HZ",
    "DemoSet", "check_motion", "demo_warnings", "lasa", "load_bag", "load_demos", "load_file", "recorded_set",
    "resample", "robottasks", "save_file", "smoothed_velocity", "spiral", "spiral3d",
]
