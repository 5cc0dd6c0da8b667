"""A field harness: agents as processes in Linux network namespaces on a bridge, behind impaired links.

- :mod:`sims.lab.field.netns`: the namespaces (``dcrt-*``), the bridge and the addresses, removed on exit;
- :mod:`sims.lab.field.proxy`: the seeded user-space impairment of every directed link (delay, jitter,
  reordering, rate), for UDP datagrams and TCP streams alike; packet loss by the kernel (iptables);
- :mod:`sims.lab.field.starve`: busy processes on the same cores;
- :mod:`sims.lab.field.run`: a whole log as one ``decentral agent`` per namespace (:func:`run_field`).

Needs Linux, root (or CAP_NET_ADMIN), ``ip`` (iproute2) and, for loss, ``iptables``
(docs/processes.md, "Field harness").
"""

__all__ = ["netns", "proxy", "starve", "run"]
