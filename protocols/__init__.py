"""protocols: messages and their wire encoding, the simulated lossy network, transports, and the
consensus and aggregation protocols that agents run over them. Depends only on ``decentral``."""

from protocols.aggregation import TreeAggregation, choose_parent, tree_from_edges
from protocols.consensus import GatherResult, RoundGather, exchange_round
from protocols.messages import (
    BROADCAST,
    AdmmDual,
    AdmmPrimal,
    CorruptFrame,
    Heartbeat,
    Message,
    OdometryReport,
    PoseEstimates,
    Tracks,
    decode,
    register,
)
from protocols.network import Crash, LinkConfig, NetworkConfig, Partition, SimulatedNetwork
from protocols.transport import REJECT_REASONS, Counts, Delivery, Transport, TransportStats, rejection_reason

__all__ = [
    "BROADCAST",
    "Message",
    "register",
    "decode",
    "CorruptFrame",
    "rejection_reason",
    "REJECT_REASONS",
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
