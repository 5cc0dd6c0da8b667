"""Seeded user-space impairment of directed links: one UDP relay and one TCP relay per link.

Run as ``python -m sims.lab.field.proxy CONFIG.json`` (in the hub namespace); it prints ``ready`` once
every relay listens and runs until killed. ``CONFIG.json`` is
``{"host": IP, "links": [{"name": "A0->A1", "port": P, "to": [IP, PORT], "delay": s, "jitter": 0.2,
"rate": bytes_per_s_or_null, "loss": share, "seed": int}]}``: what arrives on ``host:P`` (UDP datagrams,
or a TCP stream) leaves for ``to`` after ``delay * (1 + jitter * u)`` seconds, ``u`` uniform in [-1, 1]
drawn per datagram (or per chunk of a stream) from the link's own seeded stream, and no faster than
``rate``. Datagrams are delayed independently (jitter reorders them, as a radio's retries do) and each
is lost with probability ``loss``, drawn from the same seeded stream (the same datagrams in the same
order meet the same fate); a TCP stream keeps its order (each chunk leaves no earlier than the one
before) and loses nothing here: its packets are dropped by the hub's kernel
(:class:`sims.lab.field.netns.Field`), so that TCP meets real retransmissions.
"""

from __future__ import annotations

import asyncio
import json
import sys

import numpy as np

__all__ = ["LinkDelay", "main"]


class LinkDelay:
    """When each unit of a link's traffic leaves: seeded delay and jitter, rate limit, optional order.

    Examples
    --------
    >>> d = LinkDelay(delay=0.05, jitter=0.2, rate=None, seed=1)
    >>> 0.04 <= d.departure(0.0, 100) <= 0.06
    True
    """

    def __init__(self, delay: float, jitter: float, rate: float | None, seed: int, ordered: bool = False,
                 loss: float = 0.0):
        self.delay, self.jitter, self.rate, self.ordered, self.loss = float(delay), float(jitter), rate, ordered, float(loss)
        self._rng = np.random.default_rng(seed)
        self._free = 0.0  # when the link's sender side is free again (rate limit)
        self._last = 0.0  # departure of the previous unit (ordered streams)

    def lost(self) -> bool:
        """Whether the next datagram is lost (a draw from the link's stream, made for every datagram)."""
        return bool(self._rng.random() < self.loss)

    def departure(self, now: float, size: int) -> float:
        """Time at which a unit of ``size`` bytes that arrived at ``now`` leaves."""
        start = now
        if self.rate:
            start = max(now, self._free)
            self._free = start + size / self.rate
        u = 2.0 * self._rng.random() - 1.0
        t = start + max(0.0, self.delay * (1.0 + self.jitter * u))
        if self.ordered:
            t = max(t, self._last)
        self._last = t
        return t


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, to, delay: LinkDelay, loop, out):
        self.to, self.delay, self.loop, self.out = tuple(to), delay, loop, out

    def datagram_received(self, data, addr):
        if self.delay.lost():
            return
        when = self.delay.departure(self.loop.time(), len(data))
        self.loop.call_at(when, self.out.sendto, data, self.to)


async def _pump(reader, writer, delay: LinkDelay, loop):
    queue: asyncio.Queue = asyncio.Queue()

    async def release():
        while True:
            when, data = await queue.get()
            if data is None:
                break
            wait = when - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
            writer.write(data)
            await writer.drain()

    sender = asyncio.ensure_future(release())
    try:
        while True:
            data = await reader.read(65536)
            if not data:
                break
            await queue.put((delay.departure(loop.time(), len(data)), data))
    except (ConnectionError, OSError):
        pass
    await queue.put((0.0, None))
    try:
        await sender
    except (ConnectionError, OSError):
        pass
    writer.close()


async def _serve(config: dict) -> None:
    loop = asyncio.get_running_loop()
    host = config["host"]
    servers = []
    for k, link in enumerate(config["links"]):
        seed = int(link.get("seed", k))
        args = (float(link.get("delay", 0.0)), float(link.get("jitter", 0.0)), link.get("rate"))
        loss = float(link.get("loss", 0.0))
        out, _ = await loop.create_datagram_endpoint(asyncio.DatagramProtocol, local_addr=(host, 0))
        await loop.create_datagram_endpoint(lambda: _Udp(link["to"], LinkDelay(*args, seed, loss=loss), loop, out),
                                            local_addr=(host, int(link["port"])))

        async def accept(reader, writer, link=link, args=args, seed=seed):
            try:
                up_r, up_w = await asyncio.open_connection(*link["to"])
            except OSError:
                writer.close()
                return
            forward = LinkDelay(*args, seed + 1_000_003, ordered=True)
            back = LinkDelay(*args, seed + 2_000_003, ordered=True)  # the reverse leg: handshakes, replies
            await asyncio.gather(_pump(reader, up_w, forward, loop), _pump(up_r, writer, back, loop))

        servers.append(await asyncio.start_server(accept, host, int(link["port"])))
    print("ready", flush=True)
    await asyncio.Event().wait()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    with open(argv[0]) as fh:
        config = json.load(fh)
    try:
        asyncio.run(_serve(config))
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
