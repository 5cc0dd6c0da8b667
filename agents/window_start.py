"""How an assembly agent's current window started (:class:`WindowStart`): the joint solution of the shared
forms it was seeded at, and what that solution says (the agent is :class:`agents.assembly.AssemblyAgent`)."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["WindowStart"]


@dataclass
class WindowStart:
    """How the current window started: the joint solution it was seeded at, if any (reset every log step).

    Attributes
    ----------
    seeds : dict
        ``(assembly, step) -> (R (2, 2), p (3,))`` of the joint solution (empty: no seeded start).
    complete : bool
        The seeds come from every live agent's forms (then the placement test below applies).
    placeable : frozenset
        ``(assembly, step)`` keys the joint placement test places relative to this agent.
    why : dict
        Assembly -> why the joint placement test does not place it at this step.
    expected : set of str
        Observers whose first values a seeded start waits for.
    form_sig : dict or None
        Target -> detections its pair used when this window's own forms were shared.
    admm_ran : bool
        The agent has run an ADMM round in this window (its estimate is then the consensus once converged).
    without : frozenset of str
        Agents whose forms a complete set lacked (given up on as down: not heard for two windows). Its
        joint solution is the centralized estimate of the others' data, not of all the data.
    fallback : dict
        Assembly -> ``(R, p)`` at this step of what the joint solution places (of every live agent's
        forms, or of those that came before the wait for them ended): the step's answer unless this agent
        ran ADMM rounds in the window and they converged (iterates on the way are not estimates).
    """

    seeds: dict = field(default_factory=dict)
    complete: bool = False
    placeable: frozenset = frozenset()
    why: dict = field(default_factory=dict)
    expected: set = field(default_factory=set)
    form_sig: dict | None = None
    fallback: dict = field(default_factory=dict)
    admm_ran: bool = False
    without: frozenset = frozenset()
