"""The refinement methods of :func:`decentral.ensemble.refine.refine`, one per module: ``alternating``, ``lbfgs``, ``lm``, ``pcg``."""

from decentral.ensemble.refiners.alternating import refine_alternating
from decentral.ensemble.refiners.base import RefineConfig, RefineResult
from decentral.ensemble.refiners.lbfgs import refine_lbfgs
from decentral.ensemble.refiners.lm import refine_lm
from decentral.ensemble.refiners.pcg import refine_pcg

__all__ = ["RefineConfig", "RefineResult", "refine_alternating", "refine_lbfgs", "refine_lm", "refine_pcg"]
