"""Peers and key files: round trips, and every defect named by file and field."""

from __future__ import annotations

import json

import pytest

from decentral.errors import InputError
from protocols.auth import new_private_key, public_key_bytes
from protocols.peers import (
    Peer,
    check_address,
    load_peers,
    load_private_key,
    peers_json,
    private_key_json,
)

KEY = new_private_key()


def good_peers() -> dict:
    peers = {n: Peer(n, f"tcp://127.0.0.1:{47000 + i}", public_key_bytes(new_private_key()))
             for i, n in enumerate("AB")}
    return peers_json(peers)


def write(tmp_path, doc, name="peers.json"):
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    if name.endswith(".key.json"):
        path.chmod(0o600)  # as `decentral keys` writes them
    return path


def test_peers_file_round_trips(tmp_path):
    """A peers table written with peers_json loads back equal, in order."""
    peers = {n: Peer(n, a, public_key_bytes(new_private_key()))
             for n, a in (("A1", "tcp://10.0.0.2:5000"), ("A0", "tcp://[::1]:5001"), ("A2", "ipc:///tmp/a2"))}
    assert load_peers(write(tmp_path, peers_json(peers))) == peers


def test_key_file_round_trips(tmp_path):
    """A key file loads back to the same name and a key with the same public half."""
    name, key = load_private_key(write(tmp_path, private_key_json("A0", KEY), "A0.key.json"))
    assert name == "A0" and public_key_bytes(key) == public_key_bytes(KEY)


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.update(format="decentral.peers/0"), "format"),
    (lambda d: d.update(peers={}), "peers"),
    (lambda d: d.update(peers=[1]), "peers"),
    (lambda d: d["peers"].update({"*": d["peers"]["A"]}), "peers.*"),
    (lambda d: d["peers"]["A"].pop("address"), "peers.A.address"),
    (lambda d: d["peers"]["A"].update(address="udp://x:1"), "peers.A.address"),
    (lambda d: d["peers"]["A"].update(address="tcp://127.0.0.1:0"), "peers.A.address"),
    (lambda d: d["peers"]["A"].update(address="tcp://127.0.0.1:70000"), "peers.A.address"),
    (lambda d: d["peers"]["B"].update(address=d["peers"]["A"]["address"]), "peers.B.address"),
    (lambda d: d["peers"]["A"].update(public_key="AAAA"), "peers.A.public_key"),
    (lambda d: d["peers"]["A"].update(public_key="not base64!"), "peers.A.public_key"),
    (lambda d: d["peers"]["A"].update(public_key=7), "peers.A.public_key"),
    (lambda d: d["peers"]["A"].update(public_key="A" * 43 + "="), "peers.A.public_key"),  # 32 zero bytes: no key
    (lambda d: d["peers"].update(A="x"), "peers.A"),
])
def test_bad_peers_files_name_file_and_field(tmp_path, mutate, field):
    """Each defect of a peers file raises InputError naming the file and the field."""
    doc = good_peers()
    mutate(doc)
    path = write(tmp_path, doc)
    with pytest.raises(InputError) as err:
        load_peers(path)
    assert err.value.source == str(path) and err.value.field == field


@pytest.mark.parametrize("text", ["", "{", "[]", "\xff"])
def test_unreadable_peers_files_name_the_file(tmp_path, text):
    """Empty, truncated, non-object and non-UTF-8 files raise InputError naming the file."""
    path = tmp_path / "peers.json"
    path.write_bytes(text.encode("latin-1"))
    with pytest.raises(InputError) as err:
        load_peers(path)
    assert err.value.source == str(path)


def test_missing_file_is_an_input_error(tmp_path):
    """A peers or key file that does not exist raises InputError naming it."""
    for load in (load_peers, load_private_key):
        with pytest.raises(InputError, match="cannot read"):
            load(tmp_path / "nope.json")


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.update(format="decentral.pubkey/1"), "format"),
    (lambda d: d.pop("name"), "name"),
    (lambda d: d.update(name=""), "name"),
    (lambda d: d.update(private_key="AAAA"), "private_key"),
    (lambda d: d.update(public_key=private_key_json("X", new_private_key())["public_key"]), "public_key"),
])
def test_bad_key_files_name_file_and_field(tmp_path, mutate, field):
    """Each defect of a key file (including a public key that is not its private key's) names file and field."""
    doc = private_key_json("A0", KEY)
    mutate(doc)
    path = write(tmp_path, doc, "A0.key.json")
    with pytest.raises(InputError) as err:
        load_private_key(path)
    assert err.value.source == str(path) and err.value.field == field


def test_addresses():
    """tcp with host and port, bracketed IPv6 and ipc paths are addresses; port 0 only when binding."""
    for ok in ("tcp://127.0.0.1:1", "tcp://robot-3.local:65535", "tcp://[fe80::1]:5000", "ipc:///tmp/x"):
        assert check_address(ok) == ok
    for bad in ("tcp://127.0.0.1", "tcp://:5", "127.0.0.1:5", "ipc://", "tcp://a b:5", None):
        with pytest.raises(ValueError):
            check_address(bad)
    assert check_address("tcp://127.0.0.1:0", allow_any_port=True)


@pytest.mark.parametrize("mode", [0o640, 0o604, 0o644])
def test_a_key_file_others_may_read_is_refused(tmp_path, mode):
    """A private key file readable by group or others is refused naming the file and its mode."""
    path = write(tmp_path, private_key_json("A0", KEY), "A0.key.json")
    path.chmod(mode)
    with pytest.raises(InputError, match=f"mode {mode:04o}") as err:
        load_private_key(path)
    assert err.value.source == str(path)
    assert load_private_key(path, allow_readable=True)[0] == "A0"


@pytest.mark.parametrize("other", ["tcp://localhost:5000", "tcp://127.0.0.01:5000", "tcp://127.0.0.1:5000",
                                   "tcp://127.1:5000"])
def test_two_peers_at_one_resolved_address_are_refused(tmp_path, other):
    """Addresses are compared after resolution: localhost, 127.0.0.01 and 127.0.0.1 are one host."""
    doc = good_peers()
    doc["peers"]["A"]["address"] = "tcp://127.0.0.1:5000"
    doc["peers"]["B"]["address"] = other
    with pytest.raises(InputError, match="same address as 'A'"):
        load_peers(write(tmp_path, doc))
    doc["peers"]["B"]["address"] = other.replace("5000", "5001")
    assert len(load_peers(write(tmp_path, doc))) == 2
