"""The peers file and the key files: who is on the network, where, and with which public key.

``PEERS.json`` (format ``decentral.peers/1``) maps every assembly name to the address its agent
listens on and its Ed25519 public key (32 raw bytes, standard base64)::

    {"format": "decentral.peers/1",
     "peers": {"A0": {"address": "tcp://127.0.0.1:47000", "public_key": "q83v...="},
               "A1": {"address": "tcp://192.168.1.12:47000", "public_key": "HxQ2...="}}}

An address is ``tcp://HOST:PORT`` (HOST a name, an IPv4 address or a bracketed IPv6 address, PORT
1..65535) or ``ipc://PATH``. Every agent gets the same file; nothing in it is secret.

A private key file (format ``decentral.key/1``, written with mode 0600) holds one agent's name, its
private key (the 32-byte Ed25519 seed, base64) and, as a check, its public key::

    {"format": "decentral.key/1", "name": "A0", "private_key": "...", "public_key": "q83v...="}

A public key file (format ``decentral.pubkey/1``) holds the name and the public key only, for
handing to whoever assembles the peers file. Loading any of them raises
:class:`decentral.errors.InputError` naming the file and the field.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from typing import Any, Mapping

from nacl.signing import SigningKey

from decentral.errors import InputError
from protocols.auth import (
    b64decode_key,
    b64encode,
    check_public_key,
    private_key_bytes,
    private_key_from_bytes,
    public_key_bytes,
)
from protocols.messages import BROADCAST

__all__ = [
    "PEERS_FORMAT",
    "KEY_FORMAT",
    "PUBKEY_FORMAT",
    "Peer",
    "check_address",
    "check_name",
    "load_peers",
    "peers_json",
    "load_private_key",
    "private_key_json",
    "public_key_json",
]

PEERS_FORMAT = "decentral.peers/1"
KEY_FORMAT = "decentral.key/1"
PUBKEY_FORMAT = "decentral.pubkey/1"
_TCP = re.compile(r"^tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):([0-9]{1,5})$")
_MAX_FILE = 16 * 2**20  # a peers file of 100,000 agents is ~10 MB


@dataclass(frozen=True)
class Peer:
    """One agent as every other agent knows it.

    Attributes
    ----------
    name : str
        Its assembly name.
    address : str
        Where its inbound socket listens (``tcp://HOST:PORT`` or ``ipc://PATH``).
    public_key : bytes
        Its raw 32-byte Ed25519 public key.
    """

    name: str
    address: str
    public_key: bytes


def check_address(address: object, *, allow_any_port: bool = False) -> str:
    """Return ``address`` if it is a valid peer address, else raise ``ValueError`` saying why.

    ``allow_any_port`` also accepts port 0 (bind to a free port; never valid in a peers file).
    """
    if not isinstance(address, str):
        raise ValueError("must be a string like tcp://127.0.0.1:47000")
    if address.startswith("ipc://") and len(address) > len("ipc://"):
        return address
    m = _TCP.match(address)
    if m is None:
        raise ValueError(f"{address!r} is not tcp://HOST:PORT or ipc://PATH")
    port = int(m.group(2))
    if not (0 if allow_any_port else 1) <= port <= 65535:
        raise ValueError(f"port {port} is out of range")
    return address


def check_name(name: object) -> str:
    """Return ``name`` if it can name an agent (1-255 UTF-8 bytes, not the broadcast marker), else ``ValueError``."""
    if not isinstance(name, str) or not name or len(name.encode("utf-8")) > 255 or name == BROADCAST:
        raise ValueError(f"{name!r} is not a valid agent name (1-255 bytes, not {BROADCAST!r})")
    return name


def _read_json(path: str | os.PathLike, fmt: str) -> dict:
    source = str(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(_MAX_FILE + 1)
    except OSError as err:
        raise InputError(f"cannot read ({err.strerror})", source=source) from None
    if len(raw) > _MAX_FILE:
        raise InputError(f"larger than {_MAX_FILE} bytes", source=source)
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"not valid JSON ({err})", source=source) from None
    if not isinstance(data, dict):
        raise InputError("must be a JSON object", source=source)
    if data.get("format") != fmt:
        raise InputError(f"must be {fmt!r}, got {data.get('format')!r}", source=source, field="format")
    return data


def _field(data: Mapping, key: str, source: str, where: str, check) -> Any:
    path = f"{where}.{key}" if where else key
    if key not in data:
        raise InputError("missing", source=source, field=path)
    try:
        return check(data[key])
    except ValueError as err:
        raise InputError(str(err), source=source, field=path) from None


def load_peers(path: str | os.PathLike) -> dict[str, Peer]:
    """Read a ``decentral.peers/1`` file: name -> :class:`Peer`, in file order.

    Raises
    ------
    InputError
        Unreadable file, wrong format, no peers, or a bad name, address or key (naming the field).
    """
    source = str(path)
    data = _read_json(path, PEERS_FORMAT)
    peers = data.get("peers")
    if not isinstance(peers, dict) or not peers:
        raise InputError("must be a non-empty object of name -> {address, public_key}", source=source,
                         field="peers")
    out: dict[str, Peer] = {}
    addresses: dict[str, str] = {}
    for name, entry in peers.items():
        where = f"peers.{name}"
        try:
            check_name(name)
        except ValueError as err:
            raise InputError(str(err), source=source, field=where) from None
        if not isinstance(entry, dict):
            raise InputError("must be an object with address and public_key", source=source, field=where)
        address = _field(entry, "address", source, where, check_address)
        if address in addresses:
            raise InputError(f"same address as {addresses[address]!r}", source=source, field=f"{where}.address")
        addresses[address] = name
        key = _field(entry, "public_key", source, where, lambda v: check_public_key(b64decode_key(v)))
        out[name] = Peer(name, address, key)
    return out


def peers_json(peers: Mapping[str, Peer]) -> dict:
    """The ``decentral.peers/1`` JSON object of ``peers``."""
    return {"format": PEERS_FORMAT,
            "peers": {p.name: {"address": p.address, "public_key": b64encode(p.public_key)} for p in peers.values()}}


def private_key_json(name: str, key: SigningKey) -> dict:
    """The ``decentral.key/1`` JSON object of agent ``name``'s signing key (secret: write it with mode 0600)."""
    return {"format": KEY_FORMAT, "name": name, "private_key": b64encode(private_key_bytes(key)),
            "public_key": b64encode(public_key_bytes(key))}


def public_key_json(name: str, key: SigningKey) -> dict:
    """The ``decentral.pubkey/1`` JSON object of agent ``name``'s public key."""
    return {"format": PUBKEY_FORMAT, "name": name, "public_key": b64encode(public_key_bytes(key))}


def load_private_key(path: str | os.PathLike) -> tuple[str, SigningKey]:
    """Read a ``decentral.key/1`` file: (agent name, signing key).

    Raises
    ------
    InputError
        Unreadable file, wrong format, bad name or key, or a public key that does not belong to the
        private key.
    """
    source = str(path)
    data = _read_json(path, KEY_FORMAT)
    name = _field(data, "name", source, "", check_name)
    key = private_key_from_bytes(_field(data, "private_key", source, "", b64decode_key))
    if "public_key" in data:
        public = _field(data, "public_key", source, "", b64decode_key)
        if public != public_key_bytes(key):
            raise InputError("does not belong to private_key", source=source, field="public_key")
    return name, key
