"""`decentral console` as a command: its options, the loopback default, bad input as one line."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from sims.cli import feedback
from sims.cli.console import _check_host

ROOT = Path(__file__).resolve().parents[3]


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sims.cli.main", "console", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def test_help_names_the_three_sources_and_the_loopback_default():
    """--help lists --swarm, --streams and --replay, and says the page listens on 127.0.0.1 by default."""
    out = _cli("--help")
    assert out.returncode == 0
    for word in ("--swarm", "--streams", "--replay", "--mcap", "127.0.0.1"):
        assert word in out.stdout


@pytest.mark.parametrize("host", ["127.0.0.1", "::1", "localhost"])
def test_loopback_listens_without_a_warning(host, capsys):
    """The default and other loopback addresses print nothing."""
    feedback.configure(quiet=False, command="console")
    _check_host(host)
    assert capsys.readouterr().err == ""


def test_another_address_prints_a_warning(capsys):
    """Listening on a non-loopback address warns that anyone who reaches it can drive the robots."""
    feedback.configure(quiet=True, command="console")
    _check_host("0.0.0.0")
    assert "warning" in capsys.readouterr().err


def test_missing_stream_for_an_export_is_one_line_and_exit_2(tmp_path):
    """Exporting streams that do not exist ends with one line naming the path, exit status 2, nothing written."""
    out = _cli("--streams", str(tmp_path / "nope"), "--mcap", str(tmp_path / "x.mcap"))
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1 and "nope" in out.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_bad_swarm_option_is_one_line_and_exit_2(tmp_path):
    """A swarm option out of range (negative loss) is refused in one line with exit status 2."""
    out = _cli("--swarm", "--loss", "-0.5", "--mcap", str(tmp_path / "x.mcap"))
    assert out.returncode == 2 and "--loss" in out.stderr and "Traceback" not in out.stderr


def test_without_the_console_extra_the_page_says_what_to_install():
    """Serving without NiceGUI installed ends in one line naming the extra to install, exit status 2."""
    code = ("import sys; sys.modules['nicegui'] = None\n"
            "from sims.cli.main import main\n"
            "sys.exit(main(['console', '--swarm', '--robots', '3']))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and "decentral[console]" in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_display_rate_that_is_not_positive_is_one_line_and_exit_2(tmp_path):
    """--display-hz 0 is refused in one line naming the option, exit status 2, before anything runs."""
    out = _cli("--swarm", "--display-hz", "0", "--mcap", str(tmp_path / "x.mcap"))
    assert out.returncode == 2 and "--display-hz" in out.stderr and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and not (tmp_path / "x.mcap").exists()
