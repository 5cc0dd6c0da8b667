"""Perception front end: frames per second on one core, detection and id quality, and AprilTag 3 beside it.

Two sets of frames:

- ``varied`` (default): image-plane sequences of :mod:`sims.lab.experiments.varied_scenes` at 1024 x 768
  with 5-10 spheres (floors of several kinds, colours close to the floor's, 15-90 px radius,
  highlights, lighting gradients, tags on the cap, occlusion by spheres and struts, smear), on the
  held-out scene seeds (no parameter was tuned on them; ``--tuning`` adds the tuning seeds), each
  circle detector of ``--detectors`` side by side (default all: ``hough``, the default, and the
  opt-in ``rim``, ``symmetry`` and ``learned``). Per scene and detector: recall (a detection within max(2 px, 0.1 r) of a
  sphere's centre and 10 % of its radius; spheres at least half visible), radius error, false and double circles per sphere, wrong ids, ids carried
  through frames without a tag read (:mod:`sims.lab.experiments.perception_scores`). Tag reads, ours
  (the default reader inside our circles: the AprilTag 3 library, OpenCV's quads where it reads
  nothing; no tracking) against the AprilTag 3 C library on the whole grey frame (``pupil-apriltags``, the ``bench`` extra; skipped with a note when not installed):
  share of facing tags read, wrong ids, CPU time per frame.
- ``rendered``: the 3-D renderer's ``table1`` and ``multi`` scenarios (seed 0), images only and with
  the log's camera model (see docs/perception.md).
- ``mottled``: the held-out scenes of :mod:`sims.lab.experiments.mottled_scenes` (tagged discs on
  blotchy floors, a quarter of the frames with no disc; ``--frames`` frames each, at most 10),
  each detector of ``--detectors`` alone, scored as the varied scenes are
  (:mod:`sims.lab.experiments.perception_scores`; discs counted when at least 90 % visible): strict
  recall, false and double circles per frame, CPU per frame.

Times: CPU seconds of this process (``time.process_time``; BLAS and OpenCV pinned to one thread, so
one core's work) and wall seconds; each sequence runs ``--repeats`` times and per frame the smallest
time counts (other processes on a shared machine only add time), then the median over frames. The
load average at start and end is saved with the results. The reference measured in the same run:
AprilTag 3 on the same frames, and OpenCV's ``HoughCircles(HOUGH_GRADIENT_ALT)`` (FINDINGS'
detector).

Usage: ``python benchmarks/perception.py [--scenes varied rendered] [--frames 30] [--repeats 3]
[--detectors hough rim symmetry] [--scenes-max N] [--out DIR]``; writes ``perception_varied.{json,md}``,
``perception.{json,png}`` and/or ``perception_mottled.json`` under ``--out``
(default ``out/benchmarks``; pass ``--out benchmarks/results`` to replace the committed results).
"""

from __future__ import annotations

import time

from _common import machine, output, parser, save, save_figure  # noqa: I001  (pins threads before numpy)

from sims.io.atomic import write_atomic

import cv2
import numpy as np

from agents.perception.detectors import DETECTORS

cv2.setNumThreads(1)


def _render(name: str, steps: int):
    from sims.simulation.render.frame_files import render_frames
    from sims.simulation.render.renderer import RenderConfig
    from sims.simulation.scenarios import get_scenario, simulate

    sim = simulate(get_scenario(name, steps=steps), seed=0)
    frames: dict[str, list] = {}
    for k, key, frame in render_frames(sim, 0, RenderConfig()):
        frames.setdefault(key, []).append((k, frame))
    return sim, frames


def _match(dets, nodes, w, h):
    """Greedy nearest matching of detections to truth nodes; returns (pairs, counted nodes)."""
    counted = [n for n in nodes if n["visible"] >= 0.5 and n["su"] - n["sr"] >= 0 and n["sv"] - n["sr"] >= 0
               and n["su"] + n["sr"] <= w - 1 and n["sv"] + n["sr"] <= h - 1]
    cand = []
    for i, d in enumerate(dets):
        for n in nodes:
            e = np.hypot(d.circle.u - n["su"], d.circle.v - n["sv"])
            if e < 0.5 * n["sr"]:
                cand.append((e, i, n["id"]))
    pairs, used_d, used_n = [], set(), set()
    for e, i, nid in sorted(cand):
        if i in used_d or nid in used_n:
            continue
        used_d.add(i)
        used_n.add(nid)
        pairs.append((i, nid))
    return pairs, counted


def _run(sim, frames, mode: str, repeats: int = 1, detector: str = "hough") -> dict:
    from agents.perception import Perception, make_detector
    from agents.perception.apriltag3 import make_identifier
    from agents.perception.motion import odometry_homography
    from agents.perception.sphere_tags import SphereTagIdentifier

    out = {"seconds": [], "cpu_seconds": [], "stage_seconds": {}, "detections": 0, "matched": 0, "counted_nodes": 0,
           "matched_counted": 0, "radius_rel_err": [], "centre_err_px": [], "identified": 0, "id_correct": 0,
           "id_switches": 0, "untracked": 0, "node_id_changes": 0, "visible_per_frame": []}
    log = sim.log
    for key, seq in frames.items():
        cam = log.cameras[key]
        if mode == "sphere":  # with the log: camera model, and the observer's odometry for the tracker
            ident = SphereTagIdentifier(cam.K, log.node_radius)
            p = Perception(make_detector(detector), ident, motion=None)
        else:  # images only: image registration for the tracker
            ident = make_identifier()
            p = Perception(make_detector(detector), ident)
        cpu_t = np.full((repeats, len(seq)), np.inf)
        wall_t = np.full((repeats, len(seq)), np.inf)
        stage_t: dict[str, np.ndarray] = {}
        for rep, i, k, frame in ((rep, i, k, f) for rep in range(repeats) for i, (k, f) in enumerate(seq)):
            if i == 0:  # each repeat runs the whole sequence again from a fresh tracker
                p.reset()
                last_track: dict[int, int] = {}
                last_node: dict[int, int] = {}
            img = frame.image
            h, w = img.shape[:2]
            start, cpu = time.perf_counter(), time.process_time()
            given = None
            if mode == "sphere":
                step = log.steps[k]
                R = log.camera_pose(key, step).R
                ident.set_view(R, [n for c in step.config.values() for n in c])
                odo = step.odometry.get(cam.assembly) if k > 0 else None
                if odo is not None:
                    given = odometry_homography(cam.K, R, odo.dtheta)
            dets, secs = p.process(img, motion=given)
            cpu_t[rep, i] = time.process_time() - cpu
            wall_t[rep, i] = time.perf_counter() - start
            for name, v in secs.items():
                stage_t.setdefault(name, np.full((repeats, len(seq)), np.inf))[rep, i] = v
            if rep == repeats - 1:  # per frame, the least interfered-with repeat
                out["cpu_seconds"].append(float(cpu_t[:, i].min()))
                out["seconds"].append(float(wall_t[:, i].min()))
                for name, v in stage_t.items():
                    out["stage_seconds"].setdefault(name, []).append(float(v[:, i].min()))
            if rep > 0:  # the outputs repeat exactly; quality is counted once
                continue
            pairs, counted = _match(dets, frame.nodes, w, h)
            counted_ids = {n["id"] for n in counted}
            truth = {n["id"]: n for n in frame.nodes}
            out["visible_per_frame"].append(len(counted))
            out["detections"] += len(dets)
            out["matched"] += len(pairs)
            out["counted_nodes"] += len(counted)
            for i, nid in pairs:
                d, n = dets[i], truth[nid]
                out["matched_counted"] += nid in counted_ids
                if n["visible"] > 0.9 and nid in counted_ids:
                    out["radius_rel_err"].append(abs(d.circle.r - n["sr"]) / n["sr"])
                    out["centre_err_px"].append(float(np.hypot(d.circle.u - n["su"], d.circle.v - n["sv"])))
                if d.node is not None:
                    out["identified"] += 1
                    out["id_correct"] += d.node == nid
                if d.track is None:
                    out["untracked"] += 1
                else:
                    if nid in last_track and last_track[nid] != d.track:
                        out["id_switches"] += 1
                    last_track[nid] = d.track
                if d.node is not None:
                    if nid in last_node and last_node[nid] != d.node:
                        out["node_id_changes"] += 1
                    last_node[nid] = d.node
            matched = {i for i, _ in pairs}
            for i, d in enumerate(dets):  # identified detections matching no node are wrong ids too
                if d.node is not None and i not in matched:
                    out["identified"] += 1
    return out


def _hough_alt_seconds(frames, repeats: int = 1) -> list[float]:
    out = []
    for seq in frames.values():
        for _, frame in seq:
            grey = cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY)
            best = np.inf
            for _ in range(repeats):
                cpu = time.process_time()
                blurred = cv2.GaussianBlur(grey, (0, 0), 2.0)
                cv2.HoughCircles(blurred, cv2.HOUGH_GRADIENT_ALT, dp=1.5, minDist=8, param1=150, param2=0.6,
                                 minRadius=8, maxRadius=160)
                best = min(best, time.process_time() - cpu)
            out.append(best)
    return out


def _summary(r: dict, ref_median: float) -> dict:
    med = float(np.median(r["cpu_seconds"]))
    return {
        "fps_median": 1.0 / med,
        "cpu_seconds_median": med,
        "cpu_seconds_p90": float(np.percentile(r["cpu_seconds"], 90)),
        "wall_seconds_median": float(np.median(r["seconds"])),
        "stage_cpu_seconds_median": {k: float(np.median(v)) for k, v in r["stage_seconds"].items()},
        "ratio_to_reference": med / ref_median,
        "precision": r["matched"] / max(r["detections"], 1),
        "recall": r["matched_counted"] / max(r["counted_nodes"], 1),
        "centre_err_px_median": float(np.median(r["centre_err_px"])) if r["centre_err_px"] else None,
        "radius_rel_err_median": float(np.median(r["radius_rel_err"])) if r["radius_rel_err"] else None,
        "radius_rel_err_p90": float(np.percentile(r["radius_rel_err"], 90)) if r["radius_rel_err"] else None,
        "identified_fraction": r["identified"] / max(r["detections"], 1),
        "id_accuracy": r["id_correct"] / max(r["identified"], 1),
        "id_switches": r["id_switches"],
        "node_id_changes": r["node_id_changes"],
        "untracked_matched_detections": r["untracked"],
        "frames": len(r["seconds"]),
        "visible_nodes_per_frame": [int(np.min(r["visible_per_frame"])), int(np.max(r["visible_per_frame"]))],
    }


def _reference_apriltag():
    """The AprilTag 3 C library's detector (tag36h11, one thread), or None when not installed."""
    try:
        from pupil_apriltags import Detector
    except ImportError:
        return None
    return Detector(families="tag36h11", nthreads=1, quad_decimate=1.0, refine_edges=1)


def _close_apriltag(detector) -> None:
    """Unregister the tag families before ``detector`` is destroyed.

    pupil-apriltags 1.0.4's ``Detector.__del__`` frees the families first and then the C detector,
    whose destructor reads them again: a use after free that crashed the benchmark (segfault in
    libapriltag) after the last scene, before anything was saved.
    """
    if detector is not None and detector.tag_detector_ptr is not None:
        detector.libc.apriltag_detector_clear_families.restype = None
        detector.libc.apriltag_detector_clear_families(detector.tag_detector_ptr)


def _tags_facing(frame) -> np.ndarray:
    """Spheres whose tag faces the camera (normal within 60 deg of the view) and that show wholly."""
    return np.array([s.tag and s.tag_normal[2] >= 0.5 for s in frame.spheres]) & (frame.visible >= 0.9)


def _score_reads(frame, reads) -> tuple[int, int, int]:
    """(facing tags read, wrong reads, facing tags) of tag reads [(id, (u, v))] on one frame."""
    facing = _tags_facing(frame)
    hit, wrong = set(), 0
    for tag, (u, v) in reads:
        under = [j for j, s in enumerate(frame.spheres) if np.hypot(u - s.u, v - s.v) <= s.r]
        j = min(under, key=lambda j: -frame.spheres[j].r) if under else None  # the nearest sphere
        if j is None or frame.spheres[j].id != tag:
            wrong += 1
        elif facing[j]:
            hit.add(j)
    return len(hit), wrong, int(facing.sum())


def _ours(seq, name: str, repeats: int) -> dict:
    """Our front end with the detector ``name`` on one varied sequence: scores, tag reads and times."""
    from agents.perception import Perception
    from sims.lab.experiments.perception_scores import SequenceScore, score_frame

    ours = Perception(name)
    cpu = np.full((repeats, len(seq)), np.inf)
    wall = np.full((repeats, len(seq)), np.inf)
    stages: dict[str, np.ndarray] = {}
    score = SequenceScore()
    for rep in range(repeats):
        ours.reset()
        for k, fr in enumerate(seq):
            start, c0 = time.perf_counter(), time.process_time()
            dets, secs = ours.process(fr.image)
            cpu[rep, k], wall[rep, k] = time.process_time() - c0, time.perf_counter() - start
            for stage, v in secs.items():
                stages.setdefault(stage, np.full((repeats, len(seq)), np.inf))[rep, k] = v
            if rep == 0:
                score_frame(score, fr, dets)
    # tag reads inside our circles (every circle read, no tracking), comparable with AprilTag 3's
    plain = Perception(name, track=False)
    read = wrong = facing = 0
    for fr in seq:
        dets, _ = plain.process(fr.image)
        got = [(d.read.node, (float(np.mean(d.read.corners[:, 0])), float(np.mean(d.read.corners[:, 1]))))
               for d in dets if d.read is not None and d.read.node is not None]
        r, w, f = _score_reads(fr, got)
        read, wrong, facing = read + r, wrong + w, facing + f
    best_cpu, best_wall = np.median(cpu.min(axis=0)), np.median(wall.min(axis=0))
    return {**score.summary(),
            "cpu_seconds_median": float(best_cpu), "wall_seconds_median": float(best_wall),
            "fps_cpu": 1.0 / float(best_cpu), "fps_wall": 1.0 / float(best_wall),
            "stage_cpu_seconds_median": {k: float(np.median(v.min(axis=0))) for k, v in stages.items()},
            "tags": {"facing": facing, "read_share": read / max(facing, 1), "wrong_reads": wrong}}


def _apriltag3(seq, detector) -> dict:
    """The AprilTag 3 C library on the whole grey frames of one sequence: tag reads and CPU time."""
    read = wrong = facing = 0
    secs = []
    for fr in seq:
        grey = cv2.cvtColor(fr.image, cv2.COLOR_BGR2GRAY)
        c0 = time.process_time()
        found = detector.detect(grey)
        secs.append(time.process_time() - c0)
        got = [(int(r.tag_id), (float(r.center[0]), float(r.center[1]))) for r in found]
        r, w, f = _score_reads(fr, got)
        read, wrong, facing = read + r, wrong + w, facing + f
    return {"facing": facing, "read_share": read / max(facing, 1), "wrong_reads": wrong,
            "cpu_seconds_median": float(np.median(secs))}


def _run_varied(seed: int, frames: int, repeats: int, detectors, apriltag) -> dict:
    """One held-out or tuning scene: our front end with each detector, and the references."""
    from sims.lab.experiments.varied_scenes import sequence

    seq = sequence(seed, frames)
    alt = _hough_alt_seconds({"all": [(k, fr) for k, fr in enumerate(seq)]}, 1)
    return {"seed": seed, "frames": len(seq), "spheres": len(seq[0].spheres),
            "detectors": {name: _ours(seq, name, repeats) for name in detectors},
            "apriltag3": None if apriltag is None else _apriltag3(seq, apriltag),
            "reference_hough_alt_cpu_seconds_median": float(np.median(alt))}


def _table(result: dict) -> str:
    """The Markdown table of the varied scenes (one row per scene and detector, held-out first)."""
    head = ("| scene | set | detector | recall | radius err median / p90 | false / double circles per sphere | wrong ids |"
            " ids carried | tags read: ours / AprilTag 3 | wrong reads: ours / AprilTag 3 |"
            " CPU ms: ours / AprilTag 3 / ALT | wall ms | fps (CPU) |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")

    def pct(x):
        return "-" if x is None else f"{100 * x:.1f} %"

    def num(x, fmt):
        return "-" if x is None else format(x, fmt)

    rows = []
    for r in result["scenes"]:
        a = r["apriltag3"] or {}
        for name, d in r["detectors"].items():
            t = d["tags"]
            rows.append(
                f"| {r['seed']} | {r['set']} | {name} | {num(d['recall'], '.3f')} | "
                f"{pct(d['radius_rel_err_median'])} / {pct(d['radius_rel_err_p90'])} | "
                f"{num(d['false_circles_per_sphere'], '.3f')} / {num(d['double_circles_per_sphere'], '.3f')} | "
                f"{pct(d['wrong_id_share'])} | {pct(d['carried_id_share'])} | "
                f"{pct(t['read_share'])} / {pct(a.get('read_share'))} | {t['wrong_reads']} / {a.get('wrong_reads', '-')} | "
                f"{1000 * d['cpu_seconds_median']:.0f} / {num(1000 * a['cpu_seconds_median'] if a else None, '.0f')} / "
                f"{1000 * r['reference_hough_alt_cpu_seconds_median']:.0f} | {1000 * d['wall_seconds_median']:.0f} | "
                f"{d['fps_cpu']:.1f} |")
    return head + "\n".join(rows) + "\n"


def _held_out_summary(scenes: list[dict], name: str) -> dict:
    """Worst and pooled figures of detector ``name`` over the held-out scenes."""
    ds = [r["detectors"][name] for r in scenes if r["set"] == "held-out"]
    counted = max(sum(d["counted_spheres"] for d in ds), 1)
    return {"min_recall": min((d["recall"] for d in ds if d["recall"] is not None), default=None),
            "recall_pooled": sum(d["recall"] * d["counted_spheres"] for d in ds if d["recall"] is not None) / counted,
            "false_circles_per_sphere": sum(d["false_circles_per_sphere"] * d["counted_spheres"] for d in ds
                                            if d["false_circles_per_sphere"] is not None) / counted,
            "double_circles_per_sphere": sum(d["double_circles_per_sphere"] * d["counted_spheres"] for d in ds
                                             if d["double_circles_per_sphere"] is not None) / counted,
            "cpu_ms_median": 1000 * float(np.median([d["cpu_seconds_median"] for d in ds])),
            "wall_ms_median": 1000 * float(np.median([d["wall_seconds_median"] for d in ds])),
            "fps_cpu_median": float(np.median([d["fps_cpu"] for d in ds]))}


def run_varied(args) -> dict:
    """The varied scenes: held-out seeds (and tuning ones with ``--tuning``), each detector side by side."""
    from agents.perception import make_detector
    from sims.lab.experiments.varied_scenes import HELD_OUT_SEEDS, TUNING_SEEDS

    apriltag = _reference_apriltag()
    make_detector()  # sets the allocator up before anything is timed (agents.perception.heap)
    seeds = list(HELD_OUT_SEEDS[: args.scenes_max] if args.scenes_max else HELD_OUT_SEEDS)
    result = {"benchmark": "perception_varied",
              "parameters": {"held_out_seeds": seeds, "tuning_seeds": list(TUNING_SEEDS) if args.tuning else [],
                             "detectors": list(args.detectors),
                             "frames": args.frames, "image": [1024, 768], "threads": 1, "repeats": args.repeats,
                             "timing": "per frame the minimum CPU (and wall) time over the repeats, then the median",
                             "reference": "AprilTag 3 (pupil-apriltags) on the whole grey frame"
                             if apriltag is not None else "pupil-apriltags not installed: no AprilTag 3 reference"},
              "machine": machine(), "scenes": []}
    sets = [("held-out", s) for s in seeds] + ([("tuning", s) for s in TUNING_SEEDS] if args.tuning else [])
    try:
        for name, seed in sets:
            r = _run_varied(seed, args.frames, args.repeats, args.detectors, apriltag)
            r["set"] = name
            result["scenes"].append(r)
            _print_scene(r)
    finally:
        _close_apriltag(apriltag)
    result["held_out"] = {name: _held_out_summary(result["scenes"], name) for name in args.detectors}
    return result


def _print_scene(r: dict) -> None:
    """One progress line per scene."""
    print(f"scene {r['seed']} ({r['set']}): " + ", ".join(
        f"{d}: recall {v['recall'] if v['recall'] is None else round(v['recall'], 3)}, "
        f"{1000 * v['cpu_seconds_median']:.0f} ms CPU" for d, v in r["detectors"].items()), flush=True)


def run_mottled(args) -> dict:
    """The held-out mottled floors: each detector alone (recall, false circles per frame, CPU per frame)."""
    from agents.perception import make_detector
    from agents.perception.types import TrackedCircle
    from sims.lab.experiments.mottled_scenes import HELD_OUT_MOTTLED_SEEDS, mottled_frames
    from sims.lab.experiments.perception_scores import SequenceScore, score_frame

    frames = [f for seed in HELD_OUT_MOTTLED_SEEDS for f in mottled_frames(seed, min(args.frames, 10))]
    result = {"benchmark": "perception_mottled",
              "parameters": {"seeds": list(HELD_OUT_MOTTLED_SEEDS), "frames_per_seed": min(args.frames, 10),
                             "detectors": list(args.detectors), "image": [1024, 768], "threads": 1,
                             "repeats": args.repeats,
                             "scores": "sims.lab.experiments.perception_scores, discs counted when >= 90 % visible"},
              "machine": machine(), "detectors": {}}
    for name in args.detectors:
        det = make_detector(name)
        score, seconds = SequenceScore(), []
        for f in frames:
            best = np.inf
            for _ in range(args.repeats):
                cpu = time.process_time()
                circles = det.detect(f.image)
                best = min(best, time.process_time() - cpu)
            seconds.append(best)
            score_frame(score, f, [TrackedCircle(c, None, None, None) for c in circles], min_visible=0.9)
        result["detectors"][name] = d = {"recall": score.matched / max(score.counted, 1), "discs": score.counted,
                                         "frames": len(frames), "false_circles_per_frame": score.false_circles / len(frames),
                                         "double_circles_per_frame": score.double_circles / len(frames),
                                         "cpu_ms_median": 1000 * float(np.median(seconds))}
        print(f"mottled, {name}: recall {d['recall']:.3f} of {d['discs']}, {d['false_circles_per_frame']:.2f} false "
              f"circles a frame, {d['cpu_ms_median']:.1f} ms CPU", flush=True)
    return result


def run_rendered(args) -> dict:
    """The 3-D renderer's table1 and multi scenarios (seed 0), both configurations, one detector."""
    result = {"benchmark": "perception", "parameters": {"scenarios": ["table1", "multi"], "seed": 0, "steps": args.steps,
                                                         "detector": args.rendered_detector,
                                                         "image": [1024, 768], "threads": 1, "repeats": args.repeats,
                                                         "timing": "per frame the minimum CPU time over the repeats, "
                                                                   "then the median over frames"},
              "machine": machine(), "scenarios": {}}
    for name in ("table1", "multi"):
        sim, frames = _render(name, args.steps)
        ref = _hough_alt_seconds(frames, args.repeats)
        ref_med = float(np.median(ref))
        entry = {"reference_hough_alt_cpu_seconds_median": ref_med}
        for mode in ("opencv_apriltag", "sphere_model"):
            r = _run(sim, frames, "sphere" if mode == "sphere_model" else "opencv", args.repeats, args.rendered_detector)
            entry[mode] = _summary(r, ref_med)
        result["scenarios"][name] = entry
    return result


def main(argv=None) -> None:
    ap = parser(__doc__)
    ap.add_argument("--scenes", nargs="+", choices=("varied", "rendered", "mottled"), default=["varied"],
                    help="which frames (default: varied)")
    ap.add_argument("--frames", type=int, default=30, help="frames per varied scene (default 30)")
    ap.add_argument("--tuning", action="store_true", help="also report the tuning seeds of the varied scenes")
    ap.add_argument("--detectors", nargs="+", choices=DETECTORS, default=list(DETECTORS),
                    help="circle detectors compared on the varied scenes (default: all)")
    ap.add_argument("--rendered-detector", choices=DETECTORS, default="hough",
                    help="circle detector of the rendered scenarios (default hough)")
    ap.add_argument("--scenes-max", type=int, default=0,
                    help="only the first N held-out varied scenes (default 0: all)")
    ap.add_argument("--steps", type=int, default=60, help="steps of the rendered scenarios (default 60)")
    ap.add_argument("--repeats", type=int, default=3,
                    help="runs of each sequence; per frame the smallest time counts (default 3)")
    args = ap.parse_args(argv)
    if args.frames < 1 or args.repeats < 1 or args.steps < 1 or args.scenes_max < 0:
        ap.error("--frames, --repeats and --steps must be positive")
    if "varied" in args.scenes:
        result = run_varied(args)
        save("perception_varied", result, args.out)
        table = _table(result)
        write_atomic(output(args.out, "perception_varied", ".md"), lambda fh: fh.write(table))
        print(table)
    if "mottled" in args.scenes:
        save("perception_mottled", run_mottled(args), args.out)
    if "rendered" in args.scenes:
        result = run_rendered(args)
        save("perception", result, args.out)
        plot(result, output(args.out, "perception", ".png"))


def plot(result: dict, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result["scenarios"])
    modes = ("opencv_apriltag", "sphere_model")
    labels = {"opencv_apriltag": "images only (OpenCV AprilTag, flow)", "sphere_model": "with the log (sphere model, odometry)"}
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.3))
    width = 0.38
    for j, mode in enumerate(modes):
        fps = [result["scenarios"][n][mode]["fps_median"] for n in names]
        axes[0].bar(np.arange(len(names)) + j * width, fps, width, label=labels[mode])
        pr = [result["scenarios"][n][mode]["precision"] for n in names]
        rc = [result["scenarios"][n][mode]["recall"] for n in names]
        axes[1].bar(np.arange(len(names)) + j * width, rc, width, label=f"recall, {labels[mode]}")
        axes[1].plot(np.arange(len(names)) + j * width, pr, "k^")
        acc = [result["scenarios"][n][mode]["identified_fraction"] for n in names]
        axes[2].bar(np.arange(len(names)) + j * width, acc, width, label=labels[mode])
    axes[0].axhline(30, color="r", linestyle=":", label="30 fps target")
    axes[0].set_title("frames per second (1 core, CPU time)", fontsize=9)
    axes[1].set_title("circle recall (bars), precision (triangles)", fontsize=9)
    axes[2].set_title("identified fraction of detections", fontsize=9)
    for ax in axes:
        ax.set_xticks(np.arange(len(names)) + width / 2, names)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


if __name__ == "__main__":
    main()
