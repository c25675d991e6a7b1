"""Writes ROS bags of ``sensor_msgs/JointState`` with rosbags' own writers, for the bag tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

STORAGES = {"ros1": None, "db3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}


def bag_path(tmp: Path, kind: str, name: str = "run") -> Path:
    """Where a bag of ``kind`` (ros1, db3, mcap) goes: a .bag file, or a ROS2 bag folder."""
    return tmp / (f"{name}.bag" if kind == "ros1" else name)


def write_joint_states(path: Path, kind: str, stamps_ns, names, position, velocity=None, effort=None,
                       topic: str = "/joint_states", arrivals_ns=None, per_message_names=None) -> Path:
    """One JointState message per stamp; ``per_message_names[k]`` (optional) replaces ``names``
    for message k, with its own rows of values (lists of one value per name)."""
    ros2 = kind != "ros1"
    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    msg_t = store.types["sensor_msgs/msg/JointState"]
    header_t, time_t = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    writer = Writer2(path, version=9, storage_plugin=STORAGES[kind]) if ros2 else Writer1(path)
    serialize = store.serialize_cdr if ros2 else store.serialize_ros1
    with writer as w:
        conn = w.add_connection(topic, msg_t.__msgtype__, typestore=store)
        for k, stamp in enumerate(stamps_ns):
            stamp = int(stamp)
            header = header_t(stamp=time_t(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="",
                              **({} if ros2 else {"seq": k}))
            row = (lambda a: np.asarray([] if a is None else a[k], dtype=np.float64))
            msg = msg_t(header=header, name=list(per_message_names[k] if per_message_names else names),
                        position=row(position), velocity=row(velocity), effort=row(effort))
            arrival = int(arrivals_ns[k]) if arrivals_ns is not None else stamp
            w.write(conn, arrival, serialize(msg, msg_t.__msgtype__))
    return path


def write_strings(path: Path, kind: str, topic: str = "/joint_states") -> Path:
    """A bag whose topic carries std_msgs/String, not joint states."""
    ros2 = kind != "ros1"
    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    msg_t = store.types["std_msgs/msg/String"]
    writer = Writer2(path, version=9, storage_plugin=STORAGES[kind]) if ros2 else Writer1(path)
    serialize = store.serialize_cdr if ros2 else store.serialize_ros1
    with writer as w:
        conn = w.add_connection(topic, msg_t.__msgtype__, typestore=store)
        for k in range(5):
            w.write(conn, 10**9 + k, serialize(msg_t(data="hello"), msg_t.__msgtype__))
    return path
