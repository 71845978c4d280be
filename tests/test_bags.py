"""Pose demos from ROS bags (lfd.demos.bags): ROS 1, ROS 2 sqlite3 and MCAP bags written here with rosbags'
writers read back to the very arrays a CSV gives, and every bad input is one line of DemoError."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bag_writer import BASE_NS, POSE, STORES, TF, TRANSFORM, pose, transform, write_bag

import lfd
from lfd.demos import DemoSet, load_demos, load_file, robottasks, save_file
from lfd.demos.bags import GAP_S, load_bag
from lfd.errors import DemoError

KINDS = ("ros1", "sqlite3", "mcap")
T_SAMPLES = 40
STEP_NS = 100_000_000            # 10 Hz
DEMO_NS = 10 * 10**9             # demo i starts at BASE_NS + i DEMO_NS: 6 s of pause after each, above GAP_S
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ref() -> DemoSet:
    """3 pouring demos of 40 poses, every 25th sample. Times are integer nanoseconds divided by 1e9,
    as lfd.demos.bags computes them from header stamps: a float time such as k/60 s is no whole number of
    nanoseconds, so a stamp could not give it back exactly."""
    task = robottasks("pouring")
    assert task.q is not None
    t = np.broadcast_to(np.arange(T_SAMPLES, dtype=np.int64) * STEP_NS / 1e9, (3, T_SAMPLES))
    return DemoSet(t, task.x[:3, ::25], name="ref", q=task.q[:3, ::25])


def pose_msgs(kind: str, demos: DemoSet, starts: list[int] | None = None) -> list[Any]:
    """The demos' poses as PoseStamped, demo i stamped from ``starts[i]`` (default: DEMO_NS apart)."""
    ts = STORES[kind]
    assert demos.q is not None
    starts = starts or [BASE_NS + i * DEMO_NS for i in range(demos.n_demos)]
    k_ns = np.arange(demos.n_samples) * STEP_NS
    return [pose(ts, starts[i] + int(k_ns[k]), demos.x[i, k], demos.q[i, k])
            for i in range(demos.n_demos) for k in range(demos.n_samples)]


def assert_same(a: DemoSet, b: DemoSet) -> None:
    assert a.q is not None and b.q is not None
    assert a.t.shape == b.t.shape == (3, T_SAMPLES)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.x, b.x) and np.array_equal(a.q, b.q)


# ---------------------------------------------------------------- the same demos, every way

@pytest.mark.parametrize("layout", ["ros1", "sqlite3", "mcap", "mcap-dir", "mixed-dir"])
def test_bag_gives_the_csv_arrays(tmp_path: Path, ref: DemoSet, layout: str) -> None:
    """One bag split at the pauses between demos, or a directory of bags of one demo each (a ROS 1
    bag, a sqlite3 and an MCAP bag in 'mixed-dir'), give bit for bit the arrays of the CSV."""
    save_file(ref, tmp_path / "d.csv")
    csv = load_file(tmp_path / "d.csv")
    if layout in KINDS:
        path = write_bag(tmp_path / "demos", layout, {"/pose": (POSE, pose_msgs(layout, ref))})
    else:
        path = tmp_path / "demos"
        path.mkdir()
        kinds = ["mcap"] * 3 if layout == "mcap-dir" else ["sqlite3", "ros1", "mcap"]
        for i in (2, 0, 1):   # written out of order: the names decide the order, every demo from BASE_NS
            write_bag(path / f"demo_{i}", kinds[i], {"/pose": (POSE, pose_msgs(kinds[i], ref.subset([i]),
                                                                              [BASE_NS]))})
        (path / "README.txt").write_text("not a bag, ignored\n")
    demos = load_demos(f"bag:{path}:/pose")
    assert demos.name == f"bag:{path}:/pose"
    assert_same(demos, csv)
    assert_same(demos, ref)
    assert demos.t[0, 1] == 0.1 and demos.t[0, -1] == 3.9


def test_demos_of_different_lengths_are_resampled(tmp_path: Path, ref: DemoSet) -> None:
    """A demo of 30 stamps beside two of 40 is resampled to 40 over its own span; the others are kept."""
    msgs = pose_msgs("mcap", ref)
    path = write_bag(tmp_path / "b", "mcap", {"/pose": (POSE, msgs[:T_SAMPLES + 30] + msgs[2 * T_SAMPLES:])})
    demos = load_bag(f"bag:{path}:/pose")
    assert demos.t.shape == (3, T_SAMPLES)
    assert np.array_equal(demos.x[[0, 2]], ref.x[[0, 2]])
    assert np.allclose(demos.t[1], np.linspace(0.0, 2.9, T_SAMPLES), rtol=0, atol=1e-15)
    assert np.array_equal(demos.x[1, [0, -1]], ref.x[1, [0, 29]])


def test_a_bag_of_a_directory_is_one_demo_across_a_pause(tmp_path: Path, ref: DemoSet) -> None:
    """In a directory each bag is one demo: a pause of 2 s in its stamps does not split it. The arm moves
    one step across it, so the clean-up of the recording cuts it out of the demo's time."""
    for i in range(3):
        msgs = pose_msgs("mcap", ref.subset([i]), [BASE_NS])
        if i == 1:   # samples 20.. of demo 1 stamped 2 s later
            assert ref.q is not None
            msgs[20:] = [pose(STORES["mcap"], BASE_NS + k * STEP_NS + 2 * 10**9, ref.x[1, k], ref.q[1, k])
                         for k in range(20, T_SAMPLES)]
        write_bag(tmp_path / f"demo_{i}", "mcap", {"/pose": (POSE, msgs)})
    demos = load_bag(f"bag:{tmp_path}:/pose")
    assert demos.n_demos == 3 and np.array_equal(demos.x, ref.x)
    np.testing.assert_allclose(demos.t, ref.t, rtol=0, atol=1e-12)
    assert demos.notes == (f"bag:{tmp_path}:/pose: demo 1: cut a 2.1 s gap at 1.9 s in its time stamps, across "
                           "which it barely moved; later times moved back; 34% of its duration removed",)


@pytest.mark.usefixtures("one_thread")
def test_the_same_model_from_csv_and_mcap(tmp_path: Path, ref: DemoSet) -> None:
    import torch

    save_file(ref, tmp_path / "d.csv")
    path = write_bag(tmp_path / "b", "mcap", {"/pose": (POSE, pose_msgs("mcap", ref))})
    a = lfd.train("tracking", load_demos(str(tmp_path / "d.csv")), seed=0)
    b = lfd.train("tracking", load_demos(f"bag:{path}:/pose"), seed=0)
    sa, sb = a.module.state_dict(), b.module.state_dict()
    assert list(sa) == list(sb) and len(sa) > 0
    assert all(torch.equal(sa[k], sb[k]) for k in sa)


# ---------------------------------------------------------------- transforms

@pytest.mark.parametrize("kind", KINDS)
def test_transform_stamped_topic(tmp_path: Path, ref: DemoSet, kind: str) -> None:
    ts = STORES[kind]
    assert ref.q is not None
    msgs = [transform(ts, BASE_NS + i * DEMO_NS + k * STEP_NS, ref.x[i, k], ref.q[i, k], "world", "tool")
            for i in range(3) for k in range(T_SAMPLES)]
    path = write_bag(tmp_path / "b", kind, {"/tool_pose": (TRANSFORM, msgs)})
    assert_same(load_bag(f"bag:{path}:/tool_pose"), ref)


@pytest.mark.parametrize("kind", KINDS)
def test_tf_topic_takes_one_frame_pair(tmp_path: Path, ref: DemoSet, kind: str) -> None:
    """Each TFMessage holds world -> tool (the demos) and world -> cup (the demos moved by 1 m); ROS 1
    frames carry a leading slash, which the spec may give or leave out."""
    ts = STORES[kind]
    assert ref.q is not None
    slash = "/" if kind == "ros1" else ""
    moved = ref.x + 1.0
    msgs = []
    for i in range(3):
        for k in range(T_SAMPLES):
            ns = BASE_NS + i * DEMO_NS + k * STEP_NS
            msgs.append(ts.types[TF](transforms=[
                transform(ts, ns, moved[i, k], ref.q[i, k], f"{slash}world", f"{slash}cup"),
                transform(ts, ns, ref.x[i, k], ref.q[i, k], f"{slash}world", f"{slash}tool")]))
    path = write_bag(tmp_path / "b", kind, {"/tf": (TF, msgs), "/pose": (POSE, pose_msgs(kind, ref)[:5])})
    assert_same(load_bag(f"bag:{path}:/tf:world:tool"), ref)
    assert_same(load_bag(f"bag:{path}:/tf:/world:/tool"), ref)
    cup = load_bag(f"bag:{path}:/tf:world:cup")
    assert np.array_equal(cup.x, moved) and np.array_equal(cup.t, ref.t)


def test_quaternion_sign_flips_are_made_continuous(tmp_path: Path, ref: DemoSet) -> None:
    """Every other pose is stored as -q, the same rotation: read back continuous, equal to q."""
    assert ref.q is not None
    flipped = ref.q * np.where(np.arange(T_SAMPLES) % 2, -1.0, 1.0)[None, :, None]
    msgs = [pose(STORES["sqlite3"], BASE_NS + i * DEMO_NS + k * STEP_NS, ref.x[i, k], flipped[i, k])
            for i in range(3) for k in range(T_SAMPLES)]
    path = write_bag(tmp_path / "b", "sqlite3", {"/pose": (POSE, msgs)})
    demos = load_bag(f"bag:{path}:/pose")
    assert demos.q is not None
    assert np.all(np.sum(demos.q[:, 1:] * demos.q[:, :-1], axis=-1) >= 0)
    assert np.array_equal(demos.q, ref.q)


# ---------------------------------------------------------------- bad input

def _bad_bags(tmp: Path, ref: DemoSet) -> dict[str, tuple[str, str]]:
    """Bad inputs: name -> (spec, the regex its DemoError matches after the spec)."""
    ts = STORES["mcap"]
    assert ref.q is not None
    msgs = pose_msgs("mcap", ref)
    good = write_bag(tmp / "good", "mcap", {"/pose": (POSE, msgs)})
    ros1 = write_bag(tmp / "good1", "ros1", {"/pose": (POSE, pose_msgs("ros1", ref))})
    (tmp / "text.bag").write_text("hello\n")
    (tmp / "notes.txt").write_text("hello\n")
    (tmp / "cut.bag").write_bytes(ros1.read_bytes()[: ros1.stat().st_size // 2])
    cut = write_bag(tmp / "cut_mcap", "mcap", {"/pose": (POSE, msgs)})
    storage = cut / "cut_mcap.mcap"
    storage.write_bytes(storage.read_bytes()[:-40])
    (tmp / "empty").mkdir()
    many = write_bag(tmp / "many", "sqlite3", {f"/topic_{j:02d}": (POSE, msgs[:1]) for j in range(10)})
    chatter = write_bag(tmp / "chatter", "mcap", {"/chatter": ("std_msgs/msg/String",
                                                               [ts.types["std_msgs/msg/String"](data="hi")])})
    tf = write_bag(tmp / "tf", "mcap", {"/tf": (TF, [ts.types[TF](transforms=[
        transform(ts, BASE_NS + k * STEP_NS, ref.x[0, k], ref.q[0, k], "world", child)
        for child in ("tool", "cup")]) for k in range(T_SAMPLES)])})
    single = write_bag(tmp / "single", "ros1", {"/pose": (POSE, pose_msgs("ros1", ref)[:1])})
    short = write_bag(tmp / "short", "mcap", {"/pose": (POSE, msgs[:T_SAMPLES + 5])})
    swapped = msgs.copy()
    swapped[5], swapped[6] = swapped[6], swapped[5]
    unsorted = write_bag(tmp / "unsorted", "sqlite3", {"/pose": (POSE, swapped)})
    repeated = msgs.copy()
    repeated[6] = pose(ts, BASE_NS + 5 * STEP_NS, ref.x[0, 6], ref.q[0, 6])
    repeats = write_bag(tmp / "repeats", "mcap", {"/pose": (POSE, repeated)})
    nan_x = msgs.copy()
    nan_x[3] = pose(ts, BASE_NS + 3 * STEP_NS, np.array([0.1, np.nan, 0.2]), ref.q[0, 3])
    nan_pos = write_bag(tmp / "nan_pos", "mcap", {"/pose": (POSE, nan_x)})
    nan_q = msgs.copy()
    nan_q[3] = pose(ts, BASE_NS + 3 * STEP_NS, ref.x[0, 3], np.array([np.nan, 0.0, 0.0, 1.0]))
    nan_rot = write_bag(tmp / "nan_rot", "mcap", {"/pose": (POSE, nan_q)})
    mixed = tmp / "mixed"
    mixed.mkdir()
    write_bag(mixed / "demo_0", "mcap", {"/pose": (POSE, msgs[:T_SAMPLES])})
    write_bag(mixed / "demo_1", "mcap", {"/other": (POSE, msgs[:T_SAMPLES])})
    return {
        "spec": ("bag:x.bag", r": expected bag:PATH:/topic or bag:PATH:/topic:PARENT:CHILD \(PATH, topic and "
                              r"frames without ':'\)$"),
        "missing path": (f"bag:{tmp / 'absent.bag'}:/pose", r": no such file or directory$"),
        "text file .bag": (f"bag:{tmp / 'text.bag'}:/pose", r": not a readable bag \(File magic is invalid\.\)$"),
        "text file": (f"bag:{tmp / 'notes.txt'}:/pose", r": \S+notes.txt is not a bag \(expected a ROS 1 \.bag "
                                                        r"file, a ROS 2 bag directory with a metadata\.yaml"),
        "truncated ros1": (f"bag:{tmp / 'cut.bag'}:/pose", r": not a readable bag \(.+\)$"),
        "truncated mcap": (f"bag:{cut}:/pose", r": not a readable bag \(.+\)$"),
        "empty directory": (f"bag:{tmp / 'empty'}:/pose", r": the directory \S+ holds no bags"),
        "missing topic": (f"bag:{good}:/missing", r": no topic /missing in the bag; it has /pose "
                                                  rf"\({POSE}\)$"),
        "many topics": (f"bag:{many}:/missing", r": no topic /missing in the bag; it has /topic_00 \(geometry_"
                                                r"msgs/msg/PoseStamped\), .*, /topic_05 \(.*\) and 4 more$"),
        "wrong type": (f"bag:{chatter}:/chatter", r": topic /chatter has type std_msgs/msg/String; supported: "
                                                  rf"{POSE}, {TRANSFORM}, {TF}$"),
        "tf without frames": (f"bag:{tf}:/tf", r": topic /tf has type tf2_msgs/msg/TFMessage; name the frames, "
                                               r"bag:PATH:/tf:PARENT:CHILD \(it has world -> tool, world -> cup\)$"),
        "tf without the pair": (f"bag:{tf}:/tf:world:hand", r": no transform world -> hand on /tf; it has "
                                                            r"world -> tool, world -> cup$"),
        "frames of a pose topic": (f"bag:{good}:/pose:world:tool", r": frames are given, but topic /pose has "
                                                                   rf"type {POSE}; frames PARENT:CHILD are for {TF}"),
        "single sample": (f"bag:{single}:/pose", r": demo 0 \(message 0\) has 1 sample, at least 10 are needed "
                                                 rf"\(demos are split at stamp gaps over {GAP_S:g} s\)$"),
        "short demo": (f"bag:{short}:/pose", r": demo 1 \(messages 40 to 44\) has 5 samples, at least 10"),
        "unsorted": (f"bag:{unsorted}:/pose", r": the stamp of message 6 on /pose \(1700000000\.500000000 s\) is "
                                              r"before the stamp of message 5 \(1700000000\.600000000 s\); stamps "
                                              r"must increase$"),
        "repeated": (f"bag:{repeats}:/pose", r": the stamp of message 6 on /pose \(1700000000\.500000000 s\) "
                                             r"repeats the stamp of message 5"),
        "nan position": (f"bag:{nan_pos}:/pose", r": NaN or inf in the position of message 3 on /pose$"),
        "nan orientation": (f"bag:{nan_rot}:/pose", r": NaN or inf in the orientation of message 3 on /pose$"),
        "bag of a directory": (f"bag:{mixed}:/pose", r": demo_1: no topic /pose in the bag; it has /other"),
    }


@pytest.fixture(scope="module")
def bad_bags(tmp_path_factory: pytest.TempPathFactory, ref: DemoSet) -> dict[str, tuple[str, str]]:
    return _bad_bags(tmp_path_factory.mktemp("bad"), ref)


@pytest.mark.parametrize("case", [
    "spec", "missing path", "text file .bag", "text file", "truncated ros1", "truncated mcap", "empty directory",
    "missing topic", "many topics", "wrong type", "tf without frames", "tf without the pair",
    "frames of a pose topic", "single sample", "short demo", "unsorted", "repeated", "nan position",
    "nan orientation", "bag of a directory"])
def test_bad_input_is_one_line_of_demo_error(bad_bags: dict[str, tuple[str, str]], case: str) -> None:
    spec, pattern = bad_bags[case]
    with pytest.raises(DemoError) as info:
        load_demos(spec)
    text = str(info.value)
    assert text.startswith(spec) and "\n" not in text and len(text) < 500, text
    assert info.value.__cause__ is None   # no rosbags traceback chained to it
    assert re.fullmatch(re.escape(spec) + pattern + ("" if pattern.endswith("$") else ".*"), text), text


def test_cli_reports_a_missing_topic_in_one_line(tmp_path: Path, ref: DemoSet) -> None:
    path = write_bag(tmp_path / "b", "mcap", {"/pose": (POSE, pose_msgs("mcap", ref))})
    out = tmp_path / "m.pt"
    proc = subprocess.run([sys.executable, "-m", "lfd.cli", "train", "--learner", "tracking",
                           "--demos", f"bag:{path}:/missing", "--out", str(out)],
                          capture_output=True, text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.splitlines() == [f"lfd: error: bag:{path}:/missing: no topic /missing in the bag; "
                                        f"it has /pose ({POSE})"]
    assert not out.exists() and list(tmp_path.iterdir()) == [path]


def test_import_of_demos_does_not_load_rosbags() -> None:
    code = "import sys, lfd.demos; print('rosbags' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert proc.stdout.strip() == "False", proc.stderr
