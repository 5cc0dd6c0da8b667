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

import ipaddress
import json
import os
import re
import socket
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
    "check_local_keys",
    "check_name",
    "load_peers",
    "peers_json",
    "load_private_key",
    "key_file_exposure",
    "read_private_key_text",
    "parse_private_key",
    "address_identity",
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


def address_identity(address: str) -> frozenset:
    """What ``address`` reaches, for telling two addresses apart: a set of ``(ip, port)`` pairs.

    A ``tcp://`` host is resolved (``localhost``, ``127.0.0.1`` and ``127.0.0.01`` are all
    ``("127.0.0.1", port)``; a name gives every address it resolves to; one that does not resolve
    stands for itself, lower-cased); an ``ipc://`` path is made absolute. Two peers whose
    identities intersect would listen on the same socket.
    """
    if address.startswith("ipc://"):
        return frozenset({("ipc", os.path.abspath(address[len("ipc://"):]))})
    m = _TCP.match(address)
    if m is None:
        return frozenset({("raw", address)})
    host, port = m.group(1).strip("[]"), int(m.group(2))
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError, OSError):
        return frozenset({(host.lower(), port)})
    out = set()
    for family, *_, sockaddr in infos:
        ip = sockaddr[0]
        if family == socket.AF_INET6 and ip.startswith("::ffff:") and "." in ip:
            ip = ip[len("::ffff:"):]  # an IPv4-mapped address is that IPv4 address
        out.add((ipaddress.ip_address(ip.split("%")[0]).compressed, port))
    return frozenset(out)


def check_local_keys(peers: Mapping[str, Peer], keys: Mapping[str, SigningKey]) -> None:
    """Every local agent's private key belongs to an agent of the peers file, and matches its public key there
    (``InputError`` naming the agent otherwise)."""
    for name, key in keys.items():
        if name not in peers:
            raise InputError(f"agent {name!r} is not in the peers file", field="peers")
        if public_key_bytes(key) != peers[name].public_key:
            raise InputError(f"the key of {name!r} does not match its public key in the peers file",
                             field=f"peers.{name}.public_key")


def check_name(name: object) -> str:
    """Return ``name`` if it can name an agent (1-255 UTF-8 bytes, not the broadcast marker), else ``ValueError``."""
    if not isinstance(name, str) or not name or len(name.encode("utf-8")) > 255 or name == BROADCAST:
        raise ValueError(f"{name!r} is not a valid agent name (1-255 bytes, not {BROADCAST!r})")
    return name


class _DuplicateKey(Exception):
    """A JSON object names a key twice (a peer given twice must not silently be the last one)."""


def _unique_keys(pairs: list) -> dict:
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


def _read_json(path: str | os.PathLike, fmt: str) -> dict:
    source = str(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(_MAX_FILE + 1)
    except OSError as err:
        raise InputError(f"cannot read ({err.strerror})", source=source) from None
    return _parse_json(raw, source, fmt)


def _parse_json(raw: bytes, source: str, fmt: str) -> dict:
    if len(raw) > _MAX_FILE:
        raise InputError(f"larger than {_MAX_FILE} bytes", source=source)
    try:
        data = json.loads(raw.decode("utf-8"), object_pairs_hook=_unique_keys)
    except _DuplicateKey as err:
        raise InputError("key given twice in one object", source=source, field=str(err)) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"not valid JSON ({err})", source=source) from None
    except RecursionError:
        raise InputError("not valid JSON (nested too deeply)", source=source) from None
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
    reached: dict[tuple, str] = {}  # (ip, port) -> the peer listening there
    for name, entry in peers.items():
        where = f"peers.{name}"
        try:
            check_name(name)
        except ValueError as err:
            raise InputError(str(err), source=source, field=where) from None
        if not isinstance(entry, dict):
            raise InputError("must be an object with address and public_key", source=source, field=where)
        address = _field(entry, "address", source, where, check_address)
        identity = address_identity(address)
        clash = next((reached[i] for i in identity if i in reached), None)
        if clash is not None:
            raise InputError(f"same address as {clash!r} ({address} resolves to where {clash!r} listens)",
                             source=source, field=f"{where}.address")
        reached.update((i, name) for i in identity)
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


def load_private_key(path: str | os.PathLike, *, allow_readable: bool = False) -> tuple[str, SigningKey]:
    """Read a ``decentral.key/1`` file: (agent name, signing key).

    A key file that its group or other users may read (any of the mode bits ``0o077``) is refused
    unless ``allow_readable`` (:func:`key_file_exposure` tells the caller so it can warn).

    Raises
    ------
    InputError
        Unreadable file, readable by others, wrong format, bad name or key, or a public key that does
        not belong to the private key.
    """
    source = str(path)
    exposure = key_file_exposure(path)
    if exposure and not allow_readable:
        raise InputError(f"{exposure}: a private key must be readable by its owner only (chmod 600 it)",
                         source=source)
    return parse_private_key(_read_json(path, KEY_FORMAT), source)


def key_file_exposure(path: str | os.PathLike) -> str | None:
    """``"readable by group and others (mode 0644)"`` if users other than the owner may read ``path``, else None."""
    try:
        mode = os.stat(path).st_mode & 0o777
    except OSError:
        return None  # reading it says why
    who = [w for w, bits in (("group", 0o070), ("others", 0o007)) if mode & bits]
    return f"readable by {' and '.join(who)} (mode {mode:04o})" if who else None


def read_private_key_text(text: str | bytes, source: str = "<stdin>") -> tuple[str, SigningKey]:
    """A ``decentral.key/1`` document given as text (e.g. one line on a pipe): (agent name, signing key)."""
    raw = text.encode("utf-8") if isinstance(text, str) else bytes(text)
    return parse_private_key(_parse_json(raw, source, KEY_FORMAT), source)


def parse_private_key(data: Mapping, source: str) -> tuple[str, SigningKey]:
    """The (name, signing key) of a parsed ``decentral.key/1`` object (``source`` names it in errors)."""
    name = _field(data, "name", source, "", check_name)
    key = private_key_from_bytes(_field(data, "private_key", source, "", b64decode_key))
    if "public_key" in data:
        public = _field(data, "public_key", source, "", b64decode_key)
        if public != public_key_bytes(key):
            raise InputError("does not belong to private_key", source=source, field="public_key")
    return name, key
