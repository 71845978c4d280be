"""RoboTasks9: nine tasks of kinesthetic pose demos on a Franka Emika Panda, shipped in assets/robottasks."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lfd.demos.demoset import DemoSet
from lfd.errors import DemoError

ROBOTTASKS: tuple[str, ...] = ("bottle2shelf", "matfolding", "obstaclerotate", "openbox", "pan2stove",
                                "platestandingtolying", "pouring", "scoop", "wineglass")
ROBOTTASKS_RATE_HZ = 60.0
DATA = Path(__file__).resolve().parents[1] / "assets" / "robottasks"   # lfd/assets links to assets/


def robottasks(task: str) -> DemoSet:
    """One RoboTasks9 task: 9 kinesthetic demos of 1000 poses recorded at 60 Hz on a Franka Emika
    Panda, positions in metres in the robot's base frame, orientations (w, x, y, z).

    Read from the copy shipped in ``assets/robottasks`` (MIT licence, ``assets/robottasks/README.md``);
    the files hold centimetres, which this divides by 100. x has shape (9, 1000, 3), q (9, 1000, 4).
    The poses are those of the hand's tool point (``panda_hand_tcp``, the Panda's default tool frame):
    the matfolding demos then slide the fingertips 5 cm above the table, as folding a mat does (with the
    flange they would be under it); a few samples of openbox and pan2stove lie just beyond the arm's
    reach in that frame (reports/robottasks_arm.md).

    References
    ----------
    Auddy, S., Hollenstein, J., Saveriano, M., Rodriguez-Sanchez, A., Piater, J. (2023). Scalable and
    efficient continual learning from demonstration via a hypernetwork-generated stable dynamics
    model. arXiv:2311.03600
    """
    if task not in ROBOTTASKS:
        raise DemoError(f"robottasks:{task}: unknown task; known: {', '.join(ROBOTTASKS)}")
    path = DATA / f"{task}.npy"
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise DemoError(f"robottasks:{task}: cannot read the shipped data {path} ({e})") from None
    if a.ndim != 3 or a.shape[2] != 7:
        raise DemoError(f"robottasks:{task}: the shipped data {path} has shape {a.shape}, expected (N, T, 7)")
    t = np.arange(a.shape[1]) / ROBOTTASKS_RATE_HZ
    return DemoSet(np.broadcast_to(t, a.shape[:2]).copy(), a[..., :3] / 100.0, name=f"robottasks:{task}",
                   q=a[..., 3:])
