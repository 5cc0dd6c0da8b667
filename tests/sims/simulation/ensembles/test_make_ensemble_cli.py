"""Tests of ``decentral make-ensemble``."""

import numpy as np

from sims.cli.main import main


def test_writes_observations_and_truth(tmp_path):
    """The command writes a decentral.ensemble/1 file and a matching truth file, exit 0."""
    obs, truth = tmp_path / "o.npz", tmp_path / "t.npz"
    assert main(["make-ensemble", "ring", "-n", "200", "-o", str(obs), "--truth", str(truth), "--seed", "4"]) == 0
    with np.load(obs, allow_pickle=False) as f, np.load(truth, allow_pickle=False) as t:
        assert str(f["format"]) == "decentral.ensemble/1" and int(f["n"]) == int(t["n"])
        assert t["position"].shape == (int(t["n"]), 2)


def test_bad_argument_exits_2_and_writes_nothing(tmp_path, capsys):
    """A bad threshold ends with one line naming the field, exit 2, no file."""
    out = tmp_path / "o.npz"
    assert main(["make-ensemble", "ring", "-o", str(out), "--threshold", "1.5"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--threshold" in err
    assert not out.exists()
