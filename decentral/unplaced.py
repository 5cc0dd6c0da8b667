"""Why an assembly is not placed at a step: one reason per assembly left out of an estimate step.

An estimate leaves out an assembly it cannot place (never a guess); :func:`unplaced_reasons` says
which of the placement conditions of :mod:`decentral.estimator` failed, in the order they are
tested, so a user can tell "nobody saw it" from "seen, but its heading is not determined".
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

__all__ = ["REASONS", "unplaced_reasons", "count_reasons"]

#: reason code -> what it means (the codes are written in ``decentral.estimate/1`` steps' ``unplaced``)
REASONS: dict[str, str] = {
    "no_data": "no detection in the window is of it or by it",
    "not_connected": "its detections in the window do not tie it to the reference",
    "solver_failed": "the window's relaxation gave no usable solution",
    "yaw_unobservable": "its yaw relative to the reference is not determined (null space of the yaw Hessian, "
                        "e.g. a one-node target that does not move)",
    "yaw_std_above_limit": "its yaw standard deviation (Laplace approximation) is above the limit max_yaw_std",
    "no_consensus": "decentralized run: the reference agent holds no agreed pose of it at this step",
}


def unplaced_reasons(assemblies: Iterable[str], reference: str, placed: Iterable[str], *,
                     with_data: Iterable[str], connected: Iterable[str], solved: bool,
                     yaw_std: Mapping[str, float]) -> dict[str, str]:
    """Reason code (a key of :data:`REASONS`) for every assembly other than ``reference`` not in ``placed``.

    Parameters
    ----------
    assemblies : iterable of str
        Every assembly of the log, in order (the result keeps it).
    reference : str
        The reference assembly (never listed).
    placed : iterable of str
        Assemblies the step places.
    with_data : iterable of str
        Assemblies that take part in a visual factor of the window (observer or target).
    connected : iterable of str
        Assemblies whose root at the step is in the reference's connected component of the window.
    solved : bool
        Whether the window's relaxation gave a usable solution.
    yaw_std : mapping
        Assembly -> its relative-yaw standard deviation (rad), for the assemblies whose relative yaw is
        outside the non-gauge null space; any assembly connected but absent here is unobservable.
    """
    placed, with_data, connected = set(placed), set(with_data), set(connected)
    reasons = {}
    for name in assemblies:
        if name == reference or name in placed:
            continue
        if name not in with_data:
            reasons[name] = "no_data"
        elif name not in connected:
            reasons[name] = "not_connected"
        elif not solved:
            reasons[name] = "solver_failed"
        elif name not in yaw_std:
            reasons[name] = "yaw_unobservable"
        else:
            reasons[name] = "yaw_std_above_limit"
    return reasons


def count_reasons(per_step: Iterable[Mapping[str, str]]) -> dict[str, int]:
    """Number of (step, assembly) pairs left out for each reason, over all steps (reasons never met omitted)."""
    counts: dict[str, int] = {}
    for reasons in per_step:
        for reason in reasons.values():
            counts[reason] = counts.get(reason, 0) + 1
    return {code: counts[code] for code in REASONS if code in counts}
