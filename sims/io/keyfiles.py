"""Writing a key set: one private and one public key file per agent, and the peers file that lists them all.

Formats (``decentral.key/1``, ``decentral.pubkey/1``, ``decentral.peers/1``) are defined and read in
:mod:`protocols.peers`. Keys come from the operating system's random source, never from a seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

from decentral.errors import InputError
from protocols.auth import new_private_key, public_key_bytes
from protocols.peers import Peer, check_address, check_name, peers_json, private_key_json, public_key_json
from sims.io.atomic import write_json_atomic
from sims.io.paths import name_stem

__all__ = ["KeySet", "write_keys", "key_paths"]



@dataclass(frozen=True)
class KeySet:
    """Where :func:`write_keys` put everything.

    Attributes
    ----------
    peers : Path
        The peers file.
    private, public : Mapping[str, Path]
        Agent name -> its private (mode 0600) / public key file.
    """

    peers: Path
    private: Mapping[str, Path]
    public: Mapping[str, Path]


def key_paths(folder: str | Path, name: str) -> tuple[Path, Path]:
    """The private and public key file of agent ``name`` in ``folder``: ``NAME.key.json``, ``NAME.pub.json``.

    ``NAME`` is :func:`sims.io.paths.name_stem` of the name (percent-encoded: ``robot 1`` ->
    ``robot%201``, ``a/b`` -> ``a%2Fb``), so every agent name gives one plain file name in ``folder``;
    the files hold the name itself.
    """
    stem = name_stem(name, field=f"name {name[:40]!r}")
    folder = Path(folder)
    return folder / f"{stem}.key.json", folder / f"{stem}.pub.json"


def write_keys(
    folder: str | Path,
    names: Sequence[str],
    *,
    addresses: Mapping[str, str] | None = None,
    host: str = "127.0.0.1",
    base_port: int = 47000,
    force: bool = False,
) -> KeySet:
    """Make a fresh Ed25519 key per agent and write the key files and ``peers.json`` into ``folder``.

    Parameters
    ----------
    folder : path
        Created if missing.
    names : sequence of str
        Agent names (unique; 1-255 UTF-8 bytes, not ``*``; file names per :func:`key_paths`).
    addresses : Mapping[str, str], optional
        Each agent's address in the peers file; defaults to ``tcp://HOST:BASE_PORT+i`` for the
        ``i``-th name (a skeleton to edit when agents run on several machines).
    force : bool
        Replace existing files (otherwise an existing file is an error and nothing is written).

    Raises
    ------
    InputError
        A bad or repeated name, a bad address or port, an existing file without ``force``, or a
        folder that cannot be written.
    """
    names = list(names)
    if not names:
        raise InputError("give at least one agent name", field="NAME")
    for name in names:
        try:
            check_name(name)
        except ValueError as err:
            raise InputError(str(err), field="NAME") from None
    if len(set(names)) != len(names):
        raise InputError("names must be unique", field="NAME")
    if addresses is None:
        if not (isinstance(base_port, int) and 1 <= base_port and base_port + len(names) - 1 <= 65535):
            raise InputError(f"ports {base_port}..{base_port + len(names) - 1} are not all in 1..65535",
                             field="--base-port")
        addresses = {name: f"tcp://{host}:{base_port + i}" for i, name in enumerate(names)}
    for name in names:
        try:
            check_address(addresses.get(name))
        except ValueError as err:
            raise InputError(str(err), field=f"address of {name}") from None
    folder = Path(folder)
    peers_path = folder / "peers.json"
    targets = [peers_path] + [p for name in names for p in key_paths(folder, name)]
    if not force:
        for path in targets:
            if path.exists():
                raise InputError("exists already (use --force to replace the key set)", source=str(path))
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create folder ({err.strerror})", source=str(folder)) from None
    keys = {name: new_private_key() for name in names}
    private, public = {}, {}
    for name, key in keys.items():
        private[name], public[name] = key_paths(folder, name)
        write_json_atomic(private[name], private_key_json(name, key), mode=0o600)
        write_json_atomic(public[name], public_key_json(name, key))
    peers = {name: Peer(name, addresses[name], public_key_bytes(key)) for name, key in keys.items()}
    write_json_atomic(peers_path, peers_json(peers))
    return KeySet(peers_path, private, public)
