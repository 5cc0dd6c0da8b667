"""Configuration of the simulated network and the per-link random streams.

:class:`LinkConfig` is the behaviour of one directed link (loss, latency, jitter, duplication,
corruption, bandwidth), :class:`Partition` and :class:`Crash` are the faults, and
:class:`NetworkConfig` gathers them for a :class:`protocols.network.SimulatedNetwork`.
:func:`link_root` and :func:`link_stream` derive each link's own random stream from one root, keyed
by the agents' names, so the simulated network and the real transports that imitate a link draw the
same pattern for the same seed.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import numpy as np

from decentral.errors import InputError
from protocols.messages import BROADCAST

__all__ = ["link_root", "link_stream", "LinkConfig", "Partition", "Crash", "NetworkConfig"]


def link_root(rng: np.random.Generator) -> list[int]:
    """Root entropy of the per-link streams, drawn once from ``rng`` (128 bits)."""
    return [int(x) for x in rng.integers(0, 2**32, size=4, dtype=np.uint64)]


def link_stream(root: list[int], a: str, b: str) -> np.random.Generator:
    """The random stream of the directed link ``a -> b``: ``SeedSequence(root, spawn_key=(crc32(a), crc32(b)))``.

    Keyed by the names, so adding an agent or a link never changes another link's stream, and two
    processes given the same root draw the same stream for the same link.
    """
    seq = np.random.SeedSequence(root, spawn_key=(zlib.crc32(a.encode("utf-8")), zlib.crc32(b.encode("utf-8"))))
    return np.random.default_rng(seq)


def _prob(value: float, name: str) -> None:
    if not (isinstance(value, (int, float)) and 0.0 <= value <= 1.0):
        raise InputError(f"must be a probability in [0, 1], got {value!r}", field=name)


@dataclass(frozen=True)
class LinkConfig:
    """Behaviour of one directed link.

    Attributes
    ----------
    drop : float
        Probability that a copy is lost.
    latency : float
        Fixed propagation delay (s).
    jitter : float
        Extra delay drawn uniformly from ``[0, jitter]`` (s) per copy.
    duplicate : float
        Probability that a delivered copy arrives twice.
    corrupt : float
        Probability that a copy arrives with one byte flipped (rejected by the receiver's CRC check).
    bandwidth : float
        Cap in bytes per second (``inf`` = no cap); copies queue behind each other.
    mtu : int
        0 (default): ``drop`` is the chance that a copy is lost, whatever its size. Otherwise ``drop`` is
        the chance that each datagram of the UDP transport with this ``mtu`` is lost, and a copy is lost
        when its datagrams cannot be put back together (:func:`protocols.datagrams.frame_arrival`,
        parity included): a radio loses packets, so larger frames are lost more often.
    """

    drop: float = 0.0
    latency: float = 0.0
    jitter: float = 0.0
    duplicate: float = 0.0
    corrupt: float = 0.0
    bandwidth: float = math.inf
    mtu: int = 0

    def frame_loss(self, size: int) -> float:
        """Probability that a copy of ``size`` bytes is lost on this link."""
        if not self.mtu or not self.drop:
            return self.drop
        from protocols.datagrams import frame_arrival

        return 1.0 - frame_arrival(size, self.drop, self.mtu)

    def __post_init__(self) -> None:
        for name in ("drop", "duplicate", "corrupt"):
            _prob(getattr(self, name), name)
        for name in ("latency", "jitter"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"must be a finite non-negative time, got {v!r}", field=name)
        if not (isinstance(self.bandwidth, (int, float)) and self.bandwidth > 0):
            raise InputError(f"must be positive bytes per second, got {self.bandwidth!r}", field="bandwidth")
        if not (isinstance(self.mtu, int) and (self.mtu == 0 or 64 <= self.mtu <= 65507)):
            raise InputError(f"must be 0 or a datagram size of 64-65507 bytes, got {self.mtu!r}", field="mtu")


@dataclass(frozen=True)
class Partition:
    """During ``[t0, t1)`` agents in different groups cannot reach each other.

    Agents listed in no group form one more group together, so ``groups=({"A", "B"},)`` cuts
    ``{A, B}`` off from everyone else.
    """

    t0: float
    t1: float
    groups: tuple[frozenset[str], ...]

    def __post_init__(self) -> None:
        if not (self.t0 < self.t1):
            raise InputError("needs t0 < t1", field="partition")
        groups = tuple(frozenset(g) for g in self.groups)
        seen: set[str] = set()
        for g in groups:
            if seen & g:
                raise InputError("an agent is in two groups", field="partition.groups")
            seen |= g
        object.__setattr__(self, "groups", groups)

    def _group(self, agent: str) -> int:
        for i, g in enumerate(self.groups):
            if agent in g:
                return i
        return -1

    def separates(self, a: str, b: str, t: float) -> bool:
        """Whether ``a`` and ``b`` are cut off from each other at time ``t``."""
        return self.t0 <= t < self.t1 and self._group(a) != self._group(b)


@dataclass(frozen=True)
class Crash:
    """``agent`` is down (neither sends nor receives) during ``[t0, t1)``; ``t1 = inf`` never returns."""

    agent: str
    t0: float
    t1: float = math.inf

    def __post_init__(self) -> None:
        if not (self.t0 < self.t1):
            raise InputError("needs t0 < t1", field="crash")

    def down(self, agent: str, t: float) -> bool:
        return agent == self.agent and self.t0 <= t < self.t1


@dataclass(frozen=True)
class NetworkConfig:
    """Configuration of a :class:`protocols.network.SimulatedNetwork`.

    Attributes
    ----------
    agents : tuple of str
        Every agent attached to the network (unique names).
    link : LinkConfig
        Default behaviour of every directed link.
    links : Mapping[tuple[str, str], LinkConfig]
        Per directed link ``(sender, receiver)`` overrides.
    partitions : tuple of Partition
    crashes : tuple of Crash
    round_period : float
        Seconds per synchronous round (see :meth:`protocols.network.SimulatedNetwork.time_of_round`).
    """

    agents: tuple[str, ...]
    link: LinkConfig = field(default_factory=LinkConfig)
    links: Mapping[tuple[str, str], LinkConfig] = field(default_factory=dict)
    partitions: tuple[Partition, ...] = ()
    crashes: tuple[Crash, ...] = ()
    round_period: float = 0.1

    def __post_init__(self) -> None:
        agents = tuple(self.agents)
        if len(set(agents)) != len(agents) or not all(isinstance(a, str) and a and a != BROADCAST for a in agents):
            raise InputError("agent names must be unique, non-empty and not the broadcast marker", field="agents")
        object.__setattr__(self, "agents", agents)
        for (a, b) in self.links:
            if a not in agents or b not in agents:
                raise InputError(f"link {a!r}->{b!r} names an unknown agent", field="links")
        object.__setattr__(self, "links", MappingProxyType(dict(self.links)))
        object.__setattr__(self, "partitions", tuple(self.partitions))
        object.__setattr__(self, "crashes", tuple(self.crashes))
        if not (self.round_period > 0 and math.isfinite(self.round_period)):
            raise InputError("must be a positive finite time", field="round_period")

    def link_config(self, a: str, b: str) -> LinkConfig:
        """Behaviour of the directed link ``a -> b``."""
        return self.links.get((a, b), self.link)
