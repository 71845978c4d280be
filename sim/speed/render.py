"""Speed: video frames per second of ``sim.media.render`` (offscreen GL, overlays and H.264 encoding).

Runs a field (the ``tracking`` learner, trained in a moment) on ``--robot`` under three pushes
(seeds 0, 1, 2), then writes, in interleaved repeats (so machine load hits each case alike):
``single``, one video of one run, ``--size`` (default 640x480); ``side``, one side-by-side video
of the three runs, ``--side-size`` (default 1280x480, as ``demo_arm.py --side-by-side``), three
panels; ``separate``, three videos, one per run, each the size of one panel of ``side``.

Each case is timed end to end (``Experiment.render``: GL context, scene, overlays, encoding, file)
and printed as frames per second of wall time (median and p95, i.e. the slowest 5%, over the
repeats, and the first repeat, which pays for opening a GL context), and as CPU time per frame
(this process, llvmpipe's threads included, plus ffmpeg): on a loaded machine the CPU time varies
less than the wall time. ``side`` / ``separate`` is the time ratio of the side-by-side video to the
three separate ones (target: <= 1); target for ``single``: >= 50 fps at 640x480. Asserts nothing.
Timings are wall clock: note the load average (printed). Run with ``MUJOCO_GL=egl`` where EGL works.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

import lfd
import sim
from lfd.errors import ConfigError
from robots import load_robot
from sim.run.parsing import names
from sim.speed.timing import load
from sim.speed.trained import demos_of

__all__ = ["CASES", "add_arguments", "run"]

CASES = ("single", "side", "separate")
QUICK_SIZE = (64, 48)


def size(text: str) -> tuple[int, int]:
    """'WxH' -> (W, H)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got '{text[:20]}'") from None
    return w, h


def cpu_seconds() -> float:
    """CPU time (user + system, s) of this process (all its threads: llvmpipe renders in threads)
    and of its children that have ended (ffmpeg)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def render_case(exp: sim.Experiment, runs: list[Any], case: str, folder: Path, single: tuple[int, int],
                side: tuple[int, int]) -> tuple[float, float, int]:
    """(wall s, CPU s, frames of video written) of one ``case`` (see the module docstring)."""
    c0 = cpu_seconds()
    t0 = time.perf_counter()
    if case == "single":
        n = exp.render(runs[0], folder / "single.mp4", *single)
    elif case == "side":
        n = exp.render(runs, folder / "side.mp4", *side)
    else:
        pw, ph = (side[0] // len(runs)) // 2 * 2, side[1] // 2 * 2
        n = sum(exp.render(r, folder / f"separate{k}.mp4", pw, ph) for k, r in enumerate(runs))
    return time.perf_counter() - t0, cpu_seconds() - c0, n


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The robot, the demos, the video sizes, the cases, the repeats."""
    ap.add_argument("--robot", default="panda")
    ap.add_argument("--demos", default="spiral")
    ap.add_argument("--size", type=size, default=(640, 480), help="single video size (default 640x480)")
    ap.add_argument("--side-size", type=size, default=(1280, 480), help="side-by-side size (default 1280x480)")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    ap.add_argument("--repeats", type=int, default=3, help="interleaved repeats of every case")


def run(args: argparse.Namespace) -> int:
    """Render every case ``--repeats`` times, interleaved, and print the frame rates (module docstring);
    ``--quick``: a short spiral, one repeat at 64x48 (side by side 192x48)."""
    cases = names(args.cases)
    if not cases or any(c not in CASES for c in cases):
        raise ConfigError(f"--cases must name some of {', '.join(CASES)}")
    if not 1 <= args.repeats <= 1000:
        raise ConfigError("--repeats must be in 1..1000")
    repeats, single, side = (1, QUICK_SIZE, (3 * QUICK_SIZE[0], QUICK_SIZE[1])) if args.quick else \
        (args.repeats, args.size, args.side_size)
    demos = demos_of(args)
    field = lfd.train("tracking", demos, seed=0, progress=False)
    exp = sim.Experiment(load_robot(args.robot, actuation="torque"), demos)
    runs = [exp.run(field, "push", seed=s) for s in range(3)]
    print(f"robot {args.robot}, {len(runs[0].trace.frame_t)} frames per run at {exp.fps:g} fps, "
          f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}, {os.cpu_count()} CPUs")
    times: dict[str, list[float]] = {c: [] for c in cases}
    cpu: dict[str, list[float]] = {c: [] for c in cases}
    frames: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        exp.render(runs[0], folder / "warmup.mp4", 64, 48)   # imports, fonts, ffmpeg lookup
        for r in range(repeats):
            row = []
            for case in cases:
                wall, used, n = render_case(exp, runs, case, folder, single, side)
                times[case].append(wall)
                cpu[case].append(used)
                frames[case] = n
                row.append(f"{case} {n / wall:6.1f} fps {used / n * 1e3:5.1f} CPU ms/frame")
            print(f"repeat {r + 1}: {'   '.join(row)}   (load average {load():.2f})")
    sw, sh = side
    label = {"single": f"single {single[0]}x{single[1]}", "side": f"side-by-side {sw}x{sh}, 3 panels",
             "separate": f"3 separate {(sw // 3) // 2 * 2}x{sh // 2 * 2}"}
    print(f"\n{'case':36s} {'median fps':>10s} {'p95 fps':>8s} {'first fps':>10s} {'median s':>9s} "
          f"{'CPU ms/frame':>13s}")
    for case in cases:
        fps = frames[case] / np.asarray(times[case])
        print(f"{label[case]:36s} {np.median(fps):10.1f} {np.percentile(fps, 5):8.1f} {fps[0]:10.1f} "
              f"{np.median(times[case]):9.2f} {np.median(cpu[case]) / frames[case] * 1e3:13.1f}")
    if "side" in times and "separate" in times:
        ratio = np.asarray(times["side"]) / np.asarray(times["separate"])
        print(f"side-by-side / 3 separate (time): median {np.median(ratio):.2f} (target: <= 1)")
    if "single" in times:
        med = frames["single"] / float(np.median(times["single"]))
        print(f"single video: {med:.1f} fps ({'met' if med >= 50 else 'not met'}: target >= 50)")
    return 0
