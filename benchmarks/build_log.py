"""How long ``build-log`` takes to turn a recorded run into a ``decentral.log/1``, single core.

Fixed inputs: a simulated ``multi`` run (3 assemblies, one camera each, seed 0, ``--steps`` steps,
60 by default) written as robot recordings (:func:`sims.simulation.robot_data.write_robot_data`):

- ``ros1`` / ``ros2``: ``nav_msgs/Odometry`` in a ROS 1 bag / ROS 2 bag plus timed detection files;
- ``ros2_images``: the same odometry with the rendered camera images (``sensor_msgs/Image``, 1024x768
  bgr8) and ``CameraInfo`` in a ROS 2 bag, so ``build-log`` also runs perception on every frame;
- ``tum``: TUM odometry files plus detection files;
- ``ros2_images_one_camera``: ``table1`` (one observer camera, three targets) as an image bag.

Each case is timed end to end (read the rig, read the bag, associate, interpolate, perceive, build)
with ``--repeats`` repeats; the median wall time is reported, and the median CPU time of this
process (on a shared machine wall time also counts waiting for a core). References measured in the same run: reading
the simulator's own ``log.json`` (the cheapest way to the same log) and, for the image case,
perception alone on the same in-memory frames (``perceive_with_log``), whose ratio shows what the
bag adds. Target: a bag of a 60-step run converts in under 5 s.

Usage: ``python benchmarks/build_log.py [--steps 60] [--repeats 3] [--out out/benchmarks]``; writes
``OUT/build_log.json``.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    from _common import machine, parser, save  # noqa: I001  (pins threads before numpy)

    parser = parser(__doc__)
    parser.add_argument("--steps", type=int, default=60, help="steps of the simulated run (default 60)")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per case (default 3)")
    args = parser.parse_args(argv)

    from sims.runners.build_log import build_log
    from sims.io.log_json import read_log, write_log
    from sims.io.rig import read_rig
    from sims.simulation.robot_data import write_robot_data
    from sims.simulation.scenarios import get_scenario, simulate

    sim = simulate(get_scenario("multi", n_assemblies=3, steps=args.steps), seed=0)
    results: dict = {"steps": args.steps, "assemblies": 3, "cameras": 3, "repeats": args.repeats, "cases": {}}

    cpu: dict[str, float] = {}

    def median_time(fn, label: str = "") -> tuple[float, list[float]]:
        """Median wall time of ``fn`` over the repeats (its median CPU time goes to ``cpu[label]``)."""
        times, cpus = [], []
        for _ in range(args.repeats):
            start, start_cpu = time.perf_counter(), time.process_time()
            fn()
            times.append(time.perf_counter() - start)
            cpus.append(time.process_time() - start_cpu)
        cpu[label] = statistics.median(cpus)
        return statistics.median(times), times

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        write_log(root / "log.json", sim.log)
        reference, ref_times = median_time(lambda: read_log(root / "log.json"))
        results["reference_read_log_json_s"] = {"median": reference, "all": ref_times}
        for case, fmt, images in (("tum", "tum", False), ("ros1", "ros1", False), ("ros2", "ros2", False),
                                  ("ros2_images", "ros2", True)):
            rig = write_robot_data(sim, root / case, odometry=fmt, images=images)
            seconds, all_times = median_time(lambda rig=rig: build_log(read_rig(rig)), case)
            size = sum(p.stat().st_size for p in (root / case).rglob("*") if p.is_file())
            results["cases"][case] = {"median_s": seconds, "all_s": all_times, "bytes": size,
                                      "ratio_to_read_log_json": seconds / reference,
                                      "under_5_s": seconds < 5.0, "cpu_median_s": cpu[case]}
            print(f"{case:16s} {seconds:7.3f} s  ({size / 1e6:.1f} MB of recordings)", flush=True)
        one = simulate(get_scenario("table1", steps=args.steps), seed=0)  # one camera
        rig = write_robot_data(one, root / "one_camera", odometry="ros2", images=True)
        seconds, all_times = median_time(lambda: build_log(read_rig(rig)), "one")
        results["cases"]["ros2_images_one_camera"] = {"median_s": seconds, "all_s": all_times, "cpu_median_s": cpu["one"],
                                                      "ratio_to_read_log_json": seconds / reference,
                                                      "under_5_s": seconds < 5.0}
        print(f"{'ros2_images_1cam':16s} {seconds:7.3f} s", flush=True)
        # perception alone on the same frames, in memory: what the image bag adds on top of it
        from sims.runners.perception_run import perceive_with_log
        from sims.simulation.render.frame_files import render_frames
        from sims.simulation.render.renderer import RenderConfig

        frames = {key: [] for key in sim.log.cameras}
        for _, key, frame in render_frames(sim, 0, RenderConfig()):
            frames[key].append((key, frame.image))
        alone, alone_times = median_time(
            lambda: [perceive_with_log(iter(frames[key]), sim.log, key) for key in sim.log.cameras], "alone")
        results["reference_perception_alone_s"] = {"median": alone, "all": alone_times, "cpu_median": cpu["alone"]}
        results["cases"]["ros2_images"]["ratio_to_perception_alone"] = results["cases"]["ros2_images"]["median_s"] / alone
    results["machine"] = machine()
    save("build_log", results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
