"""Peers and key files are read strictly: a key given twice or absurd nesting is a one-line InputError."""

from __future__ import annotations

import pytest

from decentral.errors import InputError
from protocols.peers import load_peers


@pytest.mark.parametrize("text, words", [
    ('{"format": "decentral.peers/1", "agents": {}, "agents": {}}', "twice"),
    ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
])
def test_hostile_peers_files_are_refused_naming_the_file(text, words, tmp_path):
    """Duplicate keys are refused (never silently the last one) and deep nesting never recurses out."""
    path = tmp_path / "peers.json"
    path.write_text(text)
    with pytest.raises(InputError, match=words) as err:
        load_peers(path)
    assert "peers.json" in str(err.value) and "\n" not in str(err.value)
