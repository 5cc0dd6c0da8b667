"""Ensemble localization runs: a centralized method by name, and the distributed runner's configuration.

:func:`localize` runs one of Funiak et al. 2008's Algorithm 1 (``"ncut"``) or the baselines of its
§VI-E on a :class:`~decentral.ensemble.EnsembleProblem`; :func:`distributed_config` builds the
:class:`~sims.runners.ensemble_distributed.DistributedConfig` of a loss rate, a refinement tolerance and a
check interval. Used by ``decentral ensemble``, the studies and the benchmarks.
"""

from __future__ import annotations

from dataclasses import replace

from decentral.errors import InputError

__all__ = ["distributed_config", "localize"]


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
