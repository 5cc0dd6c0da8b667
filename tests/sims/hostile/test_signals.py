"""Temporary files are removed on every exit path the process can act on (errors, SIGINT, SIGTERM)."""

from __future__ import annotations

import argparse
import os
import signal

from sims.cli.main import _run_mapped
from sims.io.atomic import remove_stale_parts, write_atomic


def _args(run) -> argparse.Namespace:
    return argparse.Namespace(command="test", _run=run)


def test_sigterm_while_writing_removes_the_temporary_file(tmp_path, capsys):
    """SIGTERM in the middle of a write: exit 143, one line, neither the output nor a .part file remains."""
    def run(args):
        def writer(fh):
            fh.write("partial")
            os.kill(os.getpid(), signal.SIGTERM)
            fh.write("never")

        write_atomic(tmp_path / "out.json", writer)
        return 0

    assert _run_mapped(_args(run)) == 143
    assert capsys.readouterr().err.strip() == "decentral test: terminated"
    assert list(tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGTERM) is not None  # the previous handler is back


def test_any_exception_is_one_line_and_exit_2(tmp_path, capsys):
    """An unexpected exception (a bug) is still one stderr line and exit status 2, with no traceback."""
    def run(args):
        raise ValueError("first line\nsecond line")

    assert _run_mapped(_args(run)) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "ValueError: first line second line" in err


def test_stale_parts_of_live_processes_are_kept(tmp_path):
    """Only temporary files whose process is gone are removed; a live writer's file is left alone."""
    live = tmp_path / f".out.json.{os.getppid()}.abc.part"
    other = tmp_path / ".other.json.1.abc.part"
    live.write_text("")
    other.write_text("")
    assert remove_stale_parts(tmp_path / "out.json") == []
    assert live.exists() and other.exists()
