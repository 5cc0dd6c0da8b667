"""The delta half of the tree aggregation: what a child sends up, and how a parent rebuilds it.

Transport-free state machines (the agent in :mod:`agents.assembly` moves the messages):

- :class:`DeltaSender` remembers, per parent, which forms it has sent there, and packs a window's
  records as only the forms that parent lacks plus a digest per record
  (:class:`protocols.delta_messages.DeltaBundle`; the same for an agent's own record by broadcast,
  :class:`protocols.delta_messages.FactorDelta`, with everyone as the "parent");
- :class:`FormCache` keeps every form an agent has seen for the current window, keyed by owner and
  keys, and rebuilds a record from a digest: exactly, or not at all (the parent then leaves it
  unacknowledged and the child sends it whole).

A form here is ``(keys, problem)``: ``keys`` the ``((assembly index, step), (assembly index, step))``
of its two poses and ``problem`` its :class:`decentral.admm.LocalProblem`.
"""

from __future__ import annotations

from protocols.delta_messages import form_crc, record_digest

__all__ = ["FormCache", "DeltaSender"]


def _crc(problem) -> int:
    return form_crc(problem.M, problem.b_z, problem.c_z)


def _span(keys) -> tuple[int, int]:
    steps = [k for _, k in keys]
    return min(steps), max(steps)


class FormCache:
    """Every agent's forms seen here for the window: ``(owner, keys) -> (crc, problem)``."""

    def __init__(self) -> None:
        self._forms: dict[tuple, tuple[int, object]] = {}

    def __len__(self) -> int:
        return len(self._forms)

    def remember(self, owner: int, forms) -> None:
        """Keep ``owner``'s forms ``[(keys, problem)]`` (a form with the same keys is replaced)."""
        for keys, problem in forms:
            self._forms[(owner, tuple(keys))] = (_crc(problem), problem)

    def slide(self, first: int) -> None:
        """Forget forms with a pose before step ``first`` (they left the window)."""
        self._forms = {key: v for key, v in self._forms.items() if _span(key[1])[1] >= first}

    def clear(self) -> None:
        self._forms.clear()

    @staticmethod
    def whole(forms, digest: tuple[int, int]) -> list | None:
        """The record ``forms`` ``[(keys, problem)]`` (in key order) if they are all of it (``digest``: count,
        XOR of CRCs), else ``None``."""
        forms = sorted(((tuple(keys), problem) for keys, problem in forms), key=lambda f: f[0])
        if not forms or record_digest([_crc(problem) for _, problem in forms]) != tuple(digest):
            return None
        return forms

    def rebuild(self, member: int, digest: tuple[int, int], first: int, last: int) -> list | None:
        """``member``'s record of the window ``[first, last]`` if the forms held here match ``digest``
        (count, XOR of CRCs) exactly, else ``None``. Forms in key order."""
        forms = sorted((keys, crc, problem) for (owner, keys), (crc, problem) in self._forms.items()
                       if owner == member and first <= _span(keys)[0] and _span(keys)[1] <= last)
        if record_digest([crc for _, crc, _ in forms]) != tuple(digest):
            return None
        return [(keys, problem) for keys, _, problem in forms]


class DeltaSender:
    """Per parent, the forms already sent to it: a window's records go up as what is new to that parent."""

    def __init__(self) -> None:
        self._sent: dict[int, set] = {}

    def slide(self, first: int) -> None:
        """Forget forms with a pose before step ``first``."""
        self._sent = {p: {e for e in sent if _span(e[1])[1] >= first} for p, sent in self._sent.items()}

    def delta(self, parent: int, records: dict, step: int, every: bool = False,
              again_from: int | None = None) -> tuple[dict, list] | None:
        """``(carried, digests)`` for sending ``records`` (member -> ``[(keys, problem)]``) to ``parent``:
        ``carried`` member -> ``[(keys, M, b_z, c_z, count)]`` of the forms it has not had from here (``every``:
        all of them, a resend; ``again_from``: the forms with a pose at or after this step too, sent or not: a
        receiver that lost the last of them can still rebuild), ``digests`` one ``(count, crc)`` per member in
        sorted order. ``None`` when a form
        is not over two poses within 255 steps of ``step`` (the records then go as a
        :class:`protocols.admm_messages.FormBundle`). The forms are marked as sent."""
        sent = set() if every else self._sent.setdefault(parent, set())
        carried, digests, new = {}, [], set()
        for member in sorted(records):
            crcs = []
            for keys, problem in records[member]:
                if len(keys) != 2 or not 0 <= step - _span(keys)[0] <= 255:
                    return None
                crc = _crc(problem)
                crcs.append(crc)
                if (member, tuple(keys), crc) not in sent or (again_from is not None and _span(keys)[1] >= again_from):
                    carried.setdefault(member, []).append((keys, problem.M, problem.b_z, problem.c_z, problem.count))
                    new.add((member, tuple(keys), crc))
            digests.append(record_digest(crcs))
        self._sent.setdefault(parent, set()).update(new)
        return carried, digests
