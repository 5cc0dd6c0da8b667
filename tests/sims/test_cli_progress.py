"""Feedback of the commands: --version, -q, progress only on stderr, one summary line, warnings, exit 3."""

from __future__ import annotations

import json
import re
from importlib.metadata import version

import numpy as np
import pytest

from sims.cli import feedback
from sims.cli.main import EXIT_NO_RESULT, build_parser, main

BAR_MARKS = ("%|", "it/s", "step/s", "\r")


@pytest.fixture(scope="module")
def sim6(tmp_path_factory):
    """A 6-step table1 run (log.json, truth.json) and its centralized estimate."""
    out = tmp_path_factory.mktemp("sim6")
    assert main(["-q", "simulate", "table1", "-o", str(out), "--steps", "6"]) == 0
    assert main(["-q", "localize", str(out / "log.json"), "-o", str(out / "est.json")]) == 0
    return out


@pytest.fixture(scope="module")
def ensemble(tmp_path_factory):
    """A 120-module 2D ensemble (observations, truth) and its ncut estimate."""
    out = tmp_path_factory.mktemp("ens")
    obs, truth, est = out / "obs.npz", out / "truth.npz", out / "est.npz"
    assert main(["-q", "make-ensemble", "triple", "-n", "120", "-o", str(obs), "--truth", str(truth)]) == 0
    assert main(["-q", "ensemble", str(obs), "-o", str(est)]) == 0
    return obs, truth, est


@pytest.fixture
def bars_on(monkeypatch):
    """Progress bars forced on although stderr is captured (not a terminal)."""
    monkeypatch.setenv(feedback.PROGRESS_ENV, "always")


def _summary_lines(err: str, command: str) -> list[str]:
    prefix = f"decentral {command}: "
    return [ln for ln in err.replace("\r", "\n").splitlines()
            if ln.startswith(prefix) and not ln.startswith(prefix + "warning")]


def test_version_prints_the_installed_version(capsys):
    """`decentral --version` prints the package version from its metadata and exits 0."""
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.strip() == f"decentral {version('decentral')}"


@pytest.mark.parametrize("argv", [["-q", "score", "a", "b"], ["score", "a", "b", "-q"], ["score", "--quiet", "a", "b"]])
def test_quiet_is_accepted_before_and_after_the_subcommand(argv):
    """-q/--quiet works before the subcommand and after it."""
    assert build_parser().parse_args(argv).quiet is True


def test_admm_progress_goes_to_stderr_never_into_the_output(sim6, tmp_path, capsys, bars_on):
    """With bars forced on, stderr shows the bar (rounds, messages) and the output file is plain JSON."""
    out = tmp_path / "admm.json"
    assert main(["localize", str(sim6 / "log.json"), "-o", str(out), "--mode", "admm"]) == 0
    captured = capsys.readouterr()
    assert "rounds=" in captured.err and "messages=" in captured.err and "%|" in captured.err
    assert captured.out == ""
    text = out.read_text()
    assert not any(mark in text for mark in BAR_MARKS)
    assert json.loads(text)["format"] == "decentral.estimate/1"
    [line] = _summary_lines(captured.err, "localize")
    assert "rounds" in line and "messages" in line and "MB" in line and "converged 6/6" in line


def test_quiet_prints_nothing_even_with_bars_forced(sim6, tmp_path, capsys, bars_on):
    """`decentral -q` (before or after the command) leaves stdout and stderr empty on success."""
    for argv in (["-q", "localize", str(sim6 / "log.json"), "-o", str(tmp_path / "a.json"), "--mode", "admm"],
                 ["localize", str(sim6 / "log.json"), "-o", str(tmp_path / "b.json"), "-q"]):
        assert main(argv) == 0
        assert capsys.readouterr() == ("", "")


def test_centralized_summary_reports_certificates_and_coverage(sim6, tmp_path, capsys):
    """The closing line of a centralized run names the certified windows and the coverage."""
    assert main(["localize", str(sim6 / "log.json"), "-o", str(tmp_path / "e.json")]) == 0
    [line] = _summary_lines(capsys.readouterr().err, "localize")
    assert "windows certified" in line and "coverage" in line and str(tmp_path / "e.json") in line


def test_admm_that_places_nothing_warns_and_exits_3(sim6, tmp_path, capsys):
    """--loss 0.999: a non-convergence warning, a one-line reason naming --loss, exit 3, estimate still written."""
    out = tmp_path / "lost.json"
    status = main(["localize", str(sim6 / "log.json"), "-o", str(out), "--mode", "admm", "--loss", "0.999",
                   "--max-rounds", "10"])
    assert status == EXIT_NO_RESULT == 3
    err = capsys.readouterr().err
    warnings = [ln for ln in err.splitlines() if ln.startswith("decentral localize: warning: ")]
    assert any("did not converge" in w for w in warnings)
    assert any("placed no assembly" in w and "--loss 0.999" in w for w in warnings)
    assert json.loads(out.read_text())["stats"]["all_converged"] is False


def test_admm_warning_survives_quiet(sim6, tmp_path, capsys):
    """Quiet mode hides the summary but not the warning that nothing was placed."""
    status = main(["-q", "localize", str(sim6 / "log.json"), "-o", str(tmp_path / "l.json"), "--mode", "admm",
                   "--loss", "0.999", "--max-rounds", "5"])
    err = capsys.readouterr().err
    assert status == 3 and "placed no assembly" in err and not _summary_lines(err, "localize")


def test_score_json_stays_valid_with_summary_and_bars(sim6, capsys, bars_on):
    """score --json writes only JSON to stdout; the headline goes to stderr."""
    assert main(["score", str(sim6 / "est.json"), str(sim6 / "truth.json"), "--json"]) == 0
    captured = capsys.readouterr()
    assert "overall" in json.loads(captured.out)
    [line] = _summary_lines(captured.err, "score")
    assert "position" in line and "coverage" in line


def test_every_command_ends_with_one_summary_line(sim6, ensemble, tmp_path, capsys):
    """simulate, make-ensemble, localize, ensemble, score, perceive, demo and experiment each print one summary."""
    obs, truth, est = ensemble
    frames = tmp_path / "frames"
    runs = {
        "simulate": ["simulate", "table1", "-o", str(frames), "--steps", "2", "--frames", "png"],
        "make-ensemble": ["make-ensemble", "ring", "-n", "60", "-o", str(tmp_path / "r.npz")],
        "localize": ["localize", str(sim6 / "log.json"), "-o", str(tmp_path / "e.json"), "--estimator", "bearing"],
        "ensemble": ["ensemble", str(obs), "-o", str(tmp_path / "m.npz"), "--method", "mds"],
        "score": ["score", str(est), str(truth)],
        "demo": ["demo", "-o", str(tmp_path / "demo"), "--steps", "4"],
        "experiment": ["experiment", "reconfig", "-o", str(tmp_path / "exp"), "--steps", "6"],
    }
    for command, argv in runs.items():
        assert main(argv) == 0, command
        assert len(_summary_lines(capsys.readouterr().err, command)) == 1, command
    pngs = sorted(str(p) for p in frames.rglob("*.png"))
    assert main(["perceive", *pngs, "-o", str(tmp_path / "d.json")]) == 0
    [line] = _summary_lines(capsys.readouterr().err, "perceive")
    assert line.startswith(f"decentral perceive: {len(pngs)} frames")


def test_the_ensemble_summary_says_wall_and_cpu_time(ensemble, tmp_path, capsys):
    """ensemble's summary gives the localization's wall and CPU seconds; the estimate keeps both."""
    obs, _, _ = ensemble
    assert main(["ensemble", str(obs), "-o", str(tmp_path / "m.npz")]) == 0
    [line] = _summary_lines(capsys.readouterr().err, "ensemble")
    assert re.search(r", localization wall \d+\.\d s, CPU \d+\.\d s -> ", line), line
    with np.load(tmp_path / "m.npz", allow_pickle=False) as d:
        assert d["seconds"] > 0 and d["cpu_seconds"] > 0


def test_perceive_and_simulate_frames_keep_bars_out_of_their_files(tmp_path, capsys, bars_on):
    """Rendering and perceiving with bars forced on: the detections file is plain JSON."""
    assert main(["simulate", "table1", "-o", str(tmp_path / "s"), "--steps", "2", "--frames", "png"]) == 0
    assert "frame" in capsys.readouterr().err
    pngs = sorted(str(p) for p in (tmp_path / "s").rglob("*.png"))
    assert main(["perceive", *pngs, "-o", str(tmp_path / "d.json")]) == 0
    assert f"{len(pngs)}/{len(pngs)}" in capsys.readouterr().err
    text = (tmp_path / "d.json").read_text()
    assert not any(mark in text for mark in BAR_MARKS) and len(json.loads(text)["frames"]) == len(pngs)


def test_ensemble_bar_and_npz_output(ensemble, tmp_path, capsys, bars_on):
    """The hierarchy's bar counts modules on stderr; the estimate is a clean npz."""
    obs, _, _ = ensemble
    out = tmp_path / "e.npz"
    assert main(["ensemble", str(obs), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "module" in err and "%|" in err
    with np.load(out, allow_pickle=False) as d:
        assert d["position"].shape[0] == d["iterations_per_module"].shape[0]


def test_library_callbacks_reach_their_totals(sim6):
    """estimate_log and run_admm call progress once per step up to the step count (with ADMM counters)."""
    from decentral.estimator import estimate_log
    from sims.runners.admm_run import run_admm
    from sims.io.log_json import read_log

    log = read_log(sim6 / "log.json")
    calls = []
    estimate_log(log, progress=lambda done, total, **info: calls.append((done, total)))
    assert calls == [(k + 1, len(log.steps)) for k in range(len(log.steps))]
    admm = []
    run_admm(log, progress=lambda done, total, **info: admm.append((done, total, info)))
    assert [c[0] for c in admm] == list(range(1, len(log.steps) + 1))
    rounds = [c[2]["rounds"] for c in admm]
    assert rounds == sorted(rounds) and admm[-1][2]["messages"] > 0


def test_distributed_stages_reach_their_total(ensemble):
    """run_distributed reports each stage; the last call has done == total and the message count grows."""
    from sims.runners.ensemble_distributed import run_distributed
    from sims.io.ensemble_npz import read_ensemble

    obs, _, _ = ensemble
    calls = []
    res = run_distributed(read_ensemble(obs), np.random.default_rng(0),
                          progress=lambda done, total, **info: calls.append((done, total, info)))
    stages = [c for c in calls if "messages" in c[2]]  # a stage's end (not a refinement's check)
    assert calls[-1][0] == calls[-1][1] == len(stages) and all(c[1] is not None for c in calls if "iteration" in c[2])
    messages = [c[2]["messages"] for c in stages]
    assert messages == sorted(messages) and messages[-1] == int(res.messages.sum())
    assert res.info["capped_levels"] == []


def _stderr_on_a_terminal(argv: list[str]) -> tuple[int, bytes]:
    """Run the console script with stderr on a 120-column pseudo-terminal; return (status, what it showed)."""
    import fcntl
    import os
    import pty
    import struct
    import subprocess
    import sys
    import termios

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    env = {k: v for k, v in os.environ.items() if k != feedback.PROGRESS_ENV}
    proc = subprocess.Popen([sys.executable, "-m", "sims.cli.main", *argv], stdout=subprocess.DEVNULL,
                            stderr=slave, env=env)
    os.close(slave)
    shown = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        shown += chunk
    os.close(master)
    return proc.wait(), shown


@pytest.mark.skipif(not hasattr(__import__("os"), "openpty"), reason="needs a pseudo-terminal")
def test_on_a_terminal_the_bar_shows_by_default_and_quiet_hides_it(sim6, tmp_path):
    """Without any setting a terminal stderr gets the bar (then the summary); -q shows nothing; files stay clean."""
    out = tmp_path / "t.json"
    status, shown = _stderr_on_a_terminal(["localize", str(sim6 / "log.json"), "-o", str(out), "--mode", "admm"])
    assert status == 0 and b"%|" in shown and b"rounds=" in shown and b"decentral localize: 6 steps" in shown
    assert json.loads(out.read_text())["format"] == "decentral.estimate/1"
    status, shown = _stderr_on_a_terminal(["-q", "localize", str(sim6 / "log.json"), "-o", str(out), "--mode", "admm"])
    assert status == 0 and shown == b""
