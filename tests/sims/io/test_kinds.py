"""A file's kind is told from its first bytes, and a reader refuses a file of another kind, naming both."""

import json
import zipfile

import numpy as np
import pytest

from decentral.errors import InputError
from sims.io.kinds import KINDS, require_kind, sniff


def test_every_project_format_is_a_known_kind():
    """Each format constant of the readers (and the key files') is a key of KINDS."""
    from protocols.peers import KEY_FORMAT, PEERS_FORMAT, PUBKEY_FORMAT
    from sims.io import detections_json, ensemble_npz, log_json, rig, robot_files
    from sims.simulation.world.truth import TRUTH_FORMAT

    formats = {log_json.LOG_FORMAT, log_json.ESTIMATE_FORMAT, TRUTH_FORMAT, detections_json.DETECTIONS_FORMAT,
               rig.RIG_FORMAT, robot_files.LAYOUT_FORMAT, ensemble_npz.OBSERVATION_FORMAT,
               ensemble_npz.ESTIMATE_FORMAT, ensemble_npz.TRUTH_FORMAT, PEERS_FORMAT, KEY_FORMAT, PUBKEY_FORMAT}
    assert formats <= set(KINDS)


@pytest.mark.parametrize("name,content,kind", [
    ("a.png", b"\x89PNG\r\n\x1a\n" + bytes(16), "image"),
    ("a.jpg", b"\xff\xd8\xff\xe0" + bytes(16), "image"),
    ("a.avi", b"RIFF\0\0\0\0AVI LIST", "video"),
    ("a.mp4", b"\0\0\0\x18ftypmp42", "video"),
    ("a.sqlite", b"SQLite format 3\x00" + bytes(16), "sqlite"),
    ("log.json", b' \n{"assemblies": {"A0": {"cameras": {"c": {"format": "x"}}}}, "format": "decentral.log/1"}',
     "decentral.log/1"),
    ("rig.toml", b'format = "decentral.rig/1"\n[assemblies.A0]\nodometry = {format = "tum"}\n', "decentral.rig/1"),
    ("spec.toml", b'name = "s"\n[fixed]\nn = 3\n[grid]\nseed = [1]\n', "study-spec"),
    ("other.json", b'{"format": "decentral.log/9"}', None),
    ("junk.bin", bytes(range(256)), None),
    ("empty", b"", None),
])
def test_sniff_tells_the_kind_from_the_first_bytes(tmp_path, name, content, kind):
    """Magic bytes, a JSON format field (the first known one), a TOML format key or [grid]; else None."""
    path = tmp_path / name
    path.write_bytes(content)
    assert sniff(path) == kind


def test_sniff_reads_the_format_member_of_an_npz_and_nothing_larger(tmp_path):
    """An .npz is told by its format.npy; an oversized or missing member gives None, never an error."""
    np.savez(tmp_path / "t.npz", format=np.array("decentral.ensemble_truth/1"), position=np.zeros((2, 2)))
    assert sniff(tmp_path / "t.npz") == "decentral.ensemble_truth/1"
    np.savez(tmp_path / "b.npz", format=np.array("x" * 5000))
    np.savez(tmp_path / "n.npz", position=np.zeros((2, 2)))
    with zipfile.ZipFile(tmp_path / "z.npz", "w") as z:
        z.writestr("format.npy", b"\x93NUMPY\x01\x00\xff\xff{'descr': 1")
    assert sniff(tmp_path / "b.npz") is None and sniff(tmp_path / "n.npz") is None
    assert sniff(tmp_path / "z.npz") is None and sniff(tmp_path / "missing.npz") is None and sniff(tmp_path) is None


def test_require_kind_names_what_was_given_what_was_expected_and_who_reads_it(tmp_path):
    """The error names the file, the format field, both kinds, and the reading command; the right kind passes."""
    path = tmp_path / "est.json"
    path.write_text(json.dumps({"format": "decentral.estimate/1", "steps": []}))
    require_kind(path, "decentral.estimate/1", "decentral.truth/1")
    with pytest.raises(InputError) as err:
        require_kind(path, "decentral.log/1")
    assert str(err.value).startswith(f"{path}: format: this is an estimate (decentral.estimate/1), not an "
                                      "observation log (decentral.log/1); `decentral score EST TRUTH`")


def test_require_folder_refuses_a_file_saying_what_it_is(tmp_path):
    """A file where a study folder belongs is named with its kind and reader; a folder or a missing path passes."""
    from sims.io.kinds import require_folder

    db = tmp_path / "study.sqlite"
    db.write_bytes(b"SQLite format 3\x00" + bytes(84))
    with pytest.raises(InputError, match=r"study.sqlite: this is an SQLite database, not a folder holding "
                                         r"study.sqlite; `decentral report DIR` reads a study's DIR/study.sqlite"):
        require_folder(db, "study.sqlite")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="notes.txt: this is a file, not a folder holding study.sqlite$"):
        require_folder(tmp_path / "notes.txt", "study.sqlite")
    require_folder(tmp_path, "study.sqlite")
    require_folder(tmp_path / "missing", "study.sqlite")
