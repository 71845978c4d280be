#!/usr/bin/env python
"""Write a pour the stack has never seen, as a pose CSV any user could bring: assets/demos/pour_unseen.csv.

Made from RoboTasks9's nine pouring demos, changed in the three ways a new recording differs:

* another place and shape: each path, relative to its end, stretched by (1.2, 0.85, 0.9) along x, y, z,
  then the whole pour turned by 25 deg about the base's vertical axis (tool orientations too);
* another tilt: each orientation's turn from its demo's start scaled by 1.1 (the cup tilts further);
* ends spread as a recording's are (RoboTasks9's were moved to one point): each demo moved by its own
  offset, drawn N(0, 1.5 cm) in x and y and N(0, 0.8 cm) in z, and turned by up to 3 deg, both blended
  in from 0 at its start to all of it at its end (smoothstep); every second sample kept (30 Hz).

Seeded: the same file every time.

    python scripts/make_pour_csv.py [--out assets/demos/pour_unseen.csv]
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

TURN_DEG = 25.0
STRETCH = np.array([1.2, 0.85, 0.9])
TILT_SCALE = 1.1
END_SPREAD_M = np.array([0.015, 0.015, 0.008])
END_TURN_DEG = 3.0
SEED = 7


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="assets/demos/pour_unseen.csv")
    args = ap.parse_args(argv)
    import lfd

    demos = lfd.load_demos("robottasks:pouring")
    rng = np.random.default_rng(SEED)
    turn = Rotation.from_euler("z", TURN_DEG, degrees=True)
    rows = []
    for i in range(demos.n_demos):
        t, x, q = demos.t[i][::2], demos.x[i][::2], demos.q[i][::2]
        rot = Rotation.from_quat(q, scalar_first=True)
        x = x[-1] + (x - x[-1]) * STRETCH
        rel = (rot[0].inv() * rot).as_rotvec() * TILT_SCALE          # the turn from the start, scaled
        rot = rot[0] * Rotation.from_rotvec(rel)
        s = (t - t[0]) / (t[-1] - t[0])
        blend = s * s * (3 - 2 * s)                                    # smoothstep 0 -> 1
        offset = rng.normal(0.0, END_SPREAD_M)
        axis = rng.normal(size=3)
        end_turn = axis / np.linalg.norm(axis) * np.radians(rng.uniform(0, END_TURN_DEG))
        x = x + blend[:, None] * offset
        rot = Rotation.from_rotvec(blend[:, None] * end_turn) * rot
        x, rot = turn.apply(x), turn * rot
        quat = rot.as_quat(scalar_first=True)
        rows += [[i, f"{tk:.4f}", *(f"{v:.6f}" for v in xk), *(f"{v:.7f}" for v in qk)]
                 for tk, xk, qk in zip(t - t[0], x, quat)]
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with tmp.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["demo", "t", "x", "y", "z", "qw", "qx", "qy", "qz"])
        w.writerows(rows)
    tmp.replace(out)
    print(f"wrote {out}: {demos.n_demos} demos, {len(rows)} rows")
    return 0


if __name__ == "__main__":
    sys.exit(main())
