"""``decentral keys``: key files a transport can load, secrets unreadable by others, refusals without partial output."""

from __future__ import annotations

import json
import stat

import pytest

from protocols.auth import public_key_bytes
from protocols.peers import load_peers, load_private_key
from sims.cli.main import main


def test_keys_writes_loadable_keys_and_a_peers_skeleton(tmp_path, capsys):
    """Every NAME gets a 0600 private key whose public half is the one in peers.json, at consecutive ports."""
    out = tmp_path / "keys"
    assert main(["keys", "A0", "A1", "A2", "-o", str(out), "--host", "10.0.0.5", "--base-port", "6000"]) == 0
    peers = load_peers(out / "peers.json")
    assert list(peers) == ["A0", "A1", "A2"]
    assert [p.address for p in peers.values()] == ["tcp://10.0.0.5:6000", "tcp://10.0.0.5:6001", "tcp://10.0.0.5:6002"]
    for name, peer in peers.items():
        path = out / f"{name}.key.json"
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        loaded, key = load_private_key(path)
        assert loaded == name and public_key_bytes(key) == peer.public_key
        public = json.loads((out / f"{name}.pub.json").read_text())["public_key"]
        assert public == json.loads(path.read_text())["public_key"]
    assert len({p.public_key for p in peers.values()}) == 3


def test_keys_refuses_to_overwrite_and_force_replaces(tmp_path, capsys):
    """An existing key set is kept (exit 2, one line naming the file) unless --force, which makes new keys."""
    assert main(["keys", "A0", "-o", str(tmp_path)]) == 0
    assert "1 key pairs" in capsys.readouterr().err  # the summary line, on stderr
    before = (tmp_path / "A0.key.json").read_text()
    assert main(["keys", "A0", "B", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists already" in err and "peers.json" in err
    assert not (tmp_path / "B.key.json").exists() and (tmp_path / "A0.key.json").read_text() == before
    assert main(["keys", "A0", "-o", str(tmp_path), "--force"]) == 0
    assert (tmp_path / "A0.key.json").read_text() != before


@pytest.mark.parametrize("argv", [["A0", "A0"], [""], ["*"], ["x" * 256], ["A0", "A1", "--base-port", "65535"],
                                  ["A0", "--host", "bad host"]])
def test_keys_bad_arguments_exit_2_and_write_nothing(tmp_path, capsys, argv):
    """Repeated or unusable names, ports past 65535 and bad hosts end in one line, exit 2, and no files."""
    out = tmp_path / "k"
    assert main(["keys", *argv, "-o", str(out)]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    assert not out.exists() or not any(out.iterdir())


def test_any_agent_name_gets_its_own_plain_key_file(tmp_path):
    """Names with spaces, slashes or a leading dot get percent-encoded file names in DIR holding the real name."""
    names = ["robot 1", "a/b", ".hidden", "Ä"]
    assert main(["keys", *names, "-o", str(tmp_path)]) == 0
    files = sorted(p.name for p in tmp_path.glob("*.key.json"))
    assert files == sorted(["robot%201.key.json", "a%2Fb.key.json", "%2Ehidden.key.json", "%C3%84.key.json"])
    assert sorted(load_private_key(tmp_path / f)[0] for f in files) == sorted(names)
    assert list(load_peers(tmp_path / "peers.json")) == names
