"""The franka-sim server in a child process of its own environment (``robots.franka`` re-exports it).

franka-sim pins its own numpy and MuJoCo, so it runs from ``.venv-franka`` at the repository root
(``scripts/setup_franka.sh`` makes the environment and its physics model ``.venv-franka/fr3.xml``), in
a child process started here: ``FrankaSimServer`` starts it on a loopback address of its own, waits until
it serves, and stops it on exit, never leaving a process behind. libfranka connects to the fixed port
``COMMAND_PORT``, so servers are told apart by address. This module imports neither MuJoCo nor
franka-sim.
"""

from __future__ import annotations

import contextlib
import os
import random
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from types import TracebackType

ROOT = Path(__file__).resolve().parent.parent
#: the franka-sim environment; ``$LFD_FRANKA_ENV`` overrides
DEFAULT_ENV = ROOT / ".venv-franka"
#: libfranka's command port: the client cannot choose another
COMMAND_PORT = 1337
#: the line the launcher prints once the server accepts clients and its physics runs
READY = "lfd-franka-sim-ready"
# Run by the franka environment's Python: a headless server on one address, no gripper, stopped
# cleanly on SIGTERM, and ended by the kernel when the process that started it dies (PR_SET_PDEATHSIG).
_LAUNCHER = f"""
import ctypes, logging, os, signal, sys, threading, time
host, parent, motion, comm = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1", sys.argv[4] == "1"
try:
    ctypes.CDLL(None).prctl(1, signal.SIGTERM)
except Exception:
    pass
if os.getppid() != parent:
    sys.exit(3)
def stop(*_):
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise KeyboardInterrupt
signal.signal(signal.SIGTERM, stop)
logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
from franka_sim import FrankaSimServer
server = FrankaSimServer(host=host, enable_vis=False, enable_gripper=False, enforce_motion_limits=motion,
                         enforce_comm_constraints=comm)
def announce():
    while not (server.running and server.server_socket is not None and server.physics_sim.running):
        time.sleep(0.01)
    print("{READY}", flush=True)
threading.Thread(target=announce, daemon=True).start()
try:
    server.start()
except KeyboardInterrupt:
    pass
finally:
    server.stop()
"""


def _before_server() -> None:
    """In the server's process: ahead of other work where allowed (missed 1 kHz states make the FCI
    extrapolate commands, which a reflex can follow)."""
    with contextlib.suppress(OSError):
        os.nice(-10)


class FrankaSimError(RuntimeError):
    """The franka-sim server cannot run (no environment, no model) or did not start; the message says why."""


def franka_env() -> Path:
    """The franka-sim environment: ``$LFD_FRANKA_ENV``, else ``.venv-franka`` at the repository root."""
    return Path(os.environ.get("LFD_FRANKA_ENV") or DEFAULT_ENV)


def _env_python(env: Path) -> Path:
    python = env / "bin" / "python"
    if not python.is_file():
        raise FrankaSimError(f"no franka-sim environment at {env}: run scripts/setup_franka.sh")
    return python


def franka_urdf(env: Path | None = None) -> Path:
    """The FR3 URDF bundled with franka-sim (``franka_sim/models/fr3.urdf`` in ``env``, default ``franka_env()``).

    The server serves it to clients (GetRobotModel) and ``scripts/make_fr3_mjcf.py`` makes its physics
    from it, so ``pinocchio.buildModelFromUrdf(str(franka_urdf()))`` has the server's kinematics: joints
    ``JOINT_NAMES``, tool frame ``TOOL_FRAME``. It names meshes that are not installed; Pinocchio's
    kinematic model does not need them.

    Raises
    ------
    FrankaSimError
        When the environment or the file is missing.
    """
    env = franka_env() if env is None else env
    found = sorted(env.glob("lib/python3*/site-packages/franka_sim/models/fr3.urdf"))
    if not found:
        _env_python(env)
        raise FrankaSimError(f"franka-sim's fr3.urdf is not in {env}: run scripts/setup_franka.sh")
    return found[-1]


def free_loopback_host() -> str:
    """A loopback address (127.x.y.z) whose ``COMMAND_PORT`` is free, else ``127.0.0.1``."""
    draw = random.SystemRandom()
    for _ in range(32):
        host = f"127.{draw.randint(1, 254)}.{draw.randint(0, 255)}.{draw.randint(1, 254)}"
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            try:
                probe.bind((host, COMMAND_PORT))
            except OSError:
                continue
        return host
    return "127.0.0.1"


class FrankaSimServer:
    """The franka-sim server in a child process from the franka environment, as a context manager.

    ``with FrankaSimServer() as server: stream_joint_velocities(server.host, ...)``. The server listens on
    ``host`` (default: a free loopback address of its own) at ``COMMAND_PORT``, headless, without the
    gripper, with the FCI's motion limits enforced (``enforce_motion_limits``) and, if asked, its
    communication constraints (``enforce_comm_constraints``: a motion is aborted after a run of lost
    cycles, as on the robot; off by default, since a loaded machine loses cycles that a real-time host
    would not). Its physics model is ``mjcf`` (default ``fr3.xml`` in the environment), passed as
    ``$FR3_MJCF``. Its output goes to ``log_path`` (default: a temporary file, removed on exit).

    ``start`` returns once the server accepts clients and its physics runs, or raises
    ``FrankaSimError`` (a missing environment or model, an early exit, no start within
    ``start_timeout_s``: the message ends with the log's last line). ``stop`` sends SIGTERM, which the
    server answers with its own clean shutdown, then SIGKILL after ``stop_timeout_s``; the server also
    ends if this process dies (Linux), so none is left behind. On Linux that tie is to the thread that
    called ``start``: start it from the main thread or one that outlives the server.

    Parameters
    ----------
    host : str, optional
        The address to listen on; default ``free_loopback_host()``.
    env : Path, optional
        The franka-sim environment; default ``franka_env()``.
    mjcf : Path, optional
        The FR3 physics model; default ``env / "fr3.xml"``.
    log_path : Path, optional
        Where the server's stdout and stderr go.
    enforce_motion_limits, enforce_comm_constraints : bool
        franka-sim's ``--enforce-motion-limits`` and ``--enforce-comm-constraints``.
    start_timeout_s, stop_timeout_s : float
        How long to wait for the server to serve, and for it to stop before it is killed.
    """

    def __init__(self, host: str | None = None, *, env: Path | None = None, mjcf: Path | None = None,
                 log_path: Path | None = None, enforce_motion_limits: bool = True,
                 enforce_comm_constraints: bool = False, start_timeout_s: float = 30.0,
                 stop_timeout_s: float = 10.0) -> None:
        self.env = franka_env() if env is None else Path(env)
        self.mjcf = self.env / "fr3.xml" if mjcf is None else Path(mjcf)
        self.host = host or ""
        self.log_path = log_path
        self.enforce_motion_limits = enforce_motion_limits
        self.enforce_comm_constraints = enforce_comm_constraints
        self.start_timeout_s = start_timeout_s
        self.stop_timeout_s = stop_timeout_s
        self._proc: subprocess.Popen[bytes] | None = None
        self._own_log = False

    @property
    def running(self) -> bool:
        """Whether the server process is alive."""
        return self._proc is not None and self._proc.poll() is None

    @property
    def pid(self) -> int | None:
        """The server process's id while started, else None."""
        return None if self._proc is None else self._proc.pid

    def log_text(self) -> str:
        """The server's output so far ('' when there is none)."""
        try:
            return self.log_path.read_text(encoding="utf-8", errors="replace") if self.log_path else ""
        except OSError:
            return ""

    def _fail(self, what: str) -> FrankaSimError:
        lines = [line for line in self.log_text().splitlines() if line.strip()]
        last = f"; its log ({self.log_path}) ends: {lines[-1].strip()}" if lines else ""
        return FrankaSimError(f"franka-sim server on {self.host}: {what}{last}")

    def start(self) -> FrankaSimServer:
        """Start the server and wait until it serves; returns ``self``."""
        if self._proc is not None:
            raise FrankaSimError("this franka-sim server is already started")
        python = _env_python(self.env)
        if not self.mjcf.is_file():
            raise FrankaSimError(f"no FR3 physics model at {self.mjcf}: run scripts/setup_franka.sh")
        self.host = self.host or free_loopback_host()
        if self.log_path is None:
            fd, name = tempfile.mkstemp(prefix="franka-sim-", suffix=".log")
            os.close(fd)
            self.log_path, self._own_log = Path(name), True
        # the franka environment has its own numpy and MuJoCo: nothing of this one may leak into it
        child_env = {k: v for k, v in os.environ.items() if k not in (
            "PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP", "VIRTUAL_ENV", "FRANKA_SIM_ENFORCE_MOTION_LIMITS",
            "FRANKA_SIM_ENFORCE_COMM_CONSTRAINTS")}
        child_env.update(FR3_MJCF=str(self.mjcf.resolve()), PYTHONUNBUFFERED="1")
        args = [str(python), "-c", _LAUNCHER, self.host, str(os.getpid()),
                str(int(self.enforce_motion_limits)), str(int(self.enforce_comm_constraints))]
        with open(self.log_path, "wb") as log:
            self._proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                          env=child_env, cwd=str(self.env), preexec_fn=_before_server)
        deadline = time.monotonic() + self.start_timeout_s
        while READY not in self.log_text():
            if self._proc.poll() is not None:
                code = self._proc.returncode
                self.stop()
                raise self._fail(f"exited with status {code} before serving")
            if time.monotonic() > deadline:
                self.stop()
                raise self._fail(f"not serving after {self.start_timeout_s:g} s")
            time.sleep(0.02)
        return self

    def stop(self) -> None:
        """Stop the server (SIGTERM, then SIGKILL after ``stop_timeout_s``); idempotent."""
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(self.stop_timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self._own_log and self.log_path is not None:
            self.log_path.unlink(missing_ok=True)
            self.log_path, self._own_log = None, False

    def __enter__(self) -> FrankaSimServer:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()
