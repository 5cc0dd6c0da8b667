"""Ensemble (internal) localization of modular robots: Funiak et al.'s hierarchical normalized cut.

Modules observe only their immediate neighbours; :func:`normcut_localize` (Algorithm 1) recovers
every module's pose up to one global rigid motion. The building blocks are public so that the
distributed version can call them one module or one leader at a time:

- :mod:`.model`: observation model, likelihood and analytic gradients (eq. 1-3);
- :mod:`.refine`: maximum-likelihood refinement on the sparse structure;
- :mod:`.ncut`: normalized cut (eq. 4) by a sparse spectral method;
- :mod:`.abstraction`: random leaders, hop-count clusters, abstracted graph (§IV-C, §V-A);
- :mod:`.alignment`: rigid alignment from aggregable statistics (eq. 5);
- :mod:`.hierarchical`: Algorithm 1;
- :mod:`.baselines`: classical MDS, regularized SDP, incremental, bottom-up merging;
- :mod:`.metrics`: global and local RMS of §VI-C.
"""

from decentral.ensemble.abstraction import Clustering, abstract_graph, choose_leaders, elect_leaders, hop_clusters
from decentral.ensemble.alignment import AlignmentStats, RigidTransform, align_points, merge_point_pairs
from decentral.ensemble.hierarchical import HierarchyConfig, LocalizationResult, normcut_localize
from decentral.ensemble.metrics import EnsembleErrors, evaluate
from decentral.ensemble.model import gradient, negative_log_likelihood, residuals
from decentral.ensemble.ncut import NcutResult, normalized_cut
from decentral.ensemble.problem import EnsembleEstimate, EnsembleProblem
from decentral.ensemble.refine import RefineConfig, RefineResult, refine

__all__ = [
    "AlignmentStats",
    "Clustering",
    "EnsembleErrors",
    "EnsembleEstimate",
    "EnsembleProblem",
    "HierarchyConfig",
    "LocalizationResult",
    "NcutResult",
    "RefineConfig",
    "RefineResult",
    "RigidTransform",
    "abstract_graph",
    "align_points",
    "choose_leaders",
    "elect_leaders",
    "evaluate",
    "gradient",
    "hop_clusters",
    "merge_point_pairs",
    "negative_log_likelihood",
    "normalized_cut",
    "normcut_localize",
    "refine",
    "residuals",
]
