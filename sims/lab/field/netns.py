"""Network namespaces for the field harness: one per agent and a hub, joined by a bridge in the hub.

Every name starts with ``dcrt-`` and a tag of the run, so runs never collide with each other or with
anything else on the machine; :class:`Field` removes every namespace it made when its ``with`` block
ends (deleting a namespace deletes its links and firewall rules), also on error or interrupt.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass, field

from decentral.errors import DecentralError

__all__ = ["PREFIX", "Field", "available", "leftovers"]

PREFIX = "dcrt-"
_SUBNET = "10.231.{}.{}"


def available() -> str | None:
    """Why the harness cannot run here (``None`` when it can): Linux, root and ``ip`` are needed."""
    if not os.path.exists("/proc/self/ns/net"):
        return "needs Linux network namespaces"
    if os.geteuid() != 0:
        return "needs root (CAP_NET_ADMIN) to create network namespaces"
    if shutil.which("ip") is None:
        return "needs iproute2's `ip`"
    return None


def leftovers(tag: str = "") -> list[str]:
    """Namespaces named ``dcrt-TAG...`` that exist now."""
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    return [line.split()[0] for line in out.splitlines() if line.startswith(PREFIX + tag)]


def _ip(*args: str) -> None:
    res = subprocess.run(["ip", *args], capture_output=True, text=True)
    if res.returncode != 0:
        raise DecentralError(f"ip {' '.join(args)}: {res.stderr.strip()}")


@dataclass
class Field:
    """``n`` agent namespaces and a hub on one bridge (use as a context manager).

    Attributes
    ----------
    n : int
        Agent namespaces (``dcrt-TAG-0`` ... ``dcrt-TAG-{n-1}``), each with ``eth0`` at :meth:`ip` ``(i)``.
    tag : str
        Distinguishes this run's namespaces (default: from the process id).
    loss : float
        Share of the TCP packets arriving at the hub from the agents that its kernel drops (iptables
        ``statistic --mode random``; the kernel's draw takes no seed). Every TCP packet crosses the hub
        once, so this is the per-packet loss of a link, for data segments and their acknowledgements
        alike: TCP retransmits in the kernel, as over a lossy radio. Datagrams are dropped by the link
        relays instead, from each link's seeded stream (:mod:`sims.lab.field.proxy`): reproducible.
        (A fixed every-n-th pattern is no radio: it drops one piece of every frame cut into n datagrams.)
    """

    n: int
    tag: str = field(default_factory=lambda: f"{os.getpid() % 100000:05d}")
    loss: float = 0.0
    made: list[str] = field(default_factory=list)

    @property
    def hub(self) -> str:
        return f"{PREFIX}{self.tag}-h"

    def ns(self, i: int) -> str:
        """Agent ``i``'s namespace."""
        return f"{PREFIX}{self.tag}-{i}"

    @property
    def hub_ip(self) -> str:
        return _SUBNET.format(0, 1)

    def ip(self, i: int) -> str:
        """Agent ``i``'s address."""
        return _SUBNET.format(1 + (10 + i) // 250, (10 + i) % 250 + 1)

    def exec(self, ns: str) -> list[str]:
        """The command prefix that runs a program in namespace ``ns``."""
        return ["ip", "netns", "exec", ns]

    def __enter__(self) -> "Field":
        why = available()
        if why:
            raise DecentralError(f"field harness: {why}")
        try:
            self._build()
        except BaseException:
            self.close()
            raise
        return self

    def _build(self) -> None:
        for name in [self.hub] + [self.ns(i) for i in range(self.n)]:
            _ip("netns", "add", name)
            self.made.append(name)
            _ip("-n", name, "link", "set", "lo", "up")
        hub = self.hub
        _ip("-n", hub, "link", "add", "br0", "type", "bridge")
        _ip("-n", hub, "addr", "add", f"{self.hub_ip}/16", "dev", "br0")
        _ip("-n", hub, "link", "set", "br0", "up")
        for i in range(self.n):
            _ip("-n", hub, "link", "add", f"dv{i}", "type", "veth", "peer", "name", "eth0", "netns", self.ns(i))
            _ip("-n", hub, "link", "set", f"dv{i}", "master", "br0")
            _ip("-n", hub, "link", "set", f"dv{i}", "up")
            _ip("-n", self.ns(i), "addr", "add", f"{self.ip(i)}/16", "dev", "eth0")
            _ip("-n", self.ns(i), "link", "set", "eth0", "up")
        if self.loss > 0:
            if shutil.which("iptables") is None:
                raise DecentralError("field harness: packet loss needs iptables")
            mode = ["-p", "tcp", "-m", "statistic", "--mode", "random", "--probability", f"{self.loss:.6f}"]
            res = subprocess.run(self.exec(hub) + ["iptables", "-A", "INPUT", "-i", "br0", *mode, "-j", "DROP"],
                                 capture_output=True, text=True)
            if res.returncode != 0:
                raise DecentralError(f"field harness: iptables: {res.stderr.strip()}")

    def close(self) -> None:
        """Delete every namespace this field made (idempotent)."""
        while self.made:
            name = self.made.pop()
            subprocess.run(["ip", "netns", "del", name], capture_output=True)

    def __exit__(self, *exc) -> None:
        self.close()
