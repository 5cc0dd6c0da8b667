"""protocols: messages and their wire encoding, the simulated lossy network, transports, and the
consensus and aggregation protocols that agents run over them. Depends only on ``decentral``.

The real transport (:mod:`protocols.zmq_transport`), its signed frames (:mod:`protocols.auth`) and
the peers and key files (:mod:`protocols.peers`) are imported from their modules, so that importing
``protocols`` does not load ZeroMQ or OpenSSL."""

from protocols.aggregation import TreeAggregation, choose_parent, tree_from_edges
from protocols.consensus import GatherResult, RoundGather, exchange_round
from protocols.messages import (
    BROADCAST,
    AdmmDual,
    AdmmPrimal,
    Heartbeat,
    Message,
    OdometryReport,
    PoseEstimates,
    Tracks,
    decode,
    register,
)
from protocols.network import Crash, LinkConfig, NetworkConfig, Partition, SimulatedNetwork
from protocols.transport import Counts, Delivery, Transport, TransportStats, merge_stats

__all__ = [
    "BROADCAST",
    "Message",
    "register",
    "decode",
    "Tracks",
    "PoseEstimates",
    "AdmmPrimal",
    "AdmmDual",
    "Heartbeat",
    "OdometryReport",
    "Transport",
    "Delivery",
    "Counts",
    "TransportStats",
    "merge_stats",
    "LinkConfig",
    "Partition",
    "Crash",
    "NetworkConfig",
    "SimulatedNetwork",
    "RoundGather",
    "GatherResult",
    "exchange_round",
    "TreeAggregation",
    "choose_parent",
    "tree_from_edges",
]
