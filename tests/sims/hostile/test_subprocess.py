"""Hostile inputs through a real ``decentral`` process with a 1 GB address-space cap: the file-descriptor
level stderr holds exactly our one line (libpng, libjpeg, OpenCV and FFmpeg print nothing), and files
that used to take gigabytes are refused within the cap."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
import zlib

import cv2
import numpy as np
import pytest

from tests.sims.hostile.harness import assert_refused, run_subprocess, write_json_text, write_npz

#: interpreter and import start-up of a subprocess on a loaded machine, allowed on top of the 10 s
STARTUP = 5.0


def _black_png(path, side: int):
    """A valid black ``side`` x ``side`` grey PNG, compressed (32000 -> about 4 MB on disk)."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    comp = zlib.compressobj(1)
    rows = b"\0" * (side + 1) * 1000
    parts = [comp.compress(rows) for _ in range(side // 1000)] + [comp.compress(b"\0" * (side + 1) * (side % 1000))]
    idat = b"".join(parts) + comp.flush()
    ihdr = struct.pack(">IIBBBBB", side, side, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b""))
    return path


def test_a_black_32000_square_png_is_refused_within_the_memory_cap(tmp_path):
    """A 4 MB PNG of 32000 x 32000 pixels (7.3 GB decoded) is refused from its header under a 1 GB cap."""
    img = _black_png(tmp_path / "black.png", 32_000)
    assert img.stat().st_size < 10e6
    assert_refused(run_subprocess(["perceive", img, "-o", "dets.json"], tmp_path), "black.png", startup=STARTUP)


@pytest.fixture
def damaged_media(tmp_path):
    """Truncated or corrupt PNG, JPEG and MP4 files whose decoders print on their own."""
    img = (np.random.default_rng(0).random((120, 160, 3)) * 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "ok.png"), img)
    cv2.imwrite(str(tmp_path / "ok.jpg"), img)
    writer = cv2.VideoWriter(str(tmp_path / "ok.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 5, (160, 120))
    for _ in range(3):
        writer.write(img)
    writer.release()
    files = {}
    for name in ("ok.png", "ok.jpg", "ok.mp4"):
        data = (tmp_path / name).read_bytes()
        (tmp_path / name).unlink()
        files[f"cut.{name[3:]}"] = data[: len(data) // 2]
    files["crc.png"] = files["cut.png"][:40] + bytes(60) + files["cut.png"][100:]
    files["junk.mp4"] = b"\0" * 4000
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    return tmp_path, sorted(files)


def test_damaged_images_and_videos_print_only_our_line(damaged_media):
    """Each damaged file: exit 2 and exactly one stderr line (no libpng/libjpeg/FFmpeg output)."""
    folder, names = damaged_media
    for name in names:
        assert_refused(run_subprocess(["perceive", name, "-o", "dets.json"], folder), name, startup=STARTUP)


def test_huge_module_count_and_deep_json_stay_within_the_memory_cap(tmp_path):
    """n = 10**8 with no edges (was 11.3 GB) and 100,000 nested brackets are refused under a 1 GB cap."""
    obs = write_npz(tmp_path / "obs.npz", format=np.array("decentral.ensemble/1"), dim=np.array(2), n=np.array(10**8),
                    radius=np.array(0.05), i=np.zeros(0, np.int64), j=np.zeros(0, np.int64), z=np.zeros((0, 2)))
    assert_refused(run_subprocess(["ensemble", "obs.npz", "-o", "est.npz"], tmp_path), "obs.npz", startup=STARTUP)
    write_json_text(tmp_path / "log.json", "[" * 100_000 + "]" * 100_000)
    assert_refused(run_subprocess(["localize", "log.json", "-o", "est.json"], tmp_path), "log.json", startup=STARTUP)


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_stale_part_file_of_a_killed_run_is_removed_by_the_next_run(log_doc, tmp_path):
    """A temporary file left by a process killed with SIGKILL is removed when the output is next written."""
    log = write_json_text(tmp_path / "log.json", log_doc)
    stale = tmp_path / f".est.json.{_dead_pid()}.x1y2z3.part"
    stale.write_text("")
    out = run_subprocess(["localize", log, "-o", "est.json"], tmp_path)
    assert out.status == 0, out.stderr
    assert not stale.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["est.json", "log.json"]


@pytest.mark.slow
def test_kill_9_at_random_moments_leaves_no_part_file_after_the_next_run(tmp_path):
    """SIGKILL at random moments of `localize` never leaves a .part file past the next successful run."""
    from sims.io.log_json import log_to_dict
    from sims.simulation.scenarios import get_scenario, simulate

    log = write_json_text(tmp_path / "log.json", log_to_dict(simulate(get_scenario("multi", steps=30), seed=1).log))
    rng = np.random.default_rng(0)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    for _ in range(20):
        proc = subprocess.Popen([sys.executable, "-m", "sims.cli.main", "localize", log, "-o", "est.json"],
                                cwd=tmp_path, env=env, stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.3, 3.0))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    out = run_subprocess(["localize", log, "-o", "est.json"], tmp_path)
    assert out.status == 0, out.stderr
    assert not list(tmp_path.glob(".*.part"))
    json.loads((tmp_path / "est.json").read_text())
