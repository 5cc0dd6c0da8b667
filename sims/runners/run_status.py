"""What a decentralized run's ``stats.status`` says, with counts per reason, and its one-line warning.

Every decentralized runner (``localize --mode admm``, ``agent``, ``launch``, a study cell) ends with
the same verdict, computed here from what each step's window did:

- ``ok``: every step's window converged (its answer is the consensus, the centralized estimate's
  fixed point) and the run was not cut short;
- ``degraded``: some step did not converge; ``status_counts`` says how many and why;
- ``timeout``: the run was cut short (``launch --timeout``) before every step was reported.

``status_counts`` (always present, zeros included) counts

- ``unconverged``: steps whose window ended (the next sensor step came, or the round budget ran
  out) before the agent's convergence test held;
- ``provisional``: of those, steps that still have an answer: the joint solution of the forms the
  agent held, or its last iterate (placing at least one assembly);
- ``unanswered``: of those, steps that placed no assembly at all;
- ``not_run``: steps the agent never ran (it was down, started late, or the run was cut short);
- ``revised`` (where the runner reports it, ``run_status(..., revised_because=)``): steps answered
  provisionally when the next sensor step came whose window then converged in the background
  (:mod:`agents.runtime`): counted as converged, at most one sensor step late (and steps answered again
  without an excluded member);
- ``reanswered`` (reported with ``revised``): of the unconverged steps, those answered again one sensor
  step late, still provisional (reason ``"more_forms"``): the background window did not converge, but the
  forms it held when it ended placed an assembly the first answer left out (and every one it placed);
- ``without_members`` (where the runner reports it, ``run_status(..., without=)``): of the converged
  steps, those whose window's forms lacked some agent's (given up on as down after two silent windows):
  the joint estimate of the others' data, not of all of it; such a run is ``degraded``;
- one entry per reason of an assembly-step left unplaced (:data:`decentral.unplaced.REASONS`,
  e.g. ``no_consensus``), as in ``stats.unplaced``.

The commands print :func:`status_warning` as one warning line when a run is not ``ok``, and with
``--strict`` exit with :data:`EXIT_DEGRADED` (4) (:func:`report_status`). Where the processes ran their
rounds late against their own clocks (``stats.behind_ms``), :func:`cpu_hint` adds why: a process kept off
a busy CPU, which no network setting cures.
"""

from __future__ import annotations

from typing import Iterable, Mapping, Sequence

__all__ = ["STATUSES", "EXIT_DEGRADED", "run_status", "status_warning", "cpu_hint", "placed_steps"]

#: the values ``stats.status`` takes
STATUSES = ("ok", "degraded", "timeout")

#: exit status of ``--strict`` runs whose status is not ``ok`` (3 is "placed nothing", 2 "bad input")
EXIT_DEGRADED = 4


def run_status(converged: Sequence[bool], placed: Sequence[bool], unplaced: Mapping[str, int] | None = None, *,
               not_run: int = 0, timed_out: bool = False, revised_because: Sequence[str] | None = None,
               without: int | None = None) -> tuple[str, dict[str, int]]:
    """The verdict and the counts per reason of a run (see the module docstring).

    Parameters
    ----------
    converged : sequence of bool, shape (S,)
        Per step the agent ran: whether its window converged.
    placed : sequence of bool, shape (S,)
        Per step the agent ran: whether its answer placed at least one assembly.
    unplaced : mapping, optional
        Assembly-steps left unplaced, per reason (``stats.unplaced``).
    not_run : int
        Steps of the log the agent never ran.
    timed_out : bool
        Whether the run was cut short.
    revised_because : sequence of str, optional
        Per step answered again, its :attr:`agents.runtime.Revision.reason`: ``"more_forms"`` (still
        unconverged) is counted as ``reanswered``, the others as ``revised`` (omitted: neither reported).
    without : int, optional
        Of the converged steps, those whose forms lacked some agent's (``without_members``; omitted: not
        reported).

    Returns
    -------
    status : str
        ``ok``, ``degraded`` or ``timeout``.
    counts : dict
        Counts per reason (``unconverged``, ``provisional``, ``unanswered``, ``not_run`` and
        the unplaced reasons).

    Examples
    --------
    >>> run_status([True, True], [True, True])
    ('ok', {'unconverged': 0, 'provisional': 0, 'unanswered': 0, 'not_run': 0})
    >>> run_status([True, False], [True, True], {"no_consensus": 2})[0]
    'degraded'
    """
    if len(converged) != len(placed):
        raise ValueError("converged and placed must have one entry per step")
    off = [p for c, p in zip(converged, placed) if not c]
    counts = {"unconverged": len(off), "provisional": sum(1 for p in off if p),
              "unanswered": sum(1 for p in off if not p), "not_run": int(not_run)}
    for reason, n in sorted((unplaced or {}).items()):
        counts[str(reason)] = int(n)
    if revised_because is not None:
        again = sum(1 for reason in revised_because if reason == "more_forms")
        counts["revised"], counts["reanswered"] = len(revised_because) - again, again
    if without is not None:
        counts["without_members"] = int(without)
    if timed_out:
        return "timeout", counts
    return ("ok" if not off and not not_run and not without else "degraded"), counts


def status_warning(status: str, counts: Mapping[str, int], steps: int) -> str | None:
    """One line saying why a run is not ``ok`` (``None`` when it is).

    Examples
    --------
    >>> status_warning("degraded", {"unconverged": 3, "provisional": 2, "unanswered": 1, "not_run": 0,
    ...                             "no_consensus": 4}, 30)
    'status degraded: 3 of 30 steps did not converge (2 provisional: the joint solution of the forms held; 1 placed no one); 4 assembly-steps not placed (no_consensus 4)'
    """
    if status == "ok":
        return None
    parts = []
    if counts.get("unconverged"):
        parts.append(f"{counts['unconverged']} of {steps} steps did not converge ({counts.get('provisional', 0)} "
                     f"provisional: the joint solution of the forms held; {counts.get('unanswered', 0)} placed no one)")
    if counts.get("revised"):
        parts.append(f"{counts['revised']} revised one step late (converged in the background)")
    if counts.get("reanswered"):
        parts.append(f"{counts['reanswered']} answered again one step late from more forms (still provisional)")
    if counts.get("without_members"):
        parts.append(f"{counts['without_members']} converged without some agents' forms (given up on as down: "
                     "the joint estimate of the others' data)")
    if counts.get("not_run"):
        parts.append(f"{counts['not_run']} of {steps} steps never ran (agent down, late or cut short)")
    reasons = {k: v for k, v in counts.items() if k not in _OWN and v}
    if reasons:
        parts.append(f"{sum(reasons.values())} assembly-steps not placed ("
                     + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1])) + ")")
    return f"status {status}: " + ("; ".join(parts) if parts else "cut short")


def cpu_hint(behind_ms, round_period: float) -> str | None:
    """Why a run fell behind when its processes were short of CPU (``None`` when they kept their clocks).

    ``behind_ms`` is a runner's ``stats.behind_ms``: for one agent ``[median, p90, max]`` of how late its half
    rounds ran against its own clock (ms); for ``launch`` per agent ``[median, largest]`` over its steps of
    each step's p90. A process whose (typical) p90 exceeds one ``round_period`` (s) ran its rounds a
    round or more late: its peers waited for it, whatever the links did.

    Examples
    --------
    >>> cpu_hint([4.0, 80.0, 300.0], 0.025)
    'its half rounds ran 80 ms behind its clock at p90 (round period 25 ms): the process was short of CPU (give it a larger share, e.g. nice, or a slower pace: --rate, --round-period)'
    >>> cpu_hint({"A1": [3.0, 9.0], "A2": [60.0, 200.0]}, 0.025)
    'A2 ran its half rounds 60 ms behind its clock at p90 (round period 25 ms): short of CPU (give the agents a larger share, e.g. nice, or a slower pace: --rate, --round-period)'
    >>> cpu_hint([1.0, 5.0, 30.0], 0.025) is None
    True
    """
    limit = 1e3 * float(round_period)
    if isinstance(behind_ms, Mapping):
        late = {a: float(v[0]) for a, v in sorted(behind_ms.items()) if v and float(v[0]) > limit}
        if not late:
            return None
        worst = max(late.values())
        late_by = f"its half rounds {worst:.0f} ms behind its clock" if len(late) == 1 else \
            f"their half rounds up to {worst:.0f} ms behind their clocks"
        return (f"{', '.join(late)} ran {late_by} at p90 (round period {limit:.0f} ms): short of CPU "
                "(give the agents a larger share, e.g. nice, or a slower pace: --rate, --round-period)")
    if not behind_ms or float(behind_ms[1]) <= limit:
        return None
    return (f"its half rounds ran {float(behind_ms[1]):.0f} ms behind its clock at p90 (round period {limit:.0f} ms): "
            "the process was short of CPU (give it a larger share, e.g. nice, or a slower pace: --rate, --round-period)")


_OWN = ("unconverged", "provisional", "unanswered", "not_run", "revised", "without_members", "reanswered")


def placed_steps(steps: Iterable) -> list[bool]:
    """Per :class:`decentral.observations.EstimateStep`: whether it places at least one assembly."""
    return [bool(step.poses) for step in steps]
