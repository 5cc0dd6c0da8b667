"""How well a ring pins a member's camera yaw: why a member whose views are all turned 3 degrees goes unnamed.

A member that shifts every detection of its cameras by 40 px in ``u`` (3.0 degrees at the 760 px focal
length) turns its views as a camera mounted 3 degrees off would. The lie tests (docs/robustness.md) do
not name it; this measures why, on ``multi`` rings of 5 assemblies (8 steps, window 5), in pixels:

- ``noise``: the simulated detector's centre error against the truth (``u``: mean and standard deviation);
- ``predicted``: per member, the mean ``u`` offset of its own detections from where the centralized estimate
  of *everyone else's data* (the log without that member's detections) puts the nodes it saw. On honest
  logs this scatters as widely as the rest knows the member's yaw; the liar's offset is its honest one
  plus 40 px. A test can only name the lie where 40 px stands out of that scatter;
- ``observers``: the rms pixel residual of every observer's detections of each observed member against
  the joint (centralized) estimate of all the data, honest and with ``A3`` lying: what a check by the
  observers on their own detections would see.

Usage: ``python benchmarks/view_lie.py [--seeds 10] [--liar A3] [--shift 40]``; writes ``OUT/view_lie.json``.
"""

from __future__ import annotations

import dataclasses
import sys

from _common import parser, save  # noqa: I001  (pins threads before numpy)

import numpy as np

from decentral.estimator import EstimatorConfig, estimate_log
from decentral.geometry import rotz
from decentral.observations import Pose
from sims.simulation.scenarios import get_scenario, simulate
from sims.simulation.world.camera import project_nodes


def residuals(log, estimate, step: int) -> dict:
    """Per ``(observer, observed)``, the pixel residuals (n, 2) of the observer's detections at ``step`` against
    the nodes where ``estimate`` puts them (both placed; detections of the observer's own nodes, and of nodes the
    estimate puts behind the camera, left out)."""
    s, poses = log.steps[step], estimate.steps[step].poses
    owner, out = s.node_owner(), {}
    for key, dets in s.detections.items():
        obs, cam = key.split("/")[0], log.cameras[key]
        if obs not in poses:
            continue
        cam_world = Pose(rotz(poses[obs].theta), poses[obs].p).compose(cam.in_root(s.mounts.get(key)))
        for d in dets:
            j = owner.get(d.node)
            if j is None or j == obs or j not in poses:
                continue
            world = rotz(poses[j].theta) @ s.config[j][d.node] + poses[j].p
            uvr, depth = project_nodes(cam.K, cam_world, world[None], log.node_radius)
            if depth[0] > 0:  # (a node the estimate puts behind the camera has no place in the image to compare)
                out.setdefault((obs, j), []).append([d.u - uvr[0, 0], d.v - uvr[0, 1]])
    return {k: np.array(v) for k, v in out.items()}


def shifted(log, member: str, du: float):
    """``log`` with every detection of ``member``'s cameras moved ``du`` px in ``u``."""
    prefix = member + "/"
    return dataclasses.replace(log, steps=tuple(dataclasses.replace(s, detections={
        k: tuple(dataclasses.replace(d, u=d.u + du) for d in ds) if k.startswith(prefix) else ds
        for k, ds in s.detections.items()}) for s in log.steps))


def without_views(log, member: str):
    """``log`` without ``member``'s detections."""
    return dataclasses.replace(log, steps=tuple(dataclasses.replace(s, detections={
        k: ds for k, ds in s.detections.items() if not k.startswith(member + "/")}) for s in log.steps))


def predicted_offset(log, member: str, config: EstimatorConfig) -> float | None:
    """Mean ``u`` offset (px) of ``member``'s detections from the estimate of everyone else's data."""
    rest = estimate_log(without_views(log, member), config)
    r = [res[:, 0] for k in range(len(log.steps)) for (o, _), res in residuals(log, rest, k).items() if o == member]
    return float(np.mean(np.concatenate(r))) if r else None


def observer_rms(log, estimate) -> dict:
    """``"observer>observed"`` -> rms pixel residual over the log against ``estimate``."""
    pooled: dict = {}
    for k in range(len(log.steps)):
        for pair, res in residuals(log, estimate, k).items():
            pooled.setdefault(pair, []).append(res)
    return {f"{o}>{j}": float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for (o, j), v in sorted(pooled.items())}


def noise(sim) -> list[float]:
    """Detector ``u`` error against the truth's circles: [mean, std] (px)."""
    du = []
    for k, s in enumerate(sim.log.steps):
        for key, dets in s.detections.items():
            truth = {n["id"]: n for n in sim.truth.visible[k].get(key, [])}
            du += [d.u - truth[d.node]["u"] for d in dets if d.node in truth]
    return [float(np.mean(du)), float(np.std(du))]


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--seeds", type=int, default=10, help="logs 1..N (default 10)")
    ap.add_argument("--liar", default="A3")
    ap.add_argument("--shift", type=float, default=40.0, help="px added to the liar's u (default 40)")
    args = ap.parse_args(argv)
    config = EstimatorConfig(window=5)
    rows = []
    for seed in range(1, args.seeds + 1):
        sim = simulate(get_scenario("multi", n_assemblies=5, steps=8), seed=seed)
        log, lying = sim.log, shifted(sim.log, args.liar, args.shift)
        members = [a for a in log.assemblies if any(k.startswith(a + "/") for s in log.steps for k in s.detections)]
        honest = {a: predicted_offset(log, a, config) for a in members}
        row = {"seed": seed, "noise_u_px": noise(sim), "predicted_honest_px": honest,
               "predicted_liar_px": predicted_offset(lying, args.liar, config) if args.liar in members else None,
               "observers_honest_rms_px": observer_rms(log, estimate_log(log, config)),
               "observers_lying_rms_px": observer_rms(lying, estimate_log(lying, config))}
        rows.append(row)
        print(f"seed {seed}: honest offsets {({a: round(v, 1) for a, v in honest.items() if v is not None})}, "
              f"{args.liar} lying {row['predicted_liar_px'] and round(row['predicted_liar_px'], 1)}", file=sys.stderr)
    offsets = [v for r in rows for v in r["predicted_honest_px"].values() if v is not None]
    into = lambda key: [v for r in rows for pair, v in r[key].items() if pair.endswith(">" + args.liar)]  # noqa: E731
    others = lambda key: [v for r in rows for pair, v in r[key].items() if not pair.endswith(">" + args.liar)]  # noqa: E731
    summary = {
        "noise_u_std_px": [min(r["noise_u_px"][1] for r in rows), max(r["noise_u_px"][1] for r in rows)],
        "predicted_honest_std_px": float(np.std(offsets)), "predicted_honest_range_px": [min(offsets), max(offsets)],
        "shift_px": args.shift,
        "views_of_liar_rms_px": {"honest": [min(into("observers_honest_rms_px")), max(into("observers_honest_rms_px"))],
                                 "lying": [min(into("observers_lying_rms_px")), max(into("observers_lying_rms_px"))]},
        "other_views_rms_px": {"honest": [min(others("observers_honest_rms_px")), max(others("observers_honest_rms_px"))],
                               "lying": [min(others("observers_lying_rms_px")), max(others("observers_lying_rms_px"))]},
    }
    save("view_lie", {"benchmark": "view_lie", "config": vars(args) | {"out": str(args.out)}, "rows": rows,
                      "summary": summary}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
