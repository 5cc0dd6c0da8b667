"""Robots' recorded data to an observation log: the library behind ``decentral build-log``.

:func:`build_log` reads a rig (:mod:`sims.io.rig`) and every source it names, and associates them in
time explicitly:

1. **Steps** are the frames of the rig's clock camera, at their times.
2. **Other cameras' frames** go to the step nearest in time if it is within the rig's ``tolerance``
   (one frame per step: the nearest wins); the others are reported as unmatched, never moved.
3. **Odometry** trajectories are interpolated at the step times (linear position, shortest-arc yaw,
   :func:`decentral.odometry.interpolate_planar`) where a sample lies within ``tolerance``; a step
   without one is reported, and that assembly has no odometry into that step nor out of it. The
   log's ``dp``/``dtheta`` at step k are the motion from step k-1 in the root frame at k-1
   (:func:`decentral.odometry.increments`).
4. **Configurations** (and strut mounts) are each assembly's layout in force at the step time.
5. **Detections** come from ``decentral.detections/1`` files (identified detections only), or from
   running the perception front end (:func:`sims.runners.perception_run.perceive_with_log`, the
   path ``decentral perceive --log-template`` uses) on image files, a video or a bag's image topic.

What was not matched is in the :class:`BuildReport`, whose :meth:`BuildReport.summary` is one line.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from decentral.errors import InputError
from decentral.observations import Camera, Detection, ObservationLog, Odometry, Step
from decentral.odometry import increments, interpolate_planar
from sims.io.rig import Rig, RigCamera

__all__ = ["BuildReport", "build_log", "frame_times", "associate"]


@dataclass(frozen=True)
class BuildReport:
    """What :func:`build_log` matched and what it could not.

    Attributes
    ----------
    clock : str
        The camera whose frames are the steps.
    steps : int
        Steps of the log.
    frames : dict[str, int]
        Frames read per camera.
    unmatched_frames : dict[str, list[float]]
        Per camera, times of frames that went to no step (no step within tolerance, or a nearer frame).
    missing_odometry : dict[str, list[float]]
        Per assembly with an odometry source, step times with no odometry sample within tolerance.
    detections : int
        Identified detections written into the log.
    """

    clock: str
    steps: int
    frames: dict
    unmatched_frames: dict
    missing_odometry: dict
    detections: int

    def to_dict(self) -> dict:
        """Plain-JSON form."""
        return {"clock": self.clock, "steps": self.steps, "frames": self.frames, "detections": self.detections,
                "unmatched_frames": self.unmatched_frames, "missing_odometry": self.missing_odometry}

    def summary(self) -> str:
        """One line: steps, frames, detections, and what went unmatched."""
        line = (f"{self.steps} steps (frames of {self.clock}), {sum(self.frames.values())} frames of "
                f"{len(self.frames)} cameras, {self.detections} detections")
        unmatched = {k: len(v) for k, v in self.unmatched_frames.items() if v}
        missing = {k: len(v) for k, v in self.missing_odometry.items() if v}
        if unmatched:
            line += "; frames without a step: " + ", ".join(f"{k} {n}" for k, n in unmatched.items())
        if missing:
            line += "; steps without odometry: " + ", ".join(f"{k} {n}" for k, n in missing.items())
        return line


def _count_video_frames(path) -> int:
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError("cannot open the video", source=str(path))
    n = 0
    while cap.grab():
        n += 1
    cap.release()
    return n


def frame_times(camera: RigCamera, detection_frames=None) -> np.ndarray:
    """Capture times [s] of every frame of ``camera``'s source, in source order."""
    from sims.io.robot_files import read_times

    src = camera.source
    where = f"assemblies.{camera.assembly}.cameras.{camera.name}"
    if src.kind == "bag":
        from sims.io.bags import image_times

        return image_times(src.path, src.image_topic)
    if src.kind == "detections":
        stamped = [fr.t for fr in detection_frames]
        if src.times is None and src.rate is None:
            if any(t is None for t in stamped):
                k = stamped.index(None)
                raise InputError("frame has no time 't' (or give times = FILE or rate = HZ in the rig)",
                                 source=str(src.path), field=f"frames[{k}].t")
            return np.array(stamped, float)
        count = len(detection_frames)
    else:
        count = len(src.paths) if src.kind == "frames" else _count_video_frames(src.path)
    if src.times is not None:
        times = read_times(src.times)
        if len(times) != count:
            raise InputError(f"{len(times)} times for {count} frames", source=str(src.times), field=where)
        return times
    return src.start + np.arange(count) / src.rate


def associate(frame_t: np.ndarray, step_t: np.ndarray, tolerance: float) -> tuple[dict[int, int], list[int]]:
    """Frame index -> step index for the frames within ``tolerance`` of a step (the nearest frame per step).

    Returns the mapping and the indices of the frames left unmatched.
    """
    best: dict[int, tuple[float, int]] = {}
    unmatched = []
    for i, t in enumerate(frame_t):
        j = int(np.clip(np.searchsorted(step_t, t), 1, len(step_t) - 1)) if len(step_t) > 1 else 0
        j = min((j - 1, j) if len(step_t) > 1 else (0,), key=lambda s: abs(step_t[s] - t))
        gap = abs(step_t[j] - t)
        if gap > tolerance:
            unmatched.append(i)
        elif j in best and best[j][0] <= gap:
            unmatched.append(i)
        else:
            if j in best:
                unmatched.append(best[j][1])
            best[j] = (gap, i)
    return {i: j for j, (_, i) in best.items()}, sorted(unmatched)


def _odometry(rig: Rig, step_t: np.ndarray) -> tuple[list[dict[str, Odometry]], dict[str, list[float]]]:
    """Per step, assembly -> odometry into that step; per assembly, the step times without odometry."""
    from sims.io.robot_files import read_trajectory_file

    per_step: list[dict[str, Odometry]] = [{} for _ in step_t]
    missing = {}
    for a in rig.assemblies:
        if a.odometry is None:
            continue
        if a.odometry.topic is None:
            traj = read_trajectory_file(a.odometry.path)
        else:
            from sims.io.bags import read_odometry_topic

            traj = read_odometry_topic(a.odometry.path, a.odometry.topic)
        p, yaw, ok = interpolate_planar(traj.t, traj.p, traj.yaw, step_t, rig.tolerance)
        dp, dtheta = increments(p, yaw)
        for k in range(1, len(step_t)):
            if ok[k] and ok[k - 1]:
                per_step[k][a.name] = Odometry(dp[k - 1], float(dtheta[k - 1]))
        missing[a.name] = [float(t) for t in step_t[~ok]]
    return per_step, missing


def _images(camera: RigCamera) -> Iterator[tuple[str, np.ndarray]]:
    src = camera.source
    if src.kind == "bag":
        from sims.io.bags import iter_images

        return iter_images(src.path, src.image_topic)
    from agents.perception.frame_reader import iter_frames

    return iter_frames([str(p) for p in src.paths] if src.kind == "frames" else [str(src.path)])


def _perceive(camera: RigCamera, template: ObservationLog, matched: dict[int, int], options: dict):
    """Perceived identified detections of ``camera``'s matched frames: step index -> detections."""
    from agents.perception.detectors import DEFAULT_DETECTOR, LOG_MIN_SCORE
    from sims.runners.perception_run import perceive_with_log
    from sims.io.detections_json import assemble_log

    order = sorted(matched, key=matched.get)  # frame indices in step order
    steps = [matched[i] for i in order]
    sub = replace(template, steps=tuple(template.steps[j] for j in steps))
    wanted, size = set(order), {}

    def chosen():
        for i, (name, image) in enumerate(_images(camera)):
            if i in wanted:
                size.setdefault(camera.key, (image.shape[1], image.shape[0]))
                yield name, image

    contiguous = steps == list(range(steps[0], steps[0] + len(steps))) if steps else True
    perceived = perceive_with_log(chosen(), sub, camera.key, motion="auto" if contiguous else "flow", **options)
    min_score = LOG_MIN_SCORE[options.get("detector", DEFAULT_DETECTOR)]
    filled = assemble_log(sub, {camera.key: perceived.frames}, min_score=min_score, image_sizes=size)
    return {j: filled.steps[n].detections.get(camera.key, ()) for n, j in enumerate(steps)}


def build_log(rig: Rig) -> tuple[ObservationLog, BuildReport]:
    """Build the ``decentral.log/1`` of a rig's recorded data (see the module docstring).

    Raises
    ------
    InputError
        Naming the file and field of any unreadable or inconsistent source.
    """
    from sims.io.detections_json import read_detections

    if not isinstance(rig, Rig):
        raise InputError(f"expected a Rig (sims.io.rig.read_rig), got {type(rig).__name__}", field="rig")
    cams = rig.cameras
    detection_files = {key: read_detections(cam.source.path) for key, cam in cams.items()
                       if cam.source.kind == "detections"}
    times = {key: frame_times(cam, detection_files.get(key)) for key, cam in cams.items()}
    for key, t in times.items():  # times and detections files check their own order; bags are checked here
        bad = np.flatnonzero(np.diff(t) <= 0)
        if len(bad):
            src = cams[key].source
            raise InputError(f"frame times must increase ({t[bad[0] + 1]:g} after {t[bad[0]]:g} at frame "
                             f"{bad[0] + 1})", source=str(src.path) if src.path else None,
                             field=src.image_topic or f"camera {key}")
    step_t = times[rig.clock]
    if len(step_t) == 0:
        raise InputError("the clock camera has no frames", field="clock")
    matches, unmatched = {}, {}
    for key, t in times.items():
        matches[key], lost = associate(t, step_t, rig.tolerance)
        unmatched[key] = [float(t[i]) for i in lost]
    odometry, missing = _odometry(rig, step_t)
    K = {}
    for key, cam in cams.items():
        if cam.K is not None:
            K[key] = cam.K
        else:
            from sims.io.bags import read_camera_info
            from sims.io.log_json import parse_camera_matrix

            K[key] = parse_camera_matrix(read_camera_info(cam.source.path, cam.source.info_topic).tolist(),
                                         f"{cam.source.info_topic}.K")
    cameras = {key: Camera(cam.assembly, cam.name, K[key], cam.strut_in_root, cam.cam_in_strut)
               for key, cam in cams.items()}
    steps = [Step(float(t), {a.name: dict(a.layout.at(float(t))) for a in rig.assemblies}, odometry[k], {},
                  {f"{a.name}/{cam}": pose for a in rig.assemblies for cam, pose in a.layout.mounts_at(float(t)).items()})
             for k, t in enumerate(step_t)]
    template = ObservationLog(rig.node_radius, tuple(a.name for a in rig.assemblies), cameras, tuple(steps))
    per_step: list[dict] = [{} for _ in steps]
    for key, cam in cams.items():
        if key in detection_files:
            frames = detection_files[key]
            found = {j: tuple(Detection(int(d.node), d.u, d.v, d.r) for d in frames[i].detections if d.node is not None)
                     for i, j in matches[key].items()}
        else:
            found = _perceive(cam, template, matches[key], rig.perception)
        for j, dets in found.items():
            per_step[j][key] = dets
    log = replace(template, steps=tuple(replace(s, detections=d) for s, d in zip(template.steps, per_step)))
    report = BuildReport(rig.clock, len(steps), {k: len(t) for k, t in times.items()}, unmatched, missing,
                         sum(len(d) for s in per_step for d in s.values()))
    return log, report
