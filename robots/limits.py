"""A robot's motion limits as data, with their source, and a check of a joint stream against them.

``Limits`` holds, per arm joint, the position, velocity, acceleration and jerk limits, the torque and
torque-rate limits, and the tool's translational and rotational velocity, acceleration and jerk
limits. ``PANDA`` holds the Franka Emika Panda's (FER) published limits, which the robot enforces on
every 1 kHz command (a violation aborts the motion, a "reflex"). ``limits_of(robot)`` gives them for
the Panda and, for any other robot, what its model file states (positions, velocities, efforts) with
the rest assumed unlimited, and names what it assumed.

``Limits.check`` measures a stream sampled at a fixed rate: each derivative by finite differences of
the one below it (velocity from positions unless given, acceleration from velocity, jerk from
acceleration), its peak over the stream as a fraction of its limit (worst joint), and the samples
over the limit. On a real arm the limits bind the command stream; on a simulated run the stream
checked is the arm's measured motion, the closest record of what a command stream would have asked.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from robots.errors import RobotError
from robots.model import ArmModel

#: where ``PANDA``'s numbers come from
FRANKA_SOURCE = ("Franka Control Interface documentation, 'Robot and interface specifications', limits for "
                 "Panda (FER): https://frankaemika.github.io/docs/control_parameters.html")
#: the checked quantities of ``Limits.check``, in the order of its report
JOINT_ORDERS: tuple[str, ...] = ("position", "velocity", "acceleration", "jerk")
TOOL_ORDERS: tuple[str, ...] = ("velocity", "acceleration", "jerk")


def _array(values: Any, n: int, name: str, positive: bool) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    if a.shape != (n,) or np.isnan(a).any() or (positive and not (a > 0).all()):
        raise ValueError(f"{name} must be {n} {'positive ' if positive else ''}numbers, none NaN, got {a.tolist()}")
    return a


@dataclass(frozen=True)
class Limits:
    """Per-joint and tool limits of one arm (module docstring); inf where a limit is not known.

    Attributes
    ----------
    name, source : str
        The robot and where the numbers come from.
    q_min, q_max : ndarray, shape (n,)
        Joint positions, rad.
    dq_max, ddq_max, dddq_max : ndarray, shape (n,)
        Joint velocity, acceleration and jerk, rad/s, rad/s^2, rad/s^3.
    tau_max, dtau_max : ndarray, shape (n,)
        Joint torque and torque rate, Nm and Nm/s.
    tool_translation, tool_rotation : tuple of 3 floats
        The tool's velocity, acceleration and jerk: m/s, m/s^2, m/s^3 and rad/s, rad/s^2, rad/s^3.
    assumed : tuple of str
        The limits not stated by the source, taken as unlimited (inf).
    """

    name: str
    source: str
    q_min: np.ndarray
    q_max: np.ndarray
    dq_max: np.ndarray
    ddq_max: np.ndarray
    dddq_max: np.ndarray
    tau_max: np.ndarray
    dtau_max: np.ndarray
    tool_translation: tuple[float, float, float]
    tool_rotation: tuple[float, float, float]
    assumed: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        n = len(self.q_min)
        for name in ("q_min", "q_max", "dq_max", "ddq_max", "dddq_max", "tau_max", "dtau_max"):
            object.__setattr__(self, name, _array(getattr(self, name), n, name, name not in ("q_min", "q_max")))
        if not (self.q_min < self.q_max).all():
            raise ValueError(f"{self.name}: every q_min must lie below its q_max")
        for name in ("tool_translation", "tool_rotation"):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != 3 or not all(v > 0 for v in values):   # NaN fails too
                raise ValueError(f"{self.name}: {name} must be 3 positive numbers, got {list(values)}")
            object.__setattr__(self, name, values)

    @property
    def n(self) -> int:
        """Number of arm joints."""
        return len(self.q_min)

    def check(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray | None = None,
              tool: np.ndarray | None = None, tool_rotation: np.ndarray | None = None) -> dict[str, Any]:
        """Peaks and violations of a stream sampled at the fixed step of ``t``.

        Parameters
        ----------
        t : ndarray, shape (K,)
            Sample times, s, evenly spaced (K >= 4).
        q : ndarray, shape (K, n)
            Joint positions, rad.
        dq : ndarray, shape (K, n), optional
            Joint velocities, rad/s (default: the differences of q).
        tool : ndarray, shape (K, 3), optional
            Tool positions, m: its velocity, acceleration and jerk by differences.
        tool_rotation : ndarray, shape (K, 3, 3), optional
            Tool orientations, world: the angular velocity of each step, log(R_{k+1} R_k^T) / dt, and
            its differences.

        Returns
        -------
        dict
            ``joint``: for each of ``JOINT_ORDERS`` the peak fraction of its limit (the worst joint; a
            position's fraction of the half range from the range's centre, so 1 is at a limit), the
            joint it peaks on and the samples over the limit; ``tool`` and ``tool_rotation`` the same
            for ``TOOL_ORDERS``; ``violations``: all samples over a limit; ``assumed``: ``assumed``.
        """
        t = np.asarray(t, dtype=np.float64)
        q = np.asarray(q, dtype=np.float64)
        if t.ndim != 1 or len(t) < 4 or q.shape != (len(t), self.n):
            raise ValueError(f"check needs K >= 4 times and q of shape (K, {self.n}), got {t.shape} and {q.shape}")
        dt = float(np.median(np.diff(t)))
        if not dt > 0:
            raise ValueError("the sample times must increase")
        v = np.diff(q, axis=0) / dt if dq is None else np.asarray(dq, dtype=np.float64)
        a = np.diff(v, axis=0) / dt
        j = np.diff(a, axis=0) / dt
        centre, half = (self.q_max + self.q_min) / 2, (self.q_max - self.q_min) / 2
        joint = {order: _peak(np.abs(x) / limit)
                 for order, x, limit in (("position", q - centre, half), ("velocity", v, self.dq_max),
                                         ("acceleration", a, self.ddq_max), ("jerk", j, self.dddq_max))}
        out: dict[str, Any] = {"joint": joint, "rate_hz": 1.0 / dt, "assumed": list(self.assumed)}
        if tool is not None:
            out["tool"] = _tool(np.diff(np.asarray(tool, dtype=np.float64), axis=0) / dt, dt, self.tool_translation)
        if tool_rotation is not None:
            rot = Rotation.from_matrix(np.asarray(tool_rotation, dtype=np.float64))
            out["tool_rotation"] = _tool((rot[1:] * rot[:-1].inv()).as_rotvec() / dt, dt, self.tool_rotation)
        out["violations"] = sum(g["over"] for part in ("joint", "tool", "tool_rotation")
                                for g in out.get(part, {}).values())
        return out


def worst(report: dict[str, Any]) -> tuple[str, float]:
    """The quantity of a ``Limits.check`` report that came nearest its limit or went furthest over it
    ("joint acceleration", "tool_rotation jerk", ...), and its peak fraction."""
    peaks = [(f"{part} {order}", float(g["peak"])) for part in ("joint", "tool", "tool_rotation")
             for order, g in report.get(part, {}).items()]
    return max(peaks, key=lambda p: p[1])


def _tool(velocity: np.ndarray, dt: float, limits: tuple[float, float, float]) -> dict[str, dict[str, Any]]:
    """``_peak`` of the norms of a tool velocity (K-1, 3) and of its first and second differences / dt."""
    norms = (np.linalg.norm(velocity, axis=1), np.linalg.norm(np.diff(velocity, axis=0), axis=1) / dt,
             np.linalg.norm(np.diff(velocity, n=2, axis=0), axis=1) / dt ** 2)
    return {order: _peak((x / limit)[:, None]) for order, x, limit in zip(TOOL_ORDERS, norms, limits)}


def _peak(fraction: np.ndarray) -> dict[str, Any]:
    """The peak of ``fraction`` (samples, columns), its column, and the samples with any column over 1."""
    finite = np.where(np.isfinite(fraction), fraction, 0.0)
    k, col = np.unravel_index(int(np.argmax(finite)), finite.shape) if finite.size else (0, 0)
    peak = float(finite[k, col]) if finite.size else 0.0
    return {"peak": peak, "joint": int(col), "over": int(np.count_nonzero((finite > 1.0).any(axis=1)))}


#: the Franka Emika Panda (FER), joints 1-7 (``FRANKA_SOURCE``)
PANDA = Limits(
    name="panda", source=FRANKA_SOURCE,
    q_min=np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]),
    q_max=np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]),
    dq_max=np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61]),
    ddq_max=np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0]),
    dddq_max=np.array([7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0]),
    tau_max=np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0]),
    dtau_max=np.full(7, 1000.0),
    tool_translation=(1.7, 13.0, 6500.0), tool_rotation=(2.5, 25.0, 12500.0))


#: the Franka Research 3 (FR3), joints 1-7: the same documentation's limits for FR3. Its joint
#: velocity limits here are the largest the FR3 allows; the FCI lowers them near the position limits
#: (libfranka's ``computeUpperLimitsJointVelocity``), which a stream must respect there as well.
FR3 = Limits(
    name="fr3", source=FRANKA_SOURCE.replace("Panda (FER)", "Franka Research 3 (FR3)"),
    q_min=np.array([-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159]),
    q_max=np.array([2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159]),
    dq_max=np.array([2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26]),
    ddq_max=np.full(7, 10.0),
    dddq_max=np.full(7, 5000.0),
    tau_max=np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0]),
    dtau_max=np.full(7, 1000.0),
    tool_translation=(3.0, 9.0, 4500.0), tool_rotation=(2.5, 17.0, 8500.0))


def load_limits(path: str | Path) -> Limits:
    """An arm's limits from a JSON file: an object with ``name``, ``source`` and any of the per-joint
    arrays of ``Limits`` (``q_min``, ``q_max``, ``dq_max``, ``ddq_max``, ``dddq_max``, ``tau_max``,
    ``dtau_max``; ``q_min`` and ``q_max`` are required and set n) and the tool's 3-vectors
    (``tool_translation``, ``tool_rotation``). A limit left out is unlimited (inf) and named in
    ``assumed``.

    Raises
    ------
    RobotError
        A missing or unreadable file, a value that is not a number, NaN, a wrong length, or a limit
        that is not positive (one line).
    """
    p = Path(path)
    try:
        raw = json.loads(p.read_text())
    except FileNotFoundError:
        raise RobotError(f"limits file not found: {p}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RobotError(f"cannot read the limits file {p}: {exc}") from None
    if not isinstance(raw, dict) or "q_min" not in raw or "q_max" not in raw:
        raise RobotError(f"the limits file {p} must hold an object with at least q_min and q_max")
    known = {f.name for f in dataclasses.fields(Limits)} - {"assumed"}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise RobotError(f"the limits file {p} has unknown key(s) {', '.join(unknown)}; "
                         f"known: {', '.join(sorted(known))}")
    try:
        n = len(raw["q_min"])
        inf = [math.inf] * n
        assumed = [key for key in ("dq_max", "ddq_max", "dddq_max", "tau_max", "dtau_max", "tool_translation",
                                   "tool_rotation") if key not in raw]
        fields = {key: raw.get(key, inf) for key in ("dq_max", "ddq_max", "dddq_max", "tau_max", "dtau_max")}
        return Limits(name=str(raw.get("name", p.stem)), source=str(raw.get("source", f"the file {p.name}")),
                      q_min=np.asarray(raw["q_min"], dtype=np.float64),
                      q_max=np.asarray(raw["q_max"], dtype=np.float64),
                      tool_translation=tuple(raw.get("tool_translation", [math.inf] * 3)),
                      tool_rotation=tuple(raw.get("tool_rotation", [math.inf] * 3)), assumed=tuple(assumed),
                      **{k: np.asarray(v, dtype=np.float64) for k, v in fields.items()})
    except (TypeError, ValueError) as exc:
        raise RobotError(f"the limits file {p}: {str(exc).splitlines()[0]}") from None


def limits_of(robot: ArmModel) -> Limits:
    """The limits of ``robot``: ``PANDA`` for the Panda, ``FR3`` for an arm named ``fr3``; for any
    other robot its model's joint positions and velocities (``robot.q_min``, ``q_max``, ``v_max``)
    and efforts (the Pinocchio model's, where stated), every other limit assumed unlimited and named in ``assumed``."""
    if robot.name == "panda" and robot.n == PANDA.n:
        return PANDA
    if robot.name == "fr3" and robot.n == FR3.n:
        return FR3
    n = robot.n
    effort = np.asarray(robot.pin_model.effortLimit, dtype=np.float64)[:n] if robot.pin_model.nv >= n \
        else np.full(n, np.inf)
    effort = np.where((effort > 0) & (effort < 1e6), effort, np.inf)
    assumed = ["joint acceleration", "joint jerk", "torque rate", "tool translation", "tool rotation"]
    if np.isinf(effort).any():
        assumed.insert(2, "torque")
    inf = np.full(n, math.inf)
    return Limits(name=robot.name, source=f"the model file of '{robot.name}' (positions, velocities, efforts)",
                  q_min=robot.q_min, q_max=robot.q_max, dq_max=robot.v_max, ddq_max=inf, dddq_max=inf,
                  tau_max=effort, dtau_max=inf, tool_translation=(math.inf,) * 3,
                  tool_rotation=(math.inf,) * 3, assumed=tuple(assumed))
