"""How a run with obstacles is set up, in one place: the job, the obstacle study, the scaling study and
the arm-clearance speed measurement all take their settings from here.

A run with obstacles differs from a plain one in four settings:

- the field avoids the obstacles grown by the hand's size (``sim.scene.collision.hand_margin_m``) on top
  of each one's own margin (``lfd.avoid``, Eqs. (O1)-(O3)), so the tool's outside, not its point,
  keeps the margin;
- the IK carries the whole-arm collision dampers (``sim.scene.collision.Clearance``, Eqs. (A1)-(A2));
- the servo leads by ``OBSTACLE_LEAD_S`` (``sim.control.controller.Gains.lead_s``);
- the run lasts ``OBSTACLE_TIME_FACTOR`` times the demo's duration (then the settling time): a detour
  takes longer.

``ObstacleRuns(arm_clearance=False)`` keeps only the tool point clear: no hand margin, no dampers.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from lfd.demos import DemoSet
from lfd.field import Field
from lfd.obstacles import Obstacle, avoid
from robots import RobotModel
from sim.control.controller import Gains
from sim.run.experiment import Experiment
from sim.scene.collision import Clearance, hand_margin_m

#: the controller's phase lead with obstacles (``sim.control.controller.Gains.lead_s``), s
OBSTACLE_LEAD_S = 0.01
#: with obstacles a run lasts this many times the demo's duration (then the settling time): the
#: horizon at which the field-level benchmark asks every start to have arrived (``lfd.bench.obstacles``
#: HORIZON; a literal here, since importing ``lfd.bench`` would load torch with the job)
OBSTACLE_TIME_FACTOR = 3.0


def grown(obstacles: Sequence[Obstacle], margin: float) -> list[Obstacle]:
    """The obstacles with ``margin`` (task units) added to each one's own."""
    return [dataclasses.replace(o, margin=o.margin + margin) if margin > 0 else o for o in obstacles]


@dataclass(frozen=True)
class ObstacleRuns:
    """The settings of runs among obstacles (module docstring).

    Parameters
    ----------
    arm_clearance : bool
        The hand margin and the whole-arm dampers (default); False keeps only the tool point clear.
    time_factor : float
        A run's length in demo durations (``OBSTACLE_TIME_FACTOR``).
    lead_s : float
        The servo's phase lead, s (``OBSTACLE_LEAD_S``).
    """

    arm_clearance: bool = True
    time_factor: float = OBSTACLE_TIME_FACTOR
    lead_s: float = OBSTACLE_LEAD_S

    def gains(self) -> Gains:
        """The controller's gains among obstacles."""
        return Gains(lead_s=self.lead_s)

    def clearance(self) -> Clearance | None:
        """The IK's whole-arm dampers, or None without arm clearance."""
        return Clearance() if self.arm_clearance else None

    def hand_margin_m(self, robot: RobotModel) -> float:
        """The margin the field adds to every obstacle, m: the hand's size, 0 without arm clearance."""
        return hand_margin_m(robot) if self.arm_clearance else 0.0

    def avoided(self, obstacles: Sequence[Obstacle], robot: RobotModel, scale: float) -> list[Obstacle]:
        """The obstacles as the field avoids them: grown by ``hand_margin_m`` / ``scale`` (m per task unit)."""
        return grown(obstacles, self.hand_margin_m(robot) / scale)

    def avoiding(self, field: Field, obstacles: Sequence[Obstacle], robot: RobotModel, scale: float) -> Field:
        """``field`` avoiding ``obstacles`` as a run among them does (``lfd.avoid`` of ``avoided``)."""
        return avoid(field, self.avoided(obstacles, robot, scale))

    def experiment(self, robot: RobotModel, demos: DemoSet, obstacles: Sequence[Obstacle],
                   **options: Any) -> Experiment:
        """The ``sim.Experiment`` of ``demos`` on ``robot`` among ``obstacles`` with these settings;
        ``options`` go to ``Experiment`` (``placement``, ``control_hz``, ...)."""
        return Experiment(robot, demos, obstacles=obstacles, gains=self.gains(), clearance=self.clearance(),
                          time_factor=self.time_factor, **options)
