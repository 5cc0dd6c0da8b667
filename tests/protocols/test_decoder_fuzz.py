"""The wire decoder is total: every byte string decodes to a valid message or raises ProtocolError."""

from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest

from decentral.errors import ProtocolError
from protocols.admm_messages import ConfigAnnounce, ConfigRequest
from protocols.messages import CorruptFrame, Message, Tracks, decode
from protocols.network import NetworkConfig, SimulatedNetwork
from protocols.transport import rejection_reason
from tests.protocols.frame_fuzz import ISSUE_FRAME, hostile_frames, reseal, sample_messages


def _fuzz(seed: int, count: int) -> int:
    """Decode ``count`` hostile frames; fail on any other exception or warning; return how many decoded."""
    decoded = 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for frame in hostile_frames(seed, count):
            try:
                msg = decode(frame)
            except ProtocolError:
                continue
            except BaseException as err:  # noqa: BLE001 - the property under test
                pytest.fail(f"{type(err).__name__} escaped the decoder on frame {frame.hex()}: {err}")
            assert isinstance(msg, Message) and decode(msg.to_bytes()) == msg
            decoded += 1
    assert not caught, f"the decoder warned: {caught[0].message}"
    return decoded


def test_issue_frame_is_refused_with_protocol_error():
    """The 76-byte frame (valid CRC, zero-element array of overflowing dimensions) raises ProtocolError."""
    assert len(ISSUE_FRAME) == 76
    with pytest.raises(ProtocolError, match="too large"):
        decode(ISSUE_FRAME)


def test_fuzz_5000_frames_only_protocol_error_escapes():
    """5,000 mutated, retyped, oversized and random frames: only ProtocolError, no warning."""
    decoded = _fuzz(seed=13, count=5_000)
    assert 0 < decoded < 5_000  # the generator reaches both outcomes


@pytest.mark.slow
def test_fuzz_100000_frames_only_protocol_error_escapes():
    """100,000 hostile frames from another seed: only ProtocolError, no warning."""
    _fuzz(seed=2026, count=100_000)


@pytest.mark.parametrize("ids", [[np.nan, 2.7, 5.9], [1.0, 2.0], [True, False], [2**64 - 1]])
def test_integer_fields_refuse_non_integers(ids):
    """Ids sent as floats (NaN, fractions, even whole floats), bools or out of int64 range are refused."""
    valid = ConfigRequest(sender="a", receiver="b", round=0, ids=[1, 2])
    frame = valid.to_bytes()
    body = frame[16:]
    at = body.index(b"A")
    arr = np.asarray(ids)
    code = {"f": 12, "b": 1, "u": 9}[arr.dtype.kind]
    arr = arr.astype({12: "<f8", 1: "?", 9: "<u8"}[code])
    forged = body[:at] + b"A" + struct.pack("<BBI", code, 1, arr.size) + arr.tobytes()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ProtocolError, match="integer"):
            decode(reseal(frame[:16] + forged))
        with pytest.raises(ProtocolError, match="integer"):
            ConfigAnnounce(sender="a", receiver="b", round=0, step=0, ids=ids, centres=np.zeros((len(ids), 3)))


def test_empty_id_lists_are_still_integer_arrays():
    """An empty list (float64 to numpy) is accepted as an empty id array."""
    msg = Tracks(sender="a", receiver="b", round=0, t=0.0, camera="a/c", ids=[], uvr=np.zeros((0, 3)))
    assert msg.ids.dtype == np.int64 and decode(msg.to_bytes()) == msg


def test_framing_failures_are_corrupt_and_body_failures_malformed():
    """Damaged frames raise CorruptFrame (reason 'corrupt'); intact but invalid bodies are 'malformed'."""
    frame = sample_messages()[0].to_bytes()
    damaged = frame[:20] + bytes([frame[20] ^ 0xFF]) + frame[21:]
    with pytest.raises(CorruptFrame) as bad_crc:
        decode(damaged)
    with pytest.raises(ProtocolError) as bad_body:
        decode(ISSUE_FRAME)
    assert rejection_reason(bad_crc.value) == "corrupt"
    assert rejection_reason(bad_body.value) == "malformed" and not isinstance(bad_body.value, CorruptFrame)


def test_network_counts_malformed_frames_as_rejected():
    """A malformed frame on the simulated network is dropped and counted, never raised at the receiver."""
    network = SimulatedNetwork(NetworkConfig(agents=("A0", "A1")), np.random.default_rng(0))
    good = sample_messages()[4]
    network._send_copy("A0", "A1", "heartbeat", ISSUE_FRAME, 0.0)
    network._send_copy("A0", "A1", "heartbeat", b"DCNT garbage", 0.0)
    network.send(good, 0.0)
    got = network.poll("A1", 10.0)
    assert [d.message for d in got] == [good]
    stats = network.stats()
    assert stats.rejected == {"corrupt": 1, "malformed": 1}
    assert stats.as_dict()["rejected"] == {"corrupt": 1, "malformed": 1}
    assert stats.total.balanced()


def test_numbers_are_never_parsed_out_of_strings():
    """Float fields refuse strings that numpy would parse ("0.05"), on construction and on decode."""
    from protocols.ensemble.messages import Hello

    with pytest.raises(ProtocolError, match="numbers expected"):
        Hello(sender="a", receiver="b", round=0, z=("0.05", "0"))
    with pytest.raises(ProtocolError, match="numbers expected"):
        Tracks(sender="a", receiver="b", round=0, t=0.0, camera="a/c", ids=[1], uvr=[["1", "2", "3"]])


def test_every_registered_kind_has_a_fuzz_sample():
    """The fuzz corpus holds a valid message of every kind the protocol packages register (add new kinds
    to ``tests/protocols/frame_fuzz.py::sample_messages``)."""
    import importlib
    import pkgutil

    import protocols
    from protocols.messages import registered_kinds

    for module in pkgutil.walk_packages(protocols.__path__, "protocols."):
        importlib.import_module(module.name)
    shipped = {kind for kind, cls in registered_kinds().items() if cls.__module__.startswith("protocols.")}
    covered = {type(m).KIND for m in sample_messages()}
    assert shipped <= covered, sorted(shipped - covered)  # kinds registered by tests are not shipped
