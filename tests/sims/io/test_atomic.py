"""Atomic writes: whole or nothing, and ordinary file permissions."""

import os
import stat

import pytest

from sims.io.atomic import write_atomic, write_json_atomic


def test_written_file_gets_the_umask_mode(tmp_path):
    """The output is readable like any file open() would create (not mkstemp's private 0600)."""
    path = tmp_path / "out.json"
    write_json_atomic(path, {"a": 1})
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask


def test_failed_write_leaves_no_file(tmp_path):
    """A writer that raises leaves neither the target nor a temporary file behind."""
    path = tmp_path / "out.json"

    def boom(fh):
        fh.write("partial")
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError):
        write_atomic(path, boom)
    assert list(tmp_path.iterdir()) == []


def test_nan_is_refused_before_anything_is_written(tmp_path):
    """JSON output never carries NaN: the write fails and nothing is left."""
    with pytest.raises(ValueError):
        write_json_atomic(tmp_path / "x.json", {"p": float("nan")})
    assert list(tmp_path.iterdir()) == []
