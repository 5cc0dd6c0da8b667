"""Tests of ``decentral ensemble`` (docs/formats.md): outputs, and the exit-2 contract on bad input."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sims.cli.main import main

def _load_lattice_factory():
    """The lattice factory of the ensemble tests' conftest, loaded under a private name."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "decentral" / "ensemble" / "conftest.py"
    spec = importlib.util.spec_from_file_location("_ensemble_lattices", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.make_lattice


make_lattice = _load_lattice_factory()


def _save(path, **arrays):
    np.savez(path, **arrays)
    return str(path)


def _valid(dim=2, shape=(6, 5), noise=0.1):
    p, _, _ = make_lattice(dim, shape, noise=noise)
    return dict(format=np.array("decentral.ensemble/1"), dim=np.int64(dim), n=np.int64(p.n),
                radius=np.float64(p.radius), i=p.i, j=p.j, z=p.z)


@pytest.mark.parametrize("method", ["ncut", "incremental", "mds", "sdp", "bottom-up"])
def test_every_method_writes_contract_arrays_2d(tmp_path, method):
    """Each method writes position (n, 2) and orientation angles (n,), all finite."""
    obs = _save(tmp_path / "obs.npz", **_valid())
    out = tmp_path / "est.npz"
    assert main(["ensemble", obs, "-o", str(out), "--method", method]) == 0
    with np.load(out, allow_pickle=False) as d:
        assert d["position"].shape == (30, 2) and d["orientation"].shape == (30,)
        assert np.all(np.isfinite(d["position"])) and np.all(np.isfinite(d["orientation"]))


def test_3d_estimate_holds_unit_quaternions(tmp_path):
    """In 3D the orientation is n x 4 unit quaternions (w, x, y, z)."""
    obs = _save(tmp_path / "obs.npz", **_valid(3, (3, 3, 3)))
    out = tmp_path / "est.npz"
    assert main(["ensemble", obs, "-o", str(out)]) == 0
    with np.load(out, allow_pickle=False) as d:
        q = d["orientation"]
        assert q.shape == (27, 4)
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)


def test_distributed_writes_message_counts(tmp_path):
    """--distributed adds messages (n), phase_names and phase_messages that sum to the total."""
    pytest.importorskip("sims.runners.ensemble_distributed")
    obs = _save(tmp_path / "obs.npz", **_valid(shape=(5, 4)))
    out = tmp_path / "est.npz"
    assert main(["ensemble", obs, "-o", str(out), "--distributed", "--seed", "3"]) == 0
    with np.load(out, allow_pickle=False) as d:
        assert d["messages"].shape == (20,)
        assert len(d["phase_names"]) == len(d["phase_messages"])
        assert d["phase_messages"].sum() == d["messages"].sum()


def _bad_cases():
    v = _valid()
    E = v["i"].size
    cases = {
        "format": dict(v, format=np.array("decentral.log/1")),
        "dim": dict(v, dim=np.int64(4)),
        "radius": dict(v, radius=np.float64(-0.05)),
        "j": dict(v, j=v["j"][:-1]),
        "z": dict(v, z=np.where(np.arange(E)[:, None] == 3, np.nan, v["z"])),
    }
    out_of_range = v["j"].copy()
    out_of_range[0] = 999
    cases["out-of-range"] = dict(v, j=out_of_range)
    asym = dict(v, i=v["i"][1:], j=v["j"][1:], z=v["z"][1:])
    cases["asymmetric"] = asym
    missing = dict(v)
    del missing["z"]
    cases["missing"] = missing
    zero_radius = dict(v, radius=np.float64(0.0))
    cases["zero-radius"] = zero_radius
    cases["z-shape"] = dict(v, z=v["z"][:, :1])
    return cases


FIELD = {"format": "format", "dim": "dim", "radius": "radius", "j": "j", "z": "z", "out-of-range": "j",
         "asymmetric": "j", "missing": "z", "zero-radius": "radius", "z-shape": "z"}


@pytest.mark.parametrize("case", sorted(FIELD))
def test_bad_input_exits_2_naming_file_and_field(tmp_path, case):
    """Each contract violation ends with exit 2, one stderr line naming file and field, no output file."""
    obs = _save(tmp_path / "obs.npz", **_bad_cases()[case])
    out = tmp_path / "est.npz"
    proc = subprocess.run([sys.executable, "-m", "sims.cli.main", "ensemble", obs, "-o", str(out)],
                          capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert "obs.npz" in lines[0] and f": {FIELD[case]}:" in lines[0]
    assert not out.exists() and not list(tmp_path.glob(".est.npz*"))


def test_unreadable_file_exits_2(tmp_path, capsys):
    """A file that is not an .npz archive ends with exit 2 naming it, and nothing is written."""
    bad = tmp_path / "obs.npz"
    bad.write_text("not a zip")
    out = tmp_path / "est.npz"
    assert main(["ensemble", str(bad), "-o", str(out)]) == 2
    assert "obs.npz" in capsys.readouterr().err
    assert not out.exists()


def test_loss_without_distributed_is_rejected(tmp_path, capsys):
    """--loss only makes sense with --distributed: exit 2 naming the option, nothing written."""
    obs = _save(tmp_path / "obs.npz", **_valid())
    out = tmp_path / "est.npz"
    assert main(["ensemble", obs, "-o", str(out), "--loss", "0.2"]) == 2
    assert "--loss" in capsys.readouterr().err
    assert not out.exists()


def test_sdp_size_guard_is_a_clear_error(tmp_path, capsys, monkeypatch):
    """An ensemble above the SDP size guard ends with exit 2 and a message that says so."""
    from decentral.ensemble.baselines import sdp

    monkeypatch.setattr(sdp, "SDP_MAX_NODES", 10)
    obs = _save(tmp_path / "obs.npz", **_valid())
    out = tmp_path / "est.npz"
    assert main(["ensemble", obs, "-o", str(out), "--method", "sdp"]) == 2
    assert "limited to 10 modules" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("dim, shape, warned", [(3, (7, 1, 1), True), (3, (3, 3, 3), False), (2, (7, 1), False)])
def test_hinges_of_a_3d_ensemble_are_warned_about(tmp_path, capsys, dim, shape, warned):
    """A single file of 3D modules is a chain of hinges and is warned about; a block or a 2D file is not."""
    obs = _save(tmp_path / "obs.npz", **_valid(dim, shape))
    assert main(["ensemble", obs, "-o", str(tmp_path / "est.npz")]) == 0
    err = capsys.readouterr().err
    # a file of 7 has 6 contacts; the two at its ends hold one module each, which turns in place
    assert ("warning: 4 observation pair(s) are the only contact between two parts" in err) == warned
    assert ("unobservable" in err) == warned
