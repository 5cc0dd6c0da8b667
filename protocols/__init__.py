"""protocols: messages and their wire encoding, the simulated lossy network, transports, and the
consensus and aggregation protocols that agents run over them. Depends only on ``decentral``."""

__all__: list[str] = []
