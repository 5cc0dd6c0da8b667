"""ROS 1 and ROS 2 bags through ``rosbags`` (pure Python, no ROS install): odometry, images, camera info.

A bag is a ROS 1 ``.bag`` file or a ROS 2 bag folder (sqlite3 or mcap storage); message types come
from the bag itself. Times are the messages' ``header.stamp`` [s] (the clock the robot stamped its
data with), not the recording time.

- ``nav_msgs/Odometry``: ``pose.pose.position`` and the yaw of ``pose.pose.orientation``.
- ``sensor_msgs/Image`` (encodings mono8, bgr8, rgb8, bgra8, rgba8, mono16) and
  ``sensor_msgs/CompressedImage`` (any format OpenCV decodes): BGR or grey ``uint8`` arrays.
- ``sensor_msgs/CameraInfo``: the 3x3 intrinsics ``K`` of the first message.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from decentral.errors import InputError
from sims.io.robot_files import checked_trajectory, yaw_from_quaternion
from sims.io.trajectories import Trajectory

__all__ = ["IMAGE_TYPES", "read_odometry_topic", "read_camera_info", "image_times", "iter_images"]

ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPE = "sensor_msgs/msg/CameraInfo"


def _messages(bag: str | os.PathLike, topic: str, types: tuple[str, ...], *, raw: bool = False) -> Iterator:
    """Deserialized messages of ``topic`` in ``bag`` (bag order), checking the topic's type.

    With ``raw``, yields ``(serialized bytes, is_ros2)`` instead, for readers that need only a prefix.
    """
    from rosbags.highlevel import AnyReader

    path = Path(bag)
    if not path.exists():
        raise InputError("bag not found", source=str(bag))
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as err:  # rosbags raises its own error types for every kind of unreadable bag
        raise InputError(f"not a readable ROS 1 or ROS 2 bag ({type(err).__name__}: {err})", source=str(bag)) from None
    try:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections:
            known = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
            raise InputError(f"no topic {topic!r} in the bag (topics: {known})", source=str(bag), field=topic)
        for conn in connections:
            if conn.msgtype not in types:
                raise InputError(f"topic has type {conn.msgtype}, expected {' or '.join(types)}",
                                 source=str(bag), field=topic)
        for conn, _, data in reader.messages(connections=connections):
            yield (data, reader.is2) if raw else reader.deserialize(data, conn.msgtype)
    finally:
        reader.close()


def _stamp(msg) -> float:
    return float(msg.header.stamp.sec) + 1e-9 * float(msg.header.stamp.nanosec)


def read_odometry_topic(bag: str | os.PathLike, topic: str) -> Trajectory:
    """The trajectory of a ``nav_msgs/Odometry`` topic (header stamps, position, yaw)."""
    rows = []
    for msg in _messages(bag, topic, (ODOMETRY_TYPE,)):
        pos, q = msg.pose.pose.position, msg.pose.pose.orientation
        rows.append((_stamp(msg), pos.x, pos.y, pos.z, q.x, q.y, q.z, q.w))
    arr = np.array(rows, float).reshape(-1, 8)
    if not np.all(np.isfinite(arr)):
        raise InputError("non-finite odometry", source=str(bag), field=topic)
    order = np.argsort(arr[:, 0], kind="stable")  # recording order may differ from stamp order
    arr = arr[order]
    return checked_trajectory(arr[:, 0], arr[:, 1:4], yaw_from_quaternion(*arr[:, 4:8].T), f"{bag}:{topic}")


def read_camera_info(bag: str | os.PathLike, topic: str) -> np.ndarray:
    """The intrinsics ``K`` (3, 3) of the first ``sensor_msgs/CameraInfo`` message on ``topic``."""
    for msg in _messages(bag, topic, (INFO_TYPE,)):
        K = np.asarray(getattr(msg, "k", None) if hasattr(msg, "k") else msg.K, float).reshape(3, 3)
        return K
    raise InputError("no CameraInfo message", source=str(bag), field=topic)


def _raw_stamp(data: bytes, ros2: bool) -> float:
    """``header.stamp`` [s] read from a serialized message whose first field is a std_msgs/Header.

    Both encodings put the stamp's two 32-bit words at bytes 4-12: after CDR's 4-byte encapsulation
    header in ROS 2 (byte 1 gives the endianness), after the header's ``seq`` in ROS 1 (little endian).
    """
    order = "<" if not ros2 or data[1] == 1 else ">"
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    return float(sec) + 1e-9 * float(nanosec)


def image_times(bag: str | os.PathLike, topic: str) -> np.ndarray:
    """Header stamps [s] of the image messages on ``topic``, in bag order (no image is decoded)."""
    return np.array([_raw_stamp(data, ros2) for data, ros2 in _messages(bag, topic, IMAGE_TYPES, raw=True)], float)


def _decode(msg, where: str) -> np.ndarray:
    import cv2

    if msg.__msgtype__.endswith("CompressedImage"):
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(f"cannot decode a {msg.format!r} compressed image", field=where)
        return image
    channels = {"mono8": 1, "8uc1": 1, "bgr8": 3, "rgb8": 3, "8uc3": 3, "bgra8": 4, "rgba8": 4, "mono16": 1, "16uc1": 1}
    encoding = msg.encoding.lower()
    if encoding not in channels:
        raise InputError(f"unsupported image encoding {msg.encoding!r}", field=where)
    dtype = np.uint16 if "16" in encoding else np.uint8
    if dtype == np.uint16 and msg.is_bigendian:
        dtype = np.dtype(">u2")
    data = np.frombuffer(bytes(msg.data), dtype)
    row = msg.step // np.dtype(dtype).itemsize
    if data.size < row * msg.height or row < msg.width * channels[encoding]:
        raise InputError("image data shorter than height x step", field=where)
    image = data[: row * msg.height].reshape(msg.height, row)[:, : msg.width * channels[encoding]]
    image = image.reshape(msg.height, msg.width, channels[encoding]) if channels[encoding] > 1 else image
    if dtype != np.uint8:
        image = (image.astype(np.float64) / 256.0).astype(np.uint8)
    if encoding == "rgb8":
        image = image[:, :, ::-1]
    elif encoding in ("bgra8", "rgba8"):
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR if encoding == "bgra8" else cv2.COLOR_RGBA2BGR)
    return np.ascontiguousarray(image)


def iter_images(bag: str | os.PathLike, topic: str) -> Iterator[tuple[str, np.ndarray]]:
    """``(name, image)`` per image message on ``topic``, decoded one at a time (bag order)."""
    for k, msg in enumerate(_messages(bag, topic, IMAGE_TYPES)):
        try:
            yield f"{topic}#{k}", _decode(msg, f"{topic}#{k}")
        except InputError as err:
            raise err.located(str(bag)) from None
