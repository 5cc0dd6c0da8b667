"""A simulated run written as a robot would record it: a rig file plus odometry trajectories, per-camera
detections or images, as plain files or in a ROS 1 / ROS 2 bag.

This is what ``decentral simulate --robot-data DIR`` writes: a stand-in for real recordings that
``decentral build-log DIR/rig.toml`` turns back into the simulator's observation log (the tests and
the README's walk-through use it). Odometry is the log's own (noisy) odometry dead-reckoned from the
identity into one trajectory per assembly, sampled at the frame times; where the log has no
odometry for a step the sample at that step is left out (and the true motion bridges the gap, so the
rebuilt log lacks odometry into and out of that step).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from decentral.errors import InputError
from decentral.geometry import wrap_angle, yaw_of
from sims.io.trajectories import Trajectory, trajectory_lines
from sims.simulation.scenarios.base import Simulation

__all__ = ["ODOMETRY_FORMATS", "odometry_trajectories", "write_robot_data", "write_bag"]

#: how odometry (and, for bags, images) are stored
ODOMETRY_FORMATS = ("tum", "csv", "ros1", "ros2")


def odometry_trajectories(sim: Simulation) -> dict[str, Trajectory]:
    """Per assembly, the log's odometry integrated into poses, sampled at the steps where it is defined."""
    log, truth = sim.log, sim.truth.poses
    out = {}
    for name in log.assemblies:
        p, yaw = np.zeros(3), 0.0
        rows = [(log.steps[0].t, *p, yaw)]
        for k in range(1, len(log.steps)):
            odo = log.steps[k].odometry.get(name)
            if odo is None:  # bridge the gap with the true motion; no sample at this step
                R0 = truth.R[name][k - 1]
                dp = R0.T @ (truth.p[name][k] - truth.p[name][k - 1])
                dth = float(yaw_of(R0.T @ truth.R[name][k]))
            else:
                dp, dth = odo.dp, odo.dtheta
            c, s = np.cos(yaw), np.sin(yaw)
            p = p + np.array([c * dp[0] - s * dp[1], s * dp[0] + c * dp[1], dp[2]])
            yaw = float(wrap_angle(yaw + dth))
            if odo is not None:
                rows.append((log.steps[k].t, *p, yaw))
        arr = np.array(rows)
        out[name] = Trajectory(arr[:, 0], arr[:, 1:4], arr[:, 4])
    return out


def _toml(value) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(float(value)) if not isinstance(value, (bool, int, np.integer)) else str(value).lower()


def _toml_key(key) -> str:
    key = str(key)
    return key if key.replace("_", "").replace("-", "").isalnum() else _toml(key)


def write_bag(path: str | os.PathLike, version: int, odometry: dict[str, Trajectory],
              images: dict[str, list[tuple[float, np.ndarray]]] | None = None,
              infos: dict[str, np.ndarray] | None = None, compressed: bool = False) -> Path:
    """Write a ROS 1 (``version=1``, ``path`` a ``.bag`` file) or ROS 2 (``version=2``, a folder) bag.

    ``odometry``: topic -> trajectory (``nav_msgs/Odometry``, frame ``odom``); ``images``: topic ->
    ``(time, BGR uint8 image)`` list (``sensor_msgs/Image``, bgr8, or with ``compressed``
    ``sensor_msgs/CompressedImage``, PNG); ``infos``: topic -> K (``sensor_msgs/CameraInfo``, one message).
    """
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    T = store.types
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError("output folder does not exist", source=str(path))
    staging = path.with_name(f".{path.name}.part")  # the bag is written whole in here, then moved over ``path``
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    tmp = staging / path.name

    def header(t: float, frame: str):
        sec = int(np.floor(t))
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
        if version == 1:
            return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def odom_msg(t, p, yaw):
        geo = "geometry_msgs/msg/"
        pose = T[geo + "Pose"](position=T[geo + "Point"](x=p[0], y=p[1], z=p[2]),
                               orientation=T[geo + "Quaternion"](x=0.0, y=0.0, z=np.sin(yaw / 2), w=np.cos(yaw / 2)))
        vec = T[geo + "Vector3"](x=0.0, y=0.0, z=0.0)
        return T["nav_msgs/msg/Odometry"](
            header=header(t, "odom"), child_frame_id="base_link",
            pose=T[geo + "PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T[geo + "TwistWithCovariance"](twist=T[geo + "Twist"](linear=vec, angular=vec), covariance=np.zeros(36)))

    def image_msg(t, image):
        if compressed:
            import cv2

            ok, data = cv2.imencode(".png", image)
            return T["sensor_msgs/msg/CompressedImage"](header=header(t, "camera"), format="png", data=data.reshape(-1))
        h, w = image.shape[:2]
        return T["sensor_msgs/msg/Image"](header=header(t, "camera"), height=h, width=w, encoding="bgr8",
                                          is_bigendian=0, step=3 * w, data=np.ascontiguousarray(image).reshape(-1))

    def info_msg(K, t=0.0):
        fields = dict(header=header(t, "camera"), height=0, width=0, distortion_model="plumb_bob",
                      binning_x=0, binning_y=0,
                      roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                                 do_rectify=False))
        arrays = {"d": np.zeros(5), "k": np.asarray(K, float).reshape(9), "r": np.eye(3).reshape(9),
                  "p": np.hstack([K, np.zeros((3, 1))]).reshape(12)}
        fields.update({(k.upper() if version == 1 else k): v for k, v in arrays.items()})
        return T["sensor_msgs/msg/CameraInfo"](**fields)

    messages = []  # (time, topic, type, message)
    for topic, traj in odometry.items():
        messages += [(t, topic, "nav_msgs/msg/Odometry", odom_msg(t, p, y)) for t, p, y in zip(traj.t, traj.p, traj.yaw)]
    for topic, frames in (images or {}).items():
        kind = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
        messages += [(t, topic, kind, image_msg(t, im)) for t, im in frames]
    for topic, K in (infos or {}).items():
        messages.append((0.0, topic, "sensor_msgs/msg/CameraInfo", info_msg(K)))
    messages.sort(key=lambda m: m[0])
    if version == 1:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(tmp), store.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        writer, serialize = Writer(tmp, version=9), store.serialize_cdr
    with writer:
        conns = {}
        for t, topic, kind, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, kind, typestore=store)
            writer.write(conns[topic], int(round(t * 1e9)) + 1, serialize(msg, kind))
    if path.is_dir():
        shutil.rmtree(path)
    tmp.replace(path)
    staging.rmdir()
    return path


def write_robot_data(sim: Simulation, outdir: str | os.PathLike, *, odometry: str = "tum",
                     images: bool = False, seed: int = 0) -> Path:
    """Write ``sim`` as robot recordings into ``outdir`` and return the path of its ``rig.toml``.

    Parameters
    ----------
    odometry : {"tum", "csv", "ros1", "ros2"}
        Odometry as ``<NAME>.tum`` / ``<NAME>.csv`` trajectories, or as ``nav_msgs/Odometry``
        topics ``/<NAME>/odom`` of ``run.bag`` (ROS 1) or the ``run`` bag folder (ROS 2).
    images : bool
        Render the cameras' frames (seeded by ``seed``) and give them to ``build-log`` to perceive:
        PNG files with a times file, or (bags) ``sensor_msgs/Image`` topics ``/<NAME>/<CAM>/image``
        with ``CameraInfo`` on ``/<NAME>/<CAM>/camera_info``. Without images, each camera's
        identified detections go to ``<NAME>_<CAM>.json`` (``decentral.detections/1`` with times).
    """
    from sims.io.atomic import write_atomic
    from sims.io.detections_json import DetectionFrame, DetectionRecord, write_detections
    from sims.simulation.scenarios.output import prepare_outdir

    if odometry not in ODOMETRY_FORMATS:
        raise InputError(f"unknown odometry format {odometry!r} ({', '.join(ODOMETRY_FORMATS)})", field="odometry")
    out = prepare_outdir(outdir)
    log = sim.log
    times = [s.t for s in log.steps]
    traj = odometry_trajectories(sim)
    bag = {"ros1": "run.bag", "ros2": "run"}.get(odometry)
    rig = ['format = "decentral.rig/1"', f"node_radius = {log.node_radius!r}",
           f"tolerance = {round(0.25 * float(np.min(np.diff(times))), 6) if len(times) > 1 else 0.05!r}", ""]
    rendered: dict[str, list] = {key: [] for key in log.cameras}
    if images:
        from sims.simulation.render.frame_files import render_frames
        from sims.simulation.render.renderer import RenderConfig

        noisy = sim.truth.meta.get("config", {}).get("noise", True)
        for k, key, frame in render_frames(sim, seed, RenderConfig() if noisy else RenderConfig.clean()):
            rendered[key].append((times[k], frame.image))
    for name in log.assemblies:
        rig.append(f"[assemblies.{name}]")
        layouts, last = [], None
        for s in log.steps:
            cur = {"nodes": {str(n): list(map(float, c)) for n, c in s.config.get(name, {}).items()}}
            mounts = {key.split("/", 1)[1]: {"R": m.R.tolist(), "p": m.p.tolist()}
                      for key, m in s.mounts.items() if key.startswith(name + "/")}
            if mounts:
                cur["mounts"] = mounts
            if cur != last:
                layouts.append({"t": s.t, **cur})
                last = cur
        if len(layouts) > 1 or "mounts" in layouts[0]:
            from sims.io.atomic import write_json_atomic

            write_json_atomic(out / f"{name}_layout.json", {"format": "decentral.layout/1", "layouts": layouts})
            rig.append(f'layout = "{name}_layout.json"')
        else:
            rig.append(f"nodes = {_toml({int(n): c for n, c in layouts[0]['nodes'].items()})}")
        if odometry in ("tum", "csv"):
            text = "\n".join(trajectory_lines(traj[name], odometry)[f".{odometry}"]) + "\n"
            write_atomic(out / f"{name}.{odometry}", lambda fh, text=text: fh.write(text))
            rig.append(f'odometry = {{ file = "{name}.{odometry}" }}')
        else:
            rig.append(f'odometry = {{ bag = "{bag}", topic = "/{name}/odom" }}')
        rig.append("")
        for cam in (c for c in log.cameras.values() if c.assembly == name):
            rig.append(f"[assemblies.{name}.cameras.{cam.name}]")
            if not (images and bag):
                rig.append(f"K = {_toml(cam.K.tolist())}")
            for key, pose in (("strut_in_root", cam.strut_in_root), ("cam_in_strut", cam.cam_in_strut)):
                rig.append(f"{key} = {_toml({'R': pose.R.tolist(), 'p': pose.p.tolist()})}")
            stem = f"{name}_{cam.name}"
            if images and bag:
                rig += [f'bag = "{bag}"', f'image_topic = "/{name}/{cam.name}/image"',
                        f'info_topic = "/{name}/{cam.name}/camera_info"']
            elif images:
                folder = out / "frames" / name / cam.name
                folder.mkdir(parents=True, exist_ok=True)
                import cv2

                for k, (_, image) in enumerate(rendered[cam.key]):
                    cv2.imwrite(str(folder / f"{k:05d}.png"), image)
                text = "\n".join(repr(t) for t in times) + "\n"
                write_atomic(out / f"{stem}.times.txt", lambda fh, text=text: fh.write(text))
                rig += [f'frames = "frames/{name}/{cam.name}/*.png"', f'times = "{stem}.times.txt"']
            else:
                frames = [DetectionFrame(f"{k:05d}", tuple(DetectionRecord(d.u, d.v, d.r, 1.0, d.node, None)
                                                           for d in s.detections.get(cam.key, ())), s.t)
                          for k, s in enumerate(log.steps)]
                write_detections(out / f"{stem}.json", frames)
                rig.append(f'detections = "{stem}.json"')
            rig.append("")
    if bag:
        write_bag(out / bag, 1 if odometry == "ros1" else 2, {f"/{n}/odom": tr for n, tr in traj.items()},
                  {f"/{c.assembly}/{c.name}/image": rendered[c.key] for c in log.cameras.values()} if images else None,
                  {f"/{c.assembly}/{c.name}/camera_info": c.K for c in log.cameras.values()} if images else None)
    text = "\n".join(rig) + "\n"
    write_atomic(out / "rig.toml", lambda fh: fh.write(text))
    return out / "rig.toml"
