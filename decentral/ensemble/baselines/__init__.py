"""Baselines of Funiak et al. 2008 §VI-E, each returning a :class:`~decentral.ensemble.hierarchical.LocalizationResult`.

- :func:`classical_mds`: classical multidimensional scaling of hop counts (Shang et al., MDS-MAP);
- :func:`sdp_localize`: regularized (maximum-spread) SDP sensor-network localization, inequality
  form (Biswas et al.), solved in dual form by Clarabel, with a size guard;
- :func:`incremental_localize`: the breadth-first incremental method of §III-B;
- :func:`bottom_up_localize`: hierarchical merging of clusters in order of algebraic connectivity.

All of them finish, like the paper's study, with the same maximum-likelihood refinement.
"""

from decentral.ensemble.baselines.bottom_up import bottom_up_localize
from decentral.ensemble.baselines.incremental import incremental_localize
from decentral.ensemble.baselines.mds import classical_mds
from decentral.ensemble.baselines.sdp import SDP_MAX_NODES, sdp_localize

__all__ = ["SDP_MAX_NODES", "bottom_up_localize", "classical_mds", "incremental_localize", "sdp_localize"]
