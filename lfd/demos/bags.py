"""Demonstrations of poses read from ROS 1 and ROS 2 bags (sqlite3 or MCAP), without a ROS install.

The pure-Python ``rosbags`` library reads the bags. A spec names the bag and the topic:

    bag:PATH:/topic                 geometry_msgs/msg/PoseStamped or geometry_msgs/msg/TransformStamped
    bag:PATH:/topic:PARENT:CHILD    tf2_msgs/msg/TFMessage (/tf, /tf_static, ...): the transforms from
                                    frame PARENT to frame CHILD

PATH is a ROS 1 ``.bag`` file, a ROS 2 bag directory (``metadata.yaml`` beside its ``.db3`` or
``.mcap`` storage; a bare ``.db3`` or ``.mcap`` file works too), or a directory holding several of
these. The spec is split at every ':', so PATH, the topic and the frame names may not contain one
(nor a Windows drive letter: give a relative path there). A topic without a leading slash gets one;
frame names are compared with one leading slash stripped (ROS 1 writes ``/world``, ROS 2 ``world``).

A single bag is split into demos where the header stamps of consecutive messages are more than
``GAP_S`` apart; in a directory, each bag is one demo (in sorted name order), not split. Times are
the messages' header stamps (not the times the bag received them), each demo's starting at 0;
positions are in metres in the message's frame (no transform is applied), and ROS quaternions
(x, y, z, w) become (w, x, y, z). The demos are recordings, cleaned up as a file's are
(``lfd.demos.recording``: gaps, noise, standing still, pauses; demos of different lengths resampled to
the longest). Every bad input, a corrupt bag included, is a ``DemoError`` of one line.
"""

from __future__ import annotations

import struct
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lfd.demos.demoset import MIN_SAMPLES, DemoSet
from lfd.demos.recording import recorded_set
from lfd.errors import DemoError

# s: pose streams are recorded at 10 Hz or faster (steps of 0.1 s or less), so even a few dropped
# messages in a row leave a gap below half a second, while moving the arm back to a start between
# two demos takes a second or more; half a second splits the demos and nothing else
GAP_S = 0.5

POSE = "geometry_msgs/msg/PoseStamped"
TRANSFORM = "geometry_msgs/msg/TransformStamped"
TF = "tf2_msgs/msg/TFMessage"
SUPPORTED = (POSE, TRANSFORM, TF)
BAG_SUFFIXES = (".bag", ".db3", ".mcap")   # ROS 1 bag; bare ROS 2 storage files
MAX_LISTED = 6      # topics or frame pairs an error message lists before "... and N more"
MAX_NAME = 60       # characters of a topic, type or frame name shown in an error message


@dataclass(frozen=True)
class _Spec:
    path: Path
    topic: str
    frames: tuple[str, str] | None   # (PARENT, CHILD), leading slash stripped, for a TFMessage topic


@dataclass(frozen=True)
class _Stream:
    """The poses of one topic of one bag, in the order the bag holds them: M messages.

    ns : array, shape (M,), int64 -- header stamps, nanoseconds
    x : array, shape (M, 3)       -- positions
    q : array, shape (M, 4)       -- quaternions (w, x, y, z)
    """

    ns: np.ndarray
    x: np.ndarray
    q: np.ndarray


def load_bag(spec: str, clean: bool | str | Iterable[str] = True) -> DemoSet:
    """The demos of a ``bag:`` SPEC (the module's docstring gives the grammar).

    Parameters
    ----------
    spec : str
        ``bag:PATH:/topic`` or ``bag:PATH:/topic:PARENT:CHILD``; PATH holds no ':'.
    clean : bool, str or iterable of str
        The clean-up steps to run (``lfd.demos.recording.clean_steps``): True all, False none.

    Returns
    -------
    DemoSet
        N demos of T poses named ``spec``: t (N, T) seconds, each demo's from 0; x (N, T, 3) metres;
        q (N, T, 4) unit quaternions (w, x, y, z); ``notes`` says what the clean-up did.

    Raises
    ------
    DemoError
        One line naming the spec (and the bag of a directory) and what is wrong: a malformed spec, no
        such path, not a bag or a corrupt one, a missing topic (with the topics there are), an
        unsupported message type, a missing frame pair (with the pairs there are), a demo of fewer
        than ``MIN_SAMPLES`` messages, stamps not increasing, NaN or inf in a pose.
    """
    parsed = _parse(spec)
    path = parsed.path
    if not path.exists():
        raise DemoError(f"{spec}: no such file or directory")
    segments: list[tuple[str, _Stream, int, int | None]]   # (where, stream, first, end) of each demo
    if path.is_dir() and not (path / "metadata.yaml").exists():
        bags = sorted((p for p in path.iterdir() if _is_bag(p)), key=lambda p: p.name)
        if not bags:
            raise DemoError(f"{spec}: the directory {path} holds no bags (.bag files or ROS 2 bag "
                            "directories with a metadata.yaml)")
        wheres = [f"{spec}: {p.name}" for p in bags]
        segments = [(where, _read(p, parsed, where), 0, None) for p, where in zip(bags, wheres)]
        hint = ""
    else:
        if path.is_file() and path.suffix not in BAG_SUFFIXES:
            raise DemoError(f"{spec}: {path} is not a bag (expected a ROS 1 .bag file, a ROS 2 bag "
                            "directory with a metadata.yaml, or a directory of bags)")
        stream = _read(path, parsed, spec)
        cuts = (np.flatnonzero(np.diff(stream.ns) > round(GAP_S * 1e9)) + 1).tolist()
        segments = [(spec, stream, a, b) for a, b in zip([0, *cuts], [*cuts, None])]
        hint = f" (demos are split at stamp gaps over {GAP_S:g} s)"
    for i, (where, s, a, b) in enumerate(segments):
        n = len(s.ns[a:b])
        if n < MIN_SAMPLES:
            which = f"messages {a} to {a + n - 1}" if n > 1 else f"message {a}"
            raise DemoError(f"{where}: demo {i} ({which}) has {n} sample{'s' * (n != 1)}, at least "
                            f"{MIN_SAMPLES} are needed{hint}")
    ts = [(s.ns[a:b] - s.ns[a]) / 1e9 for _, s, a, b in segments]
    return recorded_set(ts, [s.x[a:b] for _, s, a, b in segments], [s.q[a:b] for _, s, a, b in segments], spec,
                        clean)


def _parse(spec: str) -> _Spec:
    parts = spec.split(":")
    if parts[0] != "bag" or len(parts) not in (3, 5) or not all(parts[1:]):
        raise DemoError(f"{spec}: expected bag:PATH:/topic or bag:PATH:/topic:PARENT:CHILD "
                        "(PATH, topic and frames without ':')")
    topic = parts[2] if parts[2].startswith("/") else "/" + parts[2]
    frames = (_frame(parts[3]), _frame(parts[4])) if len(parts) == 5 else None
    if frames is not None and not all(frames):
        raise DemoError(f"{spec}: empty frame name")
    return _Spec(Path(parts[1]), topic, frames)


def _frame(name: str) -> str:
    return name[1:] if name.startswith("/") else name


def _is_bag(p: Path) -> bool:
    """Whether ``p``, an entry of a directory of bags, is a bag."""
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.is_file() and p.suffix in BAG_SUFFIXES


def _short(name: str) -> str:
    return name if len(name) <= MAX_NAME else name[:MAX_NAME - 3] + "..."


def _listing(items: list[str]) -> str:
    """Up to MAX_LISTED items, comma-separated, then how many were left out."""
    shown = ", ".join(_short(s) for s in items[:MAX_LISTED])
    return shown + (f" and {len(items) - MAX_LISTED} more" if len(items) > MAX_LISTED else "")


def _corrupt_errors() -> tuple[type[BaseException], ...]:
    """What rosbags (and the sqlite, lz4, bz2 and zstd libraries beneath it) raise on a bag that is
    corrupt or truncated: their own error types, and the built-in ones their parsers raise when the
    bytes are not what they expect (found by corrupting bags at random). They are caught only
    around calls into rosbags (``_messages``), never around this module's own code."""
    import apsw
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError

    if sys.version_info >= (3, 14):
        from compression.zstd import ZstdError
    else:
        from backports.zstd import ZstdError
    return (AnyReaderError, Reader1Error, Reader2Error, SerdeError, TypesysError, apsw.Error, ZstdError,
            struct.error, OSError, EOFError, ValueError, KeyError, IndexError, OverflowError, MemoryError,
            TypeError, AssertionError, RuntimeError)


def _messages(bag: Path, spec: _Spec, where: str) -> Iterator[tuple[str, Any]]:
    """The messages of ``spec.topic`` in ``bag``, (type, message) in the bag's order; each error of
    rosbags on a corrupt bag becomes a DemoError. The topic must exist and have a supported type."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    corrupt = _corrupt_errors()
    try:
        # the typestore is only used for a ROS 2 bag without message definitions (before Iron);
        # the supported types are the same in every ROS 2 release
        with AnyReader([bag], default_typestore=get_typestore(Stores.LATEST)) as reader:
            topics = reader.topics
            if spec.topic not in topics:
                have = [f"{name} ({info.msgtype or 'several types'})" for name, info in topics.items()]
                raise DemoError(f"{where}: no topic {spec.topic} in the bag; "
                                + (f"it has {_listing(have)}" if have else "it has no topics"))
            connections = topics[spec.topic].connections
            types = sorted({c.msgtype for c in connections})
            if len(types) != 1 or types[0] not in SUPPORTED:
                raise DemoError(f"{where}: topic {spec.topic} has type {_listing(types)}; supported: "
                                f"{', '.join(SUPPORTED)}")
            if spec.frames is not None and types[0] != TF:
                raise DemoError(f"{where}: frames are given, but topic {spec.topic} has type {types[0]}; "
                                f"frames PARENT:CHILD are for {TF} topics")
            for connection, _, raw in reader.messages(connections):
                yield connection.msgtype, reader.deserialize(raw, connection.msgtype)
    except corrupt as e:
        text = str(e).strip()
        reason = _short(text.splitlines()[0]) if text else type(e).__name__
        raise DemoError(f"{where}: not a readable bag ({reason})") from None


def _read(bag: Path, spec: _Spec, where: str) -> _Stream:
    """The poses of ``spec.topic`` in ``bag``, checked: finite, stamps strictly increasing."""
    ns: list[int] = []
    values: list[tuple[float, ...]] = []
    pairs: dict[tuple[str, str], None] = {}     # the frame pairs of a TFMessage topic, in order seen
    for msgtype, msg in _messages(bag, spec, where):
        if msgtype == POSE:
            ns.append(_stamp(msg.header.stamp))
            values.append(_pose(msg.pose.position, msg.pose.orientation))
        elif msgtype == TRANSFORM:
            ns.append(_stamp(msg.header.stamp))
            values.append(_pose(msg.transform.translation, msg.transform.rotation))
        else:
            for tr in msg.transforms:
                pair = (_frame(tr.header.frame_id), _frame(tr.child_frame_id))
                pairs[pair] = None
                if pair == spec.frames:
                    ns.append(_stamp(tr.header.stamp))
                    values.append(_pose(tr.transform.translation, tr.transform.rotation))
    if not ns:
        have = _listing([f"{p} -> {c}" for p, c in pairs]) if pairs else "no transforms"
        if spec.frames is not None:
            raise DemoError(f"{where}: no transform {spec.frames[0]} -> {spec.frames[1]} on {spec.topic}; "
                            f"it has {have}")
        if pairs:
            raise DemoError(f"{where}: topic {spec.topic} has type {TF}; name the frames, "
                            f"bag:PATH:{spec.topic}:PARENT:CHILD (it has {have})")
        raise DemoError(f"{where}: topic {spec.topic} has no messages")
    stamps = np.asarray(ns, dtype=np.int64)
    pose = np.asarray(values, dtype=np.float64).reshape(-1, 7)
    bad = ~np.isfinite(pose).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        part = "position" if not np.isfinite(pose[k, :3]).all() else "orientation"
        raise DemoError(f"{where}: NaN or inf in the {part} of message {k} on {spec.topic}")
    back = np.flatnonzero(np.diff(stamps) <= 0)
    if len(back):
        k = int(back[0]) + 1
        how = "repeats" if stamps[k] == stamps[k - 1] else "is before"
        raise DemoError(f"{where}: the stamp of message {k} on {spec.topic} ({_seconds(stamps[k])} s) {how} "
                        f"the stamp of message {k - 1} ({_seconds(stamps[k - 1])} s); stamps must increase")
    return _Stream(stamps, pose[:, :3], pose[:, [6, 3, 4, 5]])   # ROS (x, y, z, w) -> (w, x, y, z)


def _stamp(stamp: Any) -> int:
    """A ROS time (sec, nanosec) in nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _seconds(ns: np.integer) -> str:
    """Nanoseconds as exact decimal seconds."""
    sec, nsec = divmod(abs(int(ns)), 1_000_000_000)
    return f"{'-' * (int(ns) < 0)}{sec}.{nsec:09d}"


def _pose(p: Any, o: Any) -> tuple[float, ...]:
    """Position (x, y, z) and ROS quaternion (x, y, z, w) as 7 floats."""
    return (p.x, p.y, p.z, o.x, o.y, o.z, o.w)
