"""Frame rendering speed of sims.simulation.render at 1024x768, single core, against a full-frame reference.

Fixed inputs: the ``table1`` scenario (one camera, three targets + the observer: 13 nodes) and
``multi`` with 6 assemblies (6 cameras), seed 0, 20 steps each. For every camera frame we time:

- ``clean``: geometry only (floor, spheres with tags, struts), no camera effects;
- ``full``: the default camera model (exposure drift, motion blur, optical blur, sensor noise);
- ``reference``: the same geometry ray-cast naively, every sphere and strut against every pixel
  of the frame (no per-object region of interest), measured in the same run.

Target: < 100 ms per 1024x768 frame. The machine is shared, so besides wall time each
frame's CPU time (``time.process_time``, one thread) is reported: on a loaded machine it is the
single-core cost, while wall time also counts waiting for a core. Also reports the tag read rate of OpenCV's
``ArucoDetector`` (36h11, default parameters) on clean frames of one sphere at several distances,
over all yaws (the stickers bend with the sphere, so off-facing tags fail).

Usage: ``python benchmarks/render.py [--quick]``; writes ``OUT/render.json``.
"""

from __future__ import annotations

import statistics
import time

from _common import machine, parser, save  # noqa: I001  (pins threads before numpy)

import cv2
import numpy as np

from sims.simulation.render import raycast
from sims.simulation.render.renderer import RenderConfig, Renderer
from sims.simulation.scenarios import get_scenario, simulate
from sims.simulation.world.camera import CameraSpec, default_K
from sims.simulation.world.rigs import strut_camera
from sims.simulation.world.shapes import NODE_RADIUS, Shape
from sims.simulation.world.world import AssemblyTrack, World


def full_frame_reference(renderer: Renderer, rig, k: int):
    """Ray-cast every object against the whole frame (no ROI): the naive vectorized renderer."""
    original = raycast._roi

    def whole(K, points_c, pad_px, width, height):
        return 0, height, 0, width

    raycast._roi = whole
    try:
        return renderer.render_linear(rig, k)
    finally:
        raycast._roi = original


def time_frames(sim, steps: int, reps: int) -> dict:
    out = {}
    for label, config in (("clean", RenderConfig.clean()), ("full", RenderConfig())):
        renderer = Renderer(sim.world, config, np.random.default_rng(0))
        rng = np.random.default_rng(1)
        renderer.render(sim.world.cameras[0], 0, rng)  # warm caches (rays, noise pool)
        times, cpu = [], []
        for _ in range(reps):
            for k in range(steps):
                for rig in sim.world.cameras:
                    t0, c0 = time.perf_counter(), time.process_time()
                    renderer.render(rig, k, rng)
                    times.append(time.perf_counter() - t0)
                    cpu.append(time.process_time() - c0)
        out[label] = {"median_ms": 1e3 * statistics.median(times), "median_cpu_ms": 1e3 * statistics.median(cpu),
                      "frames": len(times), "p90_ms": 1e3 * float(np.percentile(times, 90))}
    renderer = Renderer(sim.world, RenderConfig.clean(), np.random.default_rng(0))
    ref, ref_cpu = [], []
    for k in range(min(steps, 5)):
        for rig in sim.world.cameras[:2]:
            t0, c0 = time.perf_counter(), time.process_time()
            full_frame_reference(renderer, rig, k)
            ref.append(time.perf_counter() - t0)
            ref_cpu.append(time.process_time() - c0)
    out["reference"] = {"median_ms": 1e3 * statistics.median(ref), "median_cpu_ms": 1e3 * statistics.median(ref_cpu),
                        "frames": len(ref)}
    out["speedup_clean_vs_reference_cpu"] = out["reference"]["median_cpu_ms"] / out["clean"]["median_cpu_ms"]
    return out


def tag_read_rates(distances, yaw_step_deg: float) -> dict:
    """Fraction of yaws at which OpenCV reads a lone sphere's tag (clean frames, default parameters)."""
    K = default_K()
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11),
                                       cv2.aruco.DetectorParameters())
    out = {}
    for dist in distances:
        hits, radius = 0, None
        yaws = np.arange(0.0, 360.0, yaw_step_deg)
        for yaw in yaws:
            steps = 1
            observer = Shape((900,), np.zeros((1, 3)))
            target = Shape((5,), np.zeros((1, 3)))
            tracks = (
                AssemblyTrack("A0", 0.3 - NODE_RADIUS, np.zeros((1, 2)), np.zeros(1), (observer,)),
                AssemblyTrack("A1", 0.3 - NODE_RADIUS, np.array([[dist + 0.15, 0.0]]), np.array([np.radians(yaw)]),
                              (target,)),
            )
            rig = strut_camera("A0", "cam0", at=(0.1, 0.0, 0.0), look_yaw=0.0, spec=CameraSpec(K))
            world = World(NODE_RADIUS, np.zeros(steps), tracks, (rig,))
            frame = Renderer(world, RenderConfig.clean(), np.random.default_rng(0)).render(rig, 0, np.random.default_rng(0))
            (node,) = frame.nodes
            radius = node["r"]
            pad = int(1.5 * node["r"])
            u, v = int(node["u"]), int(node["v"])
            roi = cv2.cvtColor(frame.image[max(v - pad, 0):v + pad, max(u - pad, 0):u + pad], cv2.COLOR_BGR2GRAY)
            _, ids, _ = detector.detectMarkers(roi)
            hits += ids is not None and 5 in ids.ravel()
        out[f"{dist:.1f} m"] = {"radius_px": round(radius, 1), "read_rate": hits / len(yaws), "yaws": len(yaws)}
    return out


def main(argv=None) -> None:
    ap = parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer frames (a smoke run)")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    steps, reps = (4, 1) if args.quick else (20, 2)
    result = {
        "benchmark": "render",
        "parameters": {"image": [1024, 768], "steps": steps, "reps": reps, "seed": 0, "cv2_threads": 1},
        "machine": machine(),
        "target_ms_per_frame": 100.0,
    }
    result["table1"] = time_frames(simulate(get_scenario("table1", steps=steps), seed=0), steps, reps)
    result["multi6"] = time_frames(simulate(get_scenario("multi", steps=steps, n_assemblies=6), seed=0), steps, reps)
    result["tag_read_rate_clean"] = tag_read_rates((0.6, 1.0, 1.5, 2.0, 2.5), 15.0 if args.quick else 5.0)
    save("render", result, args.out)


if __name__ == "__main__":
    main()
