"""Fingerprints of the library's outputs: one SHA-256 per part, over seeded runs, for refactor checks.

A refactor that must not change behaviour is checked by running this program before and after on the
same machine and comparing the hashes (floating-point results are hashed bit for bit, so hashes from
two machines need not agree; this is a same-machine check, not a test against recorded numbers). The
parts:

- ``admm``: the simulated decentralized runner (:func:`sims.runners.admm_run.run_admm`) on seeded logs, clean,
  with loss and jitter, with a crash, and with the cold-start-only share mode: every estimated pose and
  the messages and bytes sent per kind and per step;
- ``central``: the centralized estimator (:func:`decentral.estimator.estimate_log`) on a seeded log;
- ``ensemble``: the centralized methods and the distributed runner on small seeded ensembles: positions,
  rotations and message counts per phase;
- ``perception``: the detections of the default pipeline and of every named detector on rendered frames.

Usage: ``python benchmarks/fingerprint.py [--parts admm,central,ensemble,perception] [--out DIR]``
(the hashes are printed and saved as ``DIR/fingerprint.json``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

PARTS = ("admm", "central", "ensemble", "perception")


class Digest:
    """A SHA-256 fed with tagged, canonical bytes of arrays, numbers and strings."""

    def __init__(self) -> None:
        self.h = hashlib.sha256()

    def add(self, tag: str, value) -> None:
        self.h.update(tag.encode() + b"\0")
        if isinstance(value, np.ndarray) or isinstance(value, (list, tuple)) and value and isinstance(value[0], float):
            a = np.ascontiguousarray(np.asarray(value))
            self.h.update(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
        else:
            self.h.update(json.dumps(value, sort_keys=True, default=_plain).encode())

    def hexdigest(self) -> str:
        return self.h.hexdigest()


def _plain(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return repr(x)


def _timeless(x):
    """``x`` without the wall-clock entries (keys naming seconds), which differ from run to run."""
    if isinstance(x, dict):
        return {k: _timeless(v) for k, v in x.items() if "seconds" not in str(k)}
    if isinstance(x, (list, tuple)):
        return [_timeless(v) for v in x]
    return x


def _add_estimate(d: Digest, tag: str, estimate) -> None:
    for k, step in enumerate(estimate.steps):
        d.add(f"{tag}/{k}/t", float(step.t))
        for name in sorted(step.poses):
            pose = step.poses[name]
            d.add(f"{tag}/{k}/{name}/theta", np.asarray([pose.theta], dtype=float))
            d.add(f"{tag}/{k}/{name}/p", np.asarray(pose.p))
        d.add(f"{tag}/{k}/unplaced", dict(step.unplaced))


def admm_part() -> str:
    from protocols.network import Crash
    from sims.runners.admm_run import AdmmRunConfig, run_admm
    from sims.simulation.scenarios import get_scenario, simulate

    d = Digest()
    log = simulate(get_scenario("multi", n_assemblies=4, steps=3), seed=3).log
    names = list(log.assemblies)
    runs = {
        "clean": AdmmRunConfig(window=3),
        "loss_jitter": AdmmRunConfig(window=3, loss=0.2, jitter=0.03, duplicate=0.05),
        "crash": AdmmRunConfig(window=3, crashes=(Crash(names[-1], 0.2, 1.5),)),
        "first": AdmmRunConfig(window=3, share_forms="first"),
        "broadcast": AdmmRunConfig(window=3, aggregation="broadcast"),
    }
    for tag, config in runs.items():
        run = run_admm(log, config=config, seed=5)
        _add_estimate(d, tag, run.estimate)
        d.add(f"{tag}/rounds", list(run.rounds))
        d.add(f"{tag}/converged", list(run.converged))
        d.add(f"{tag}/messages_per_step", list(run.messages_per_step))
        d.add(f"{tag}/bytes_per_step", list(run.bytes_per_step))
        d.add(f"{tag}/per_kind", run.stats["messages"]["per_kind"])
        d.add(f"{tag}/per_sender", run.stats["messages"]["per_sender"])
        d.add(f"{tag}/unplaced", run.stats["unplaced"])
        d.add(f"{tag}/agents", _timeless(run.stats["agents"]))
    return d.hexdigest()


def central_part() -> str:
    from decentral.estimator import EstimatorConfig, estimate_log
    from sims.simulation.scenarios import get_scenario, simulate

    d = Digest()
    log = simulate(get_scenario("multi", n_assemblies=5, steps=4), seed=11).log
    est = estimate_log(log, EstimatorConfig(window=3))
    _add_estimate(d, "central", est)
    d.add("central/stats", _timeless(est.stats))
    return d.hexdigest()


def ensemble_part() -> str:
    from dataclasses import replace

    from decentral.ensemble import EnsembleProblem, HierarchyConfig, normcut_localize
    from sims.runners.ensemble_run import distributed_config, localize
    from sims.simulation.ensembles import EnsembleSpec, generate
    from sims.runners.ensemble_distributed import run_distributed

    d = Digest()
    hierarchy = replace(HierarchyConfig(), leaf_size=16)  # several levels on small ensembles
    cases = [("triple", 80, 1), ("sphere", 80, 2), ("ring", 40, 3)]
    for shape, n, seed in cases:
        ens = generate(EnsembleSpec(shape=shape, n=n), np.random.default_rng([seed, n]))
        prob = EnsembleProblem.create(ens.dim, ens.n, ens.radius, ens.i, ens.j, ens.z)
        results = {"ncut16": normcut_localize(prob, np.random.default_rng(seed), hierarchy)}
        methods = ["ncut", "incremental", "mds", "bottom-up"] + (["sdp"] if n <= 40 else [])
        for method in methods:
            results[method] = localize(prob, method, seed)
        for method, res in results.items():
            tag = f"{shape}/{method}"
            d.add(f"{tag}/position", res.estimate.position)
            d.add(f"{tag}/rotation", res.estimate.rotation)
            d.add(f"{tag}/component", res.estimate.component)
        for loss in (0.0, 0.1):
            config = replace(distributed_config(loss), hierarchy=hierarchy)
            res = run_distributed(prob, np.random.default_rng(seed), config)
            tag = f"{shape}/distributed/{loss}"
            d.add(f"{tag}/position", res.estimate.position)
            d.add(f"{tag}/rotation", res.estimate.rotation)
            d.add(f"{tag}/messages", np.asarray(res.messages))
            d.add(f"{tag}/phases", list(res.phase_names))
            d.add(f"{tag}/phase_messages", np.asarray(res.phase_messages))
            d.add(f"{tag}/rounds", int(res.rounds))
            d.add(f"{tag}/cost", float(res.cost))
            d.add(f"{tag}/network", res.network)
    return d.hexdigest()


def perception_part() -> str:
    from agents.perception import DETECTORS, Perception, make_detector
    from sims.simulation.render.frame_files import render_frames
    from sims.simulation.render.renderer import RenderConfig
    from sims.simulation.scenarios import get_scenario, simulate

    d = Digest()
    sim = simulate(get_scenario("table1", steps=3, noise=False, ranges=(1.8, 2.5, 2.0)), seed=4)
    frames = [f for _, key, f in render_frames(sim, 4, RenderConfig()) if key == "A0/cam0"]
    pipeline = Perception()
    for k, f in enumerate(frames):
        dets, _ = pipeline.process(f.image)
        d.add(f"pipeline/{k}", [(c.circle.u, c.circle.v, c.circle.r, c.node, c.track,
                                 None if c.read is None else (c.read.tag, c.read.hamming, c.read.margin,
                                                              np.asarray(c.read.corners).tolist()))
                                for c in dets])
    for name in DETECTORS:
        det = make_detector(name)
        for k, f in enumerate(frames[:2]):
            d.add(f"{name}/{k}", [(c.u, c.v, c.r, c.score) for c in det.detect(f.image)])
    return d.hexdigest()


def main(argv=None) -> int:
    from _common import machine, output, parser

    p = parser(__doc__)
    p.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated subset of {', '.join(PARTS)}")
    args = p.parse_args(argv)
    parts = [s for s in args.parts.split(",") if s]
    unknown = [s for s in parts if s not in PARTS]
    if unknown:
        print(f"fingerprint: --parts: unknown part(s) {', '.join(unknown)} (known: {', '.join(PARTS)})",
              file=sys.stderr)
        return 2
    fns = {"admm": admm_part, "central": central_part, "ensemble": ensemble_part, "perception": perception_part}
    hashes = {}
    for part in parts:
        hashes[part] = fns[part]()
        print(f"{part:<11} {hashes[part]}", flush=True)
    path = output(args.out, "fingerprint")
    path.write_text(json.dumps({"benchmark": "fingerprint", "machine": machine(), "hashes": hashes}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
