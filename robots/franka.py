"""robots.franka: a simulated Franka FR3 driven through libfranka's own protocol, as a real arm is.

The server is franka-sim, a MuJoCo FR3 that speaks the FCI's network protocol; with its motion limits
enforced it aborts a motion that breaks the FCI's limits with the reflex the robot would raise. It pins
its own numpy and MuJoCo, so it runs from its own environment, ``.venv-franka`` at the repository root,
in a child process (``scripts/setup_franka.sh`` makes the environment and its physics model,
``.venv-franka/fr3.xml``). The client is pylibfranka, libfranka's official binding, in this process, so
a controller (Pinocchio, torch) runs inside libfranka's 1 kHz loop.

- ``FrankaSimServer`` (``robots.franka_server``): a context manager that starts the server on a
  loopback address of its own, waits until it serves, and stops it on exit;
- ``stream_joint_velocities``: one joint-velocity motion, ``controller(q, dq, t) -> dq_cmd`` every
  cycle, recorded in a ``FrankaRecord``; a reflex is returned in the record, not raised;
- ``move_to``: a minimum-jerk joint move to a start configuration, within the FR3's limits;
- ``franka_urdf``: the URDF the server serves and its physics model is made from, for Pinocchio: its
  joints are ``JOINT_NAMES``, and the state's ``O_T_EE`` is its frame ``TOOL_FRAME``.

libfranka connects to the fixed port ``COMMAND_PORT``, so servers are told apart by address: each takes
its own 127.x.y.z. This module imports neither MuJoCo nor franka-sim; pylibfranka is imported when a
motion is made.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from robots.franka_server import (
    COMMAND_PORT,
    DEFAULT_ENV,
    FrankaSimError,
    FrankaSimServer,
    franka_env,
    franka_urdf,
    free_loopback_host,
)

__all__ = ["A_MAX", "COMMAND_PORT", "DECELERATION", "DEFAULT_ENV", "DELTA_T", "HOME_Q", "J_MAX", "JOINT_NAMES",
           "LEAD_CYCLES", "Q_LIMITS", "SIM_STEP_S", "TOOL_FRAME", "V_MAX", "V_OFFSET", "Controller", "FrankaRecord",
           "FrankaSimError", "FrankaSimServer", "Reference", "franka_env", "franka_urdf", "free_loopback_host",
           "min_jerk_plan", "move_to", "stream_joint_velocities"]

#: the arm joints of ``franka_urdf()`` in libfranka's order (``q[0]`` is ``joint1``)
JOINT_NAMES: tuple[str, ...] = tuple(f"joint{i}" for i in range(1, 8))
#: the frame of ``franka_urdf()`` that the server's ``O_T_EE`` is (its ``F_T_EE`` is the identity):
#: ``link7``'s frame, which the flange ``link8`` sits 0.107 m along z from
TOOL_FRAME = "link7"
#: franka-sim's initial configuration, rad
HOME_Q = np.array([0.0, 0.0, 0.0, -1.57, 0.0, 1.57, 0.785])
#: joint position limits (rad) of ``franka_urdf()``, (7, 2): the ones franka-sim enforces
Q_LIMITS = np.array([[-2.7501, 2.7501], [-1.7918, 1.7918], [-2.9065, 2.9065], [-3.0481, -0.1458],
                     [-2.8101, 2.8101], [0.54092, 4.5205], [-3.0196, 3.0196]])
#: the FR3's position-based velocity envelope per joint, from ``franka_urdf()``: the velocity cap
#: (rad/s), its offset (rad/s) and the deceleration it allows towards a limit (rad/s^2)
V_MAX = np.array([2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26])
V_OFFSET = np.array([0.30, 0.20, 0.20, 0.30, 0.35, 0.35, 0.35])
DECELERATION = np.array([6.0, 2.585, 3.5, 4.0, 17.0, 5.5, 17.0])
#: libfranka's limits of a commanded joint motion: acceleration (rad/s^2) and jerk (rad/s^3), per joint
A_MAX = 10.0
J_MAX = 5000.0
#: franka-sim's physics step, s
SIM_STEP_S = 0.001
#: libfranka's control period, s
DELTA_T = 0.001
#: cycles at rest that start every motion of ``stream_joint_velocities``: the FCI extrapolates a missed
#: command from the last real ones, and has none before the first
LEAD_CYCLES = 3
#: a controller: the joint-velocity command (7,) from the measured q (7,), dq (7,) and the time t (s)
Controller = Callable[[np.ndarray, np.ndarray, float], np.ndarray]
#: a joint reference: its positions (7,) and velocities (7,) at the time t (s)
Reference = Callable[[float], "tuple[np.ndarray, np.ndarray]"]

@dataclass(frozen=True)
class FrankaRecord:
    """One streamed motion, a row per 1 kHz cycle.

    Attributes
    ----------
    t : np.ndarray
        (n,) time of each cycle's state since the motion's first, s: libfranka's clock, which counts the
        robot's states (one per millisecond on the robot; franka-sim numbers its states the same way, but
        its physics keeps wall-clock time, so where the host cannot publish every state in time the arm
        moves further per unit of ``t`` than a real one would; compare ``t_wall``).
    t_wall : np.ndarray
        (n,) wall-clock time of each cycle since the connection was opened, s.
    q, dq : np.ndarray
        (n, 7) measured joint positions (rad) and velocities (rad/s).
    dq_cmd : np.ndarray
        (n, 7) the joint-velocity command sent in the cycle.
    position, rotation : np.ndarray
        (n, 3) and (n, 3, 3): the measured tool pose ``O_T_EE`` (frame ``TOOL_FRAME``) in the base frame.
        franka-sim publishes the pose of one physics step before ``q`` (the body poses MuJoCo computed
        before its last integration): it is the tool frame at ``q - dq * SIM_STEP_S``, exactly.
    braking : np.ndarray
        (n,) bool: the cycle belongs to the stop after ``duration_s``, not to the controller.
    error : str or None
        libfranka's message when the motion was aborted (a reflex: its names are ``reflexes``), else None.
    cycles : int
        Cycles streamed (``len(t)``).
    wall_s : float
        Wall-clock time from the connection to the end of the motion, s.
    t_control : np.ndarray
        (n,) the time the controller was called with, s (NaN in the lead at rest and the braking).
    """

    t: np.ndarray
    t_wall: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    dq_cmd: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    braking: np.ndarray
    error: str | None
    cycles: int
    wall_s: float
    t_control: np.ndarray

    @property
    def reflexes(self) -> tuple[str, ...]:
        """The reflex names in ``error`` (e.g. ``joint_motion_generator_acceleration_discontinuity``)."""
        return tuple(re.findall(r'"([a-z0-9_]+)"', self.error or ""))


def _pylibfranka() -> Any:
    try:
        import pylibfranka
    except ImportError as error:
        raise FrankaSimError(f"pylibfranka is not installed ({error}): run scripts/setup_franka.sh") from error
    return pylibfranka


def _connect(fr: Any, host: str, realtime: bool) -> Any:
    mode = fr.RealtimeConfig.kEnforce if realtime else fr.RealtimeConfig.kIgnore
    return fr.Robot(host, mode)


def _pose(o_t_ee: Any) -> np.ndarray:
    """libfranka's column-major 16-vector as a 4x4."""
    return np.asarray(o_t_ee, dtype=float).reshape(4, 4, order="F")


class _Brake:
    """The stop after a controller's last command v0 (with acceleration a0): a cubic in velocity from
    (v0, a0) to (0, 0), long enough to stay within half of libfranka's acceleration and jerk limits."""

    def __init__(self, t0: float, v0: np.ndarray, a0: np.ndarray) -> None:
        a_lim, j_lim = 0.5 * A_MAX, 0.5 * J_MAX
        v, a = float(np.max(np.abs(v0))), float(np.max(np.abs(a0)))
        self.t0, self.v0, self.a0 = t0, v0, a0
        self.T = 0.0 if v < 1e-6 and a < 1e-3 else max(
            0.01, 3.0 * v / a_lim, 2.0 * a / a_lim, math.sqrt(12.0 * v / j_lim), 8.0 * a / j_lim)

    def done(self, t: float) -> bool:
        return t - self.t0 >= self.T - 1e-9

    def __call__(self, t: float) -> np.ndarray:
        if self.done(t):
            return np.zeros(7)
        s = (t - self.t0) / self.T
        return (2 * s**3 - 3 * s**2 + 1) * self.v0 + (s**3 - 2 * s**2 + s) * self.T * self.a0


def _command(out: Any) -> np.ndarray:
    cmd = np.asarray(out, dtype=float)
    if cmd.shape != (7,) or not np.all(np.isfinite(cmd)):
        raise ValueError(f"the controller must return 7 finite joint velocities, got {cmd!r}")
    return cmd


def _stream(fr: Any, robot: Any, controller: Controller, duration_s: float, wall0: float,
            wall_clock: bool = False) -> FrankaRecord:
    """The control loop on a connected robot (see ``stream_joint_velocities``)."""
    rows: list[tuple[float, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]] = []
    times: dict[int, float] = {}   # row -> the time the controller was called with
    error: str | None = None
    try:
        control = robot.start_joint_velocity_control(fr.ControllerMode.JointImpedance)
        t, t0, w0, brake = 0.0, 0.0, 0.0, None
        last = np.zeros(7)
        accel = np.zeros(7)
        while True:
            state, period = control.readOnce()
            dt = period.to_sec()
            t += dt
            q, dq = np.array(state.q), np.array(state.dq)
            if len(rows) < LEAD_CYCLES:   # at rest first: the FCI has a history of real commands
                cmd = np.zeros(7)
                t0, w0 = t, time.perf_counter()
            elif brake is None and t - t0 < duration_s - 1e-9:
                tc = time.perf_counter() - w0 if wall_clock else t - t0 - DELTA_T
                cmd = _command(controller(q, dq, tc))
                times[len(rows)] = tc
                if dt > 0 and rows:
                    accel = (cmd - last) / dt
            else:
                brake = brake or _Brake(t, last, accel)
                cmd = brake(t)
            finished = brake is not None and brake.done(t)
            rows.append((t, time.perf_counter() - wall0, q, dq, cmd, _pose(state.O_T_EE), brake is not None))
            last = cmd
            command = fr.JointVelocities(cmd.tolist())
            command.motion_finished = finished
            control.writeOnce(command)
            if finished:
                break
    except fr.ControlException as exc:
        error = " ".join(str(exc).split())
        with contextlib.suppress(Exception):   # leave the robot ready for the next motion, as on hardware
            robot.automatic_error_recovery()
    except BaseException:
        with contextlib.suppress(Exception):   # the controller's failure is the one to report
            robot.stop()
        raise
    wall = time.perf_counter() - wall0
    n = len(rows)
    poses = np.array([r[5] for r in rows]).reshape(n, 4, 4)
    return FrankaRecord(
        t=np.array([r[0] for r in rows], dtype=float), t_wall=np.array([r[1] for r in rows], dtype=float),
        q=np.array([r[2] for r in rows]).reshape(n, 7), dq=np.array([r[3] for r in rows]).reshape(n, 7),
        dq_cmd=np.array([r[4] for r in rows]).reshape(n, 7), position=poses[:, :3, 3].copy(),
        rotation=poses[:, :3, :3].copy(), braking=np.array([r[6] for r in rows], dtype=bool), error=error,
        cycles=n, wall_s=wall, t_control=np.array([times.get(i, np.nan) for i in range(n)]))


def stream_joint_velocities(host: str, controller: Controller, duration_s: float, *,
                            realtime: bool = False, wall_clock: bool = False) -> FrankaRecord:
    """Run ``controller`` in libfranka's joint-velocity control loop for ``duration_s`` and record it.

    Connects to the robot (or franka-sim) at ``host`` with pylibfranka and starts a joint-velocity motion
    (joint impedance). Its first ``LEAD_CYCLES`` cycles command rest; then every cycle, at the state's
    time t (0 at the controller's first cycle, then libfranka's clock: a missed state advances it by more
    than a millisecond), it calls ``controller(q, dq, t)`` with the measured joint positions and
    velocities and sends the returned command unchanged: the FCI judges it, as on the robot. From the first cycle with
    ``t >= duration_s`` the controller is no longer called: the last command is brought to rest within
    half of libfranka's acceleration and jerk limits (``FrankaRecord.braking``) and the motion is finished
    (``motion_finished``). A controller that ends at rest finishes at once.

    Parameters
    ----------
    host : str
        The robot's or the server's address (``FrankaSimServer.host``).
    controller : Controller
        ``controller(q, dq, t) -> dq_cmd``, arrays of shape (7,), t in s.
    duration_s : float
        How long the controller drives the arm, s.
    realtime : bool
        libfranka's ``RealtimeConfig.kEnforce`` (a real-time kernel) instead of ``kIgnore``.
    wall_clock : bool
        Give the controller the wall-clock time since its first cycle, not libfranka's clock: the same
        on a robot; franka-sim's physics keeps the wall clock while its states fall behind (``FrankaRecord.t``).

    Returns
    -------
    FrankaRecord
        The cycles streamed; a motion aborted by the robot (a reflex) has ``error`` set, and the robot is
        recovered (``automatic_error_recovery``) for the next motion.

    Raises
    ------
    FrankaSimError
        When pylibfranka is missing.
    ValueError
        When the controller returns anything but 7 finite numbers (the motion is stopped first).
    """
    fr = _pylibfranka()
    wall0 = time.perf_counter()
    robot = _connect(fr, host, realtime)
    # this process ahead of other work where allowed, as the server is (a missed 1 kHz cycle makes the
    # FCI extrapolate the command, which a reflex can follow); its own priority back afterwards
    before = os.getpriority(os.PRIO_PROCESS, 0)
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, 0, min(before, -10))
    try:
        return _stream(fr, robot, controller, duration_s, wall0, wall_clock)
    finally:
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, 0, before)


def min_jerk_plan(q_start: np.ndarray, q_goal: np.ndarray, max_velocity: float = 0.5, max_acceleration: float = 2.0,
                  min_duration_s: float = 0.2) -> tuple[float, Reference]:
    """A minimum-jerk (quintic) joint motion from ``q_start`` to ``q_goal``: its duration and ``ref(t) -> (q, dq)``.

    The duration is the shortest that keeps every joint's peak velocity, acceleration and jerk within
    ``max_velocity``, ``max_acceleration`` and a tenth of libfranka's jerk limit, and its velocity inside
    nine tenths of the FR3's position-based envelope along the path (lengthened until it is).

    Raises
    ------
    ValueError
        When ``q_goal`` is not (7,) or lies outside ``Q_LIMITS``.
    """
    q_start, q_goal = np.asarray(q_start, dtype=float), np.asarray(q_goal, dtype=float)
    if q_goal.shape != (7,) or not np.all(np.isfinite(q_goal)):
        raise ValueError(f"q_goal must be 7 finite joint positions, got {q_goal!r}")
    outside = (q_goal < Q_LIMITS[:, 0]) | (q_goal > Q_LIMITS[:, 1])
    if outside.any():
        raise ValueError(f"q_goal is outside the FR3's joint limits at joints {list(np.flatnonzero(outside) + 1)}")
    delta = q_goal - q_start
    d = float(np.max(np.abs(delta)))
    T = max(min_duration_s, 1.875 * d / max_velocity, math.sqrt(5.7735 * d / max_acceleration),
            (60.0 * d / (0.1 * J_MAX)) ** (1.0 / 3.0))
    s = np.linspace(0.0, 1.0, 201)[:, None]
    q = q_start + delta * (10 * s**3 - 15 * s**4 + 6 * s**5)
    upper = np.minimum(V_MAX, np.sqrt(np.maximum(0.0, 2 * DECELERATION * (Q_LIMITS[:, 1] - q))) - V_OFFSET)
    lower = np.maximum(-V_MAX, V_OFFSET - np.sqrt(np.maximum(0.0, 2 * DECELERATION * (q - Q_LIMITS[:, 0]))))
    shape = delta * (30 * s**2 - 60 * s**3 + 30 * s**4)   # the velocity times T
    for _ in range(40):
        if np.all((shape / T <= 0.9 * np.maximum(upper, 0.0)) & (shape / T >= 0.9 * np.minimum(lower, 0.0))):
            break
        T *= 1.25
    duration = T

    def ref(t: float) -> tuple[np.ndarray, np.ndarray]:
        tau = min(max(t / duration, 0.0), 1.0)
        return (q_start + delta * (10 * tau**3 - 15 * tau**4 + 6 * tau**5),
                delta * (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / duration)

    return duration, ref


def _concat(parts: list[FrankaRecord]) -> FrankaRecord:
    """Motions made one after the other as one record (each part's ``t`` continues the previous one's)."""
    offsets = np.cumsum([0.0] + [float(p.t[-1]) + 1e-3 if p.cycles else 0.0 for p in parts[:-1]])
    return FrankaRecord(
        t=np.concatenate([p.t + off for p, off in zip(parts, offsets)]),
        t_wall=np.concatenate([p.t_wall for p in parts]), q=np.concatenate([p.q for p in parts]),
        dq=np.concatenate([p.dq for p in parts]), dq_cmd=np.concatenate([p.dq_cmd for p in parts]),
        position=np.concatenate([p.position for p in parts]), rotation=np.concatenate([p.rotation for p in parts]),
        braking=np.concatenate([p.braking for p in parts]), error=parts[-1].error,
        cycles=sum(p.cycles for p in parts), wall_s=parts[-1].wall_s,
        t_control=np.concatenate([p.t_control + off for p, off in zip(parts, offsets)]))


def _velocity_of(ref: Reference) -> Controller:
    """The controller that commands ``ref``'s velocity, whatever the arm measures."""
    return lambda q, dq, t: ref(t)[1]


def move_to(host: str, q_goal: np.ndarray, *, max_velocity: float = 0.5, max_acceleration: float = 2.0,
            tolerance: float = 1e-3, attempts: int = 6, realtime: bool = False) -> FrankaRecord:
    """Move the arm at ``host`` to ``q_goal`` along minimum-jerk joint paths (``min_jerk_plan``).

    Reads the arm's configuration, plans from it and streams the plan's velocity; then, while a joint is
    further than ``tolerance`` from ``q_goal`` (the servo's lag and the server's clock, see
    ``FrankaRecord.t``, leave the arm short or past it), plans again from where the arm is, up to
    ``attempts`` motions in all. The commands stay smooth: a position feedback inside the loop would
    pass the jitter of franka-sim's measured state on as jerk. ``record.q[-1]`` is where the arm ended.
    Used to bring franka-sim from ``HOME_Q`` to a motion's start configuration.

    Parameters
    ----------
    host : str
        The robot's or the server's address.
    q_goal : np.ndarray
        (7,) the configuration to reach, rad, inside ``Q_LIMITS``.
    max_velocity, max_acceleration : float
        Per-joint peak velocity (rad/s) and acceleration (rad/s^2) of a plan.
    tolerance : float
        The largest joint error (rad) accepted.
    attempts : int
        At most this many motions.
    realtime : bool
        libfranka's ``RealtimeConfig.kEnforce`` instead of ``kIgnore``.

    Returns
    -------
    FrankaRecord
        The motions, one after the other; ``error`` is set if the robot aborted the last one.

    Raises
    ------
    ValueError
        When ``q_goal`` is not 7 numbers inside ``Q_LIMITS``.
    """
    fr = _pylibfranka()
    q_goal = np.asarray(q_goal, dtype=float)
    wall0 = time.perf_counter()
    robot = _connect(fr, host, realtime)
    q = np.array(robot.read_once().q)
    parts: list[FrankaRecord] = []
    for _ in range(max(1, attempts)):
        duration, ref = min_jerk_plan(q, q_goal, max_velocity, max_acceleration)
        parts.append(_stream(fr, robot, _velocity_of(ref), duration, wall0))
        if parts[-1].error is not None:
            break
        q = np.array(robot.read_once().q)
        if float(np.max(np.abs(q_goal - q))) < tolerance:
            break
    return _concat(parts)
