"""The CLI's feedback mechanism: bars on stderr only when wanted, summary and warnings on stderr."""

from __future__ import annotations

import pytest

from sims.cli import feedback


@pytest.fixture(autouse=True)
def _fresh_state():
    with feedback.configured(quiet=False, command="test"):
        yield


def test_bar_forced_on_writes_counts_and_postfix_to_stderr_only(monkeypatch, capsys):
    """DECENTRAL_PROGRESS=always shows the bar, with count and postfix, on stderr and nothing on stdout."""
    monkeypatch.setenv(feedback.PROGRESS_ENV, "always")
    with feedback.progress("steps", total=4, leave=True) as bar:
        for k in range(4):
            bar(k + 1, rounds=7)
        bar.fail()
    out, err = capsys.readouterr()
    assert out == ""
    assert "steps" in err and "4/4" in err and "rounds=7" in err and "failed=1" in err


def test_bar_hidden_when_stderr_is_not_a_terminal(monkeypatch, capsys):
    """By default (auto) a bar on a non-terminal stderr prints nothing."""
    monkeypatch.delenv(feedback.PROGRESS_ENV, raising=False)
    with feedback.progress("steps", total=3) as bar:
        bar.advance(3, rounds=2)
    assert capsys.readouterr() == ("", "")


def test_quiet_silences_bars_and_summary_but_not_warnings(monkeypatch, capsys):
    """Quiet mode hides even a forced bar and the summary; a warning still reaches stderr."""
    monkeypatch.setenv(feedback.PROGRESS_ENV, "always")
    with feedback.configured(quiet=True):
        for _ in feedback.track(range(5), "frames"):
            pass
        feedback.summary("5 frames")
        feedback.warn("did not converge")
    out, err = capsys.readouterr()
    assert out == "" and err == "decentral test: warning: did not converge\n"


def test_summary_is_one_prefixed_line_on_stderr(capsys):
    """summary() prints exactly one line, prefixed with the command, on stderr."""
    feedback.summary("12 windows, 12 certified")
    assert capsys.readouterr() == ("", "decentral test: 12 windows, 12 certified\n")


def test_callback_sets_absolute_count_and_total(monkeypatch):
    """A Progress used as a library callback takes absolute counts and may set the total late."""
    monkeypatch.setenv(feedback.PROGRESS_ENV, "always")
    with feedback.progress("levels") as bar:
        bar(2, 10)
        bar(5)
        assert (bar._bar.n, bar._bar.total) == (5, 10)


def test_postfix_fields_are_replaced_per_call_and_failures_kept(monkeypatch):
    """Each call's fields replace the last call's (no stale counters); failed=N stays."""
    monkeypatch.setenv(feedback.PROGRESS_ENV, "always")
    with feedback.progress("stages", total=3) as bar:
        bar(1, stage="cut", messages=10)
        bar.fail()
        bar(1, stage="refine", iteration=5)
        assert bar._bar.postfix == "stage=refine, iteration=5, failed=1"
        bar.advance()
        assert bar._bar.postfix == "stage=refine, iteration=5, failed=1"
