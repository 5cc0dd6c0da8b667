"""Ensemble localization runs: a centralized method by name, the distributed runner's configuration, a score.

:func:`localize` runs one of Funiak et al. 2008's Algorithm 1 (``"ncut"``) or the baselines of its
§VI-E on a :class:`~decentral.ensemble.EnsembleProblem`; :func:`distributed_config` builds the
:class:`~sims.runners.ensemble_distributed.DistributedConfig` of a loss rate, a refinement tolerance
and a check interval; :func:`ensemble_score` scores an estimate file against a truth file. Used by
``decentral ensemble`` and ``score``, the studies and the benchmarks.
"""

from __future__ import annotations

from dataclasses import replace

from decentral.errors import InputError

__all__ = ["distributed_config", "ensemble_score", "localize"]


def localize(problem, method: str, seed: int, tol: float | None = None, progress=None):
    """Run a centralized ``method`` on ``problem``; returns a LocalizationResult (no I/O).

    ``tol`` (module radii) replaces the gradient tolerance of every refinement; ``progress`` is
    passed to the hierarchical method (the baselines report none).
    """
    import numpy as np

    rng = np.random.default_rng(seed)
    if method == "ncut":
        from decentral.ensemble.hierarchical import HierarchyConfig, normcut_localize

        config = HierarchyConfig() if tol is None else HierarchyConfig().with_tolerance(tol)
        return normcut_localize(problem, rng, config, progress=progress)
    from decentral.ensemble import baselines
    from decentral.ensemble.baselines.common import FINAL_REFINE

    final = FINAL_REFINE if tol is None else replace(FINAL_REFINE, gtol=tol)
    if method == "incremental":
        return baselines.incremental_localize(problem, final)
    if method == "mds":
        return baselines.classical_mds(problem, final)
    if method == "sdp":
        return baselines.sdp_localize(problem, final)
    if method == "bottom-up":
        return baselines.bottom_up_localize(problem, rng, refine_config=final)
    raise InputError(f"unknown method {method!r}", field="--method")


def distributed_config(loss: float = 0.0, tol: float | None = None, check_every: int | None = None):
    """The :class:`~sims.runners.ensemble_distributed.DistributedConfig` of ``--loss``, ``--tol``, ``--check-every``."""
    from sims.runners.ensemble_distributed import DistributedConfig

    config = DistributedConfig(loss=loss)
    if tol is not None:
        config = replace(config, hierarchy=config.hierarchy.with_tolerance(tol), top_gtol=tol)
    if check_every is not None:
        config = replace(config, check_every=check_every)
    return config


def ensemble_score(estimate_path: str, truth_path: str) -> dict:
    """Global and local RMS (module radii) of an ensemble estimate file against a truth file, JSON-ready."""
    import numpy as np

    from decentral.ensemble.metrics import evaluate
    from sims.io.ensemble_npz import read_ensemble_positions, read_ensemble_truth

    truth = read_ensemble_truth(truth_path)
    n, dim = truth.position.shape
    position = read_ensemble_positions(estimate_path, n, dim)
    pairs, source = truth.pairs, "observed"
    if pairs is None:
        from scipy.spatial import cKDTree

        from sims.simulation.ensembles.sensors import SensorModel

        pairs = cKDTree(truth.position).query_pairs(SensorModel().reach(truth.radius), output_type="ndarray")
        source = "true contacts"
    if len(pairs) == 0:
        raise InputError("no neighbour pairs: cannot fix the scale", source=truth_path, field="pairs")
    if np.ptp(position, axis=0).max() == 0.0:
        raise InputError("every module at one point", source=estimate_path, field="position")
    err = evaluate(position, truth.position, pairs, truth.radius)
    if not (np.isfinite(err.global_rms) and np.isfinite(err.local_rms)):
        raise InputError("degenerate estimate (no finite alignment)", source=estimate_path, field="position")
    return {"modules": n, "dim": dim, "units": "module radii", "global_rms": err.global_rms,
            "local_rms": err.local_rms, "scale": err.scale, "regions": err.regions, "pairs": int(len(pairs)),
            "pairs_from": source}
