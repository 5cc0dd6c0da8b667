"""`decentral score` on ensembles, `ensemble --tol/--check-every`, and the non-convergence warning."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from decentral.ensemble.metrics import evaluate
from sims.cli.main import main
from sims.io.ensemble_npz import read_ensemble
from sims.runners import ensemble_run


@pytest.fixture(scope="module")
def ens(tmp_path_factory):
    """A 150-module 2D ensemble: observations, truth and its ncut estimate."""
    out = tmp_path_factory.mktemp("ens")
    obs, truth, est = out / "obs.npz", out / "truth.npz", out / "est.npz"
    assert main(["-q", "make-ensemble", "triple", "-n", "150", "-o", str(obs), "--truth", str(truth), "--seed", "2"]) == 0
    assert main(["-q", "ensemble", str(obs), "-o", str(est)]) == 0
    return obs, truth, est


def _score(capsys, est, truth) -> dict:
    assert main(["score", str(est), str(truth), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_score_matches_the_library_metric_on_the_observed_pairs(ens, capsys):
    """score --json gives decentral.ensemble.metrics.evaluate on the observation file's pairs."""
    obs, truth, est = ens
    got = _score(capsys, est, truth)
    prob = read_ensemble(obs)
    with np.load(est) as e, np.load(truth) as t:
        ref = evaluate(e["position"], t["position"], prob.pairs(), prob.radius)
    assert got["global_rms"] == pytest.approx(ref.global_rms, rel=1e-12)
    assert got["local_rms"] == pytest.approx(ref.local_rms, rel=1e-12)
    assert got["modules"] == prob.n and got["units"] == "module radii" and got["pairs_from"] == "observed"


def test_exact_truth_scores_zero_and_is_invariant_to_a_rigid_motion(ens, tmp_path, capsys):
    """The truth itself, rotated and shifted, scores zero global and local RMS."""
    _, truth, _ = ens
    with np.load(truth) as t:
        p = t["position"]
    c, s = np.cos(0.7), np.sin(0.7)
    moved = p @ np.array([[c, -s], [s, c]]).T + np.array([3.0, -1.0])
    est = tmp_path / "moved.npz"
    np.savez(est, position=moved, orientation=np.zeros(len(p)))
    got = _score(capsys, est, truth)
    assert got["global_rms"] < 1e-9 and got["local_rms"] < 1e-9


def test_truth_without_pairs_falls_back_to_true_contacts(ens, tmp_path, capsys):
    """A truth file without `pairs` still scores, with pairs from the true layout."""
    _, truth, est = ens
    with np.load(truth) as t:
        bare = {k: t[k] for k in t.files if k != "pairs"}
    path = tmp_path / "bare.npz"
    np.savez(path, **bare)
    got = _score(capsys, est, path)
    assert got["pairs_from"] == "true contacts" and np.isfinite(got["global_rms"]) and got["pairs"] > 0


def _bad_estimate(tmp_path, **arrays):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("case, field", [
    ("short", "position"), ("nan", "position"), ("missing", "position"), ("wrong_format", "format"),
    ("one_point", "position"),
])
def test_bad_ensemble_estimate_exits_2_naming_file_and_field(ens, tmp_path, capsys, case, field):
    """A malformed estimate ends with exit 2 and one line naming the file and the field."""
    _, truth, est = ens
    with np.load(est) as e:
        p = e["position"].copy()
    arrays = {
        "short": dict(position=p[:-1]),
        "nan": dict(position=np.where(np.arange(len(p))[:, None] == 3, np.nan, p)),
        "missing": dict(orientation=np.zeros(len(p))),
        "wrong_format": dict(format=np.array("decentral.ensemble/1"), position=p),
        "one_point": dict(position=np.zeros_like(p)),
    }[case]
    path = _bad_estimate(tmp_path, **arrays)
    assert main(["score", str(path), str(truth)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and field in lines[0] and captured.out == ""


def test_bad_ensemble_truth_exits_2_naming_file_and_field(ens, tmp_path, capsys):
    """Observations given as truth, or a non-npz truth, end with exit 2 naming the truth file."""
    obs, _, est = ens
    assert main(["score", str(est), str(obs)]) == 2
    err = capsys.readouterr().err
    assert str(obs) in err and "format" in err
    text = tmp_path / "truth.json"
    text.write_text("{}")
    assert main(["score", str(est), str(text)]) == 2
    assert "not an .npz archive" in capsys.readouterr().err


@pytest.mark.parametrize("argv, field", [
    (["--tol", "0"], "--tol"), (["--tol", "-1"], "--tol"), (["--tol", "nan"], "--tol"), (["--tol", "inf"], "--tol"),
    (["--check-every", "5"], "--check-every"), (["--distributed", "--check-every", "0"], "--check-every"),
])
def test_bad_tolerance_options_exit_2(ens, tmp_path, capsys, argv, field):
    """Non-positive or non-finite --tol, and --check-every without --distributed or below 1, exit 2."""
    obs, _, _ = ens
    out = tmp_path / "e.npz"
    assert main(["ensemble", str(obs), "-o", str(out), *argv]) == 2
    assert field in capsys.readouterr().err and not out.exists()


def test_looser_tolerance_refines_less(ens, tmp_path):
    """--tol loosens every refinement of ncut: fewer iterations per module than a tight tolerance."""
    obs, _, _ = ens
    its = {}
    for tol in ("1e-1", "1e-6"):
        out = tmp_path / f"e{tol}.npz"
        assert main(["-q", "ensemble", str(obs), "-o", str(out), "--tol", tol]) == 0
        with np.load(out) as d:
            its[tol] = float(d["iterations_per_module"].mean())
    assert its["1e-1"] < its["1e-6"]


def test_distributed_tolerance_sets_level_and_top_and_check_every():
    """--tol reaches every level's and the top's tolerance of the distributed run; --check-every its checks."""
    cfg = ensemble_run.distributed_config(0.0, 0.01, 5)
    assert cfg.top_gtol == 0.01 and cfg.hierarchy.level_refine.gtol == 0.01 and cfg.check_every == 5
    assert ensemble_run.distributed_config() == type(cfg)()


def test_distributed_run_at_its_cap_warns(ens, tmp_path, capsys, monkeypatch):
    """A distributed refinement stopped by the iteration cap is reported as a non-convergence warning."""
    obs, _, _ = ens
    capped = replace(ensemble_run.distributed_config(), top_max_iter=2, level_max_iter=2)
    monkeypatch.setattr(ensemble_run, "distributed_config", lambda *a, **k: capped)
    assert main(["ensemble", str(obs), "-o", str(tmp_path / "d.npz"), "--distributed"]) == 0
    err = capsys.readouterr().err
    assert "decentral ensemble: warning: distributed refinement did not converge" in err
    summary = [ln for ln in err.splitlines() if ln.startswith("decentral ensemble: 1")]
    assert summary and "messages per module" in summary[0] and "rounds" in summary[0]


def test_converged_distributed_run_does_not_warn(ens, tmp_path, capsys):
    """A lossless distributed run at a loose tolerance converges: summary, no warning."""
    obs, _, _ = ens
    assert main(["ensemble", str(obs), "-o", str(tmp_path / "d.npz"), "--distributed", "--tol", "0.01",
                 "--check-every", "5"]) == 0
    err = capsys.readouterr().err
    assert "warning" not in err and "messages per module" in err


def _explained(header: str) -> list[str]:
    """The column names of a printed table header, units in brackets dropped, compared word by word."""
    return re.sub(r"\s*\[[^\]]*\]", "", header).split()


def test_every_column_of_the_ensemble_score_is_explained_in_help_and_docs(ens, capsys):
    """Each column the ensemble table prints has a line in `score --help` (COLUMNS) and in docs/cli.md."""
    from sims.cli.score import COLUMNS

    obs, truth, est = ens
    assert main(["score", str(est), str(truth)]) == 0
    header = capsys.readouterr().out.splitlines()[0]
    section = COLUMNS.split("columns of an ensemble score", 1)[1]
    explained = [m.group(1) for m in re.finditer(r"^  ([a-zA-Z][a-zA-Z ]*?)  +\S", section, re.MULTILINE)]
    assert _explained(header) == " ".join(explained).split()
    docs = (Path(__file__).resolve().parents[2] / "docs" / "cli.md").read_text(encoding="utf-8")
    for name in explained:
        assert f"| `{name}` |" in docs, name
