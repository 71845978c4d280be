"""Writing ROS 1 and ROS 2 (sqlite3, MCAP) bags of poses in tests, with rosbags' writers."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

POSE, TRANSFORM, TF = "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped", "tf2_msgs/msg/TFMessage"
BASE_NS = 1_700_000_000 * 10**9  # the first stamp, an epoch time as a recorder writes


def _typestores() -> dict[str, Typestore]:
    ros1 = get_typestore(Stores.ROS1_NOETIC)   # noetic's store lacks tf2_msgs: register it
    ros1.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF))
    ros2 = get_typestore(Stores.ROS2_HUMBLE)
    return {"ros1": ros1, "sqlite3": ros2, "mcap": ros2}


STORES = _typestores()


def _header(ts: Typestore, ns: int, frame: str) -> Any:
    T = ts.types
    extra = {"seq": 0} if ts is STORES["ros1"] else {}
    stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **extra)


def _xyzw(ts: Typestore, q: np.ndarray) -> Any:
    return ts.types["geometry_msgs/msg/Quaternion"](x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0]))


def pose(ts: Typestore, ns: int, x: np.ndarray, q: np.ndarray, frame: str = "world") -> Any:
    """A PoseStamped at x (3,), q (4,) (w, x, y, z), stamped ns."""
    T = ts.types
    point = T["geometry_msgs/msg/Point"](x=float(x[0]), y=float(x[1]), z=float(x[2]))
    return T[POSE](header=_header(ts, ns, frame), pose=T["geometry_msgs/msg/Pose"](position=point,
                                                                                  orientation=_xyzw(ts, q)))


def transform(ts: Typestore, ns: int, x: np.ndarray, q: np.ndarray, parent: str, child: str) -> Any:
    """A TransformStamped from parent to child, x (3,), q (4,) (w, x, y, z), stamped ns."""
    T = ts.types
    v = T["geometry_msgs/msg/Vector3"](x=float(x[0]), y=float(x[1]), z=float(x[2]))
    return T[TRANSFORM](header=_header(ts, ns, parent), child_frame_id=child,
                        transform=T["geometry_msgs/msg/Transform"](translation=v, rotation=_xyzw(ts, q)))


def write_bag(path: Path, kind: str, topics: dict[str, tuple[str, list[Any]]]) -> Path:
    """A bag of ``kind`` (ros1, sqlite3, mcap) at ``path`` (``.bag`` added for ros1) holding, per
    topic, messages of one type, received 1 ms apart in the given order."""
    ts = STORES[kind]
    if kind == "ros1":
        path = path.with_suffix(".bag")
        writer: Any = Writer1(path)
    else:
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=9, storage_plugin=plugin)
    serialize = ts.serialize_ros1 if kind == "ros1" else ts.serialize_cdr
    with writer:
        for topic, (msgtype, msgs) in topics.items():
            connection = writer.add_connection(topic, msgtype, typestore=ts)
            for k, msg in enumerate(msgs):
                writer.write(connection, BASE_NS + k * 1_000_000, serialize(msg, msgtype))
    return path
