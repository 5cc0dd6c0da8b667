"""Every reproducer of malformed input found by hand: each is refused with exit 2, one stderr line naming
the file (or option), nothing written, within 10 s and 1 GB (run in-process through the CLI's main)."""

from __future__ import annotations

import json
import struct
import zipfile
import zlib

import numpy as np
import pytest

from tests.sims.hostile.harness import assert_refused, run_in_process, write_json_text, write_npz

DEEP = "[" * 100_000 + "]" * 100_000
BIG_INT = "1" * 5_000


def _set(doc, path, value):
    target = doc
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    return doc


# --- decentral.log/1 through `localize` ---------------------------------------------------------

LOG_FIELDS = {
    "node_radius": (["node_radius"], 1e308),
    "node_radius_tiny": (["node_radius"], 1e-308),
    "detection_r": (["steps", 1, "detections", "A0/cam0", 0, "r"], 1e308),
    "detection_r_tiny": (["steps", 1, "detections", "A0/cam0", 0, "r"], 1e-308),
    "detection_u": (["steps", 1, "detections", "A0/cam0", 0, "u"], 1e308),
    "K": (["assemblies", "A0", "cameras", "cam0", "K", 0, 0], 1e308),
    "K_principal": (["assemblies", "A0", "cameras", "cam0", "K", 0, 2], -1e308),
    "odometry_dp": (["steps", 1, "odometry", "A1", "dp", 0], 1e308),
    "odometry_dtheta": (["steps", 1, "odometry", "A1", "dtheta"], 1e308),
    "node_centre": (["steps", 0, "config", "A1", "10", 2], 1e308),
    "mount_p": (["assemblies", "A0", "cameras", "cam0", "strut_in_root", "p", 1], 1e308),
    "step_time": (["steps", 3, "t"], 1e308),
    "id_as_string": (["steps", 1, "detections", "A0/cam0", 0, "id"], "10"),
    "id_as_float": (["steps", 1, "detections", "A0/cam0", 0, "id"], 10.0),
    "id_huge": (["steps", 1, "detections", "A0/cam0", 0, "id"], 2**60),
    "rotation_not_rotation": (["assemblies", "A0", "cameras", "cam0", "cam_in_strut", "R", 0, 0], 2.0),
}


@pytest.mark.parametrize("case", sorted(LOG_FIELDS))
def test_log_values_out_of_range_are_refused_naming_the_field(case, log_doc, tmp_path):
    """Finite extremes and mistyped ids in a log are refused at validation, naming the file and field."""
    path, value = LOG_FIELDS[case]
    log = write_json_text(tmp_path / "log.json", _set(log_doc, path, value))
    out = run_in_process(["localize", log, "-o", tmp_path / "est.json"], tmp_path)
    assert_refused(out, "log.json")
    assert str(path[-1]) in out.lines[0]


@pytest.mark.parametrize("text, words", [
    (DEEP, "nesting depth"),
    ('{"format": "decentral.log/1", "node_radius": ' + BIG_INT + "}", "digits"),
    ("", "not valid JSON"),
    ("\xff\xfe garbage", "not valid JSON"),
])
def test_log_text_attacks_are_refused(text, words, tmp_path):
    """Deep nesting and 5,000-digit integers are refused before json recursion or int() can fail."""
    log = write_json_text(tmp_path / "log.json", text)
    out = run_in_process(["localize", log, "-o", tmp_path / "est.json"], tmp_path)
    assert_refused(out, "log.json")
    assert words in out.lines[0]


def test_assembly_count_is_bounded(log_doc, tmp_path, monkeypatch):
    """A log declaring more assemblies than the limit is refused before parsing them."""
    monkeypatch.setenv("DECENTRAL_MAX_ASSEMBLIES", "1")
    log = write_json_text(tmp_path / "log.json", log_doc)
    out = run_in_process(["localize", log, "-o", tmp_path / "est.json"], tmp_path)
    assert_refused(out, "log.json")
    assert "DECENTRAL_MAX_ASSEMBLIES" in out.lines[0]


def test_a_deeply_nested_rig_file_is_refused(tmp_path):
    """A TOML rig nested 100,000 deep is refused in one line (no RecursionError)."""
    rig = tmp_path / "rig.toml"
    rig.write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    out = run_in_process(["build-log", rig, "-o", tmp_path / "log.json"], tmp_path)
    assert_refused(out, "rig.toml")
    assert "nested too deeply" in out.lines[0]


def test_a_node_id_given_twice_in_one_assembly_is_refused(log_doc, tmp_path):
    """Duplicate JSON keys (a node listed twice) are refused, not silently the last one."""
    text = json.dumps(log_doc).replace('"A1": {"10": [0.0, 0.0, 0.0]}', '"A1": {"10": [0.0, 0.0, 0.0], "10": [9, 9, 9]}', 1)
    assert text.count('"10": [9, 9, 9]') == 1
    out = run_in_process(["localize", write_json_text(tmp_path / "log.json", text), "-o", tmp_path / "e.json"], tmp_path)
    assert_refused(out, "log.json")
    assert "twice" in out.lines[0] and "10" in out.lines[0]


def test_a_node_key_that_is_not_a_decimal_integer_is_refused(log_doc, tmp_path):
    """Config keys are decimal-integer strings; "ten" or "1e1" are not node ids."""
    for key in ("ten", "1e1", " 10"):
        doc = json.loads(json.dumps(log_doc).replace('"10": [0.0, 0.0, 0.0]', f'"{key}": [0.0, 0.0, 0.0]'))
        out = run_in_process(["localize", write_json_text(tmp_path / "log.json", doc), "-o", tmp_path / "e.json"],
                             tmp_path)
        assert_refused(out, "log.json")


@pytest.mark.parametrize("option, value", [
    ("--sigma-radius", "inf"), ("--sigma-radius", "nan"), ("--sigma-pixel", "1e308"), ("--sigma-odom-p", "0"),
    ("--sigma-odom-theta", "-1"), ("--loss", "nan"), ("--window", "0"), ("--seed", "-1"),
])
def test_absurd_localize_options_are_refused(option, value, log_doc, tmp_path):
    """Non-finite or out-of-range numeric options are refused naming the option."""
    log = write_json_text(tmp_path / "log.json", log_doc)
    before = log.read_bytes()
    out = run_in_process(["localize", log, "-o", tmp_path / "est.json", option, value], tmp_path)
    assert_refused(out, option)
    assert log.read_bytes() == before


def test_output_naming_a_directory_is_refused(log_doc, tmp_path):
    """`-o` naming an existing directory: one line, not IsADirectoryError."""
    (tmp_path / "outdir").mkdir()
    log = write_json_text(tmp_path / "log.json", log_doc)
    assert_refused(run_in_process(["localize", log, "-o", tmp_path / "outdir"], tmp_path), "outdir")


def test_output_equal_to_the_input_is_refused_and_the_input_kept(log_doc, tmp_path):
    """`-o` equal to the input (also through another spelling of the path) leaves the input untouched."""
    log = write_json_text(tmp_path / "log.json", log_doc)
    before = log.read_bytes()
    for output in (log, tmp_path / "." / "log.json"):
        assert_refused(run_in_process(["localize", log, "-o", output], tmp_path), "log.json")
    assert log.read_bytes() == before


def test_missing_output_folder_is_refused(log_doc, tmp_path):
    """An output in a folder that does not exist is refused before any work."""
    log = write_json_text(tmp_path / "log.json", log_doc)
    assert_refused(run_in_process(["localize", log, "-o", tmp_path / "no" / "est.json"], tmp_path), "est.json")


# --- `score`: estimate and truth ---------------------------------------------------------------------


def test_score_refuses_a_deeply_nested_estimate(truth_doc, tmp_path):
    """A deeply nested estimate is refused (no RecursionError)."""
    est = write_json_text(tmp_path / "est.json", DEEP)
    truth = write_json_text(tmp_path / "truth.json", truth_doc)
    assert_refused(run_in_process(["score", est, truth], tmp_path), "est.json")


def test_score_refuses_an_estimate_position_out_of_range(estimate_doc, truth_doc, tmp_path):
    """An estimate position of 1e308 is refused, never scored as Infinity."""
    est = write_json_text(tmp_path / "est.json", _set(estimate_doc, ["steps", 1, "poses", "A1", "p", 0], 1e308))
    truth = write_json_text(tmp_path / "truth.json", truth_doc)
    for extra in ([], ["--json"]):
        out = run_in_process(["score", est, truth, *extra], tmp_path)
        assert_refused(out, "est.json")
        assert "Infinity" not in out.stderr


def test_score_refuses_a_truth_rotation_that_is_not_a_rotation(estimate_doc, truth_doc, tmp_path):
    """Truth rotations are validated like the log's."""
    est = write_json_text(tmp_path / "est.json", estimate_doc)
    truth = write_json_text(tmp_path / "truth.json", _set(truth_doc, ["steps", 2, "poses", "A1", "R", 0], [2, 0, 0]))
    out = run_in_process(["score", est, truth], tmp_path)
    assert_refused(out, "truth.json")
    assert "steps[2].poses.A1.R" in out.lines[0]


def test_score_refuses_duplicate_keys_in_the_truth(estimate_doc, truth_doc, tmp_path):
    """A truth with an assembly given twice is refused."""
    text = json.dumps(truth_doc).replace('"poses": {', '"poses": {"A1": {}, ', 1)
    est = write_json_text(tmp_path / "est.json", estimate_doc)
    truth = write_json_text(tmp_path / "truth.json", text)
    assert_refused(run_in_process(["score", est, truth], tmp_path), "truth.json")


@pytest.mark.parametrize("change", ["reference", "target"])
def test_score_errors_name_the_estimate(change, estimate_doc, truth_doc, tmp_path):
    """What the truth lacks (the reference, a placed assembly) is reported against the estimate file."""
    if change == "reference":
        estimate_doc["reference"] = "A9"
    else:
        estimate_doc["steps"][0]["poses"]["A9"] = {"p": [0, 0, 0], "theta": 0}
    est = write_json_text(tmp_path / "est.json", estimate_doc)
    truth = write_json_text(tmp_path / "truth.json", truth_doc)
    assert_refused(run_in_process(["score", est, truth], tmp_path), "est.json")


# --- `ensemble`: decentral.ensemble/1 ---------------------------------------------------------------


@pytest.mark.parametrize("n", [10**8, 10**9, 10**12, 2**32, np.uint64(2**64 - 1), 1e12])
def test_huge_module_counts_are_refused_before_allocation(n, ensemble_arrays, tmp_path):
    """A 2 KB file declaring n = 1e8 ... uint64 max with no edges is refused at once, in little memory."""
    arrays = {**ensemble_arrays, "n": np.asarray(n), "i": np.zeros(0, np.int64), "j": np.zeros(0, np.int64),
              "z": np.zeros((0, 2))}
    obs = write_npz(tmp_path / "obs.npz", **arrays)
    out = run_in_process(["ensemble", obs, "-o", tmp_path / "est.npz"], tmp_path)
    assert_refused(out, "obs.npz")
    assert "n" in out.lines[0] and out.peak_bytes < 50e6


def test_distributed_runs_are_bounded_by_the_agent_limit(ensemble_arrays, tmp_path):
    """--distributed holds one agent per module: n over the agent limit is refused before any agent exists."""
    arrays = {**ensemble_arrays, "n": np.asarray(10**6), "i": np.zeros(0, np.int64), "j": np.zeros(0, np.int64),
              "z": np.zeros((0, 2))}
    obs = write_npz(tmp_path / "obs.npz", **arrays)
    out = run_in_process(["ensemble", obs, "-o", tmp_path / "est.npz", "--distributed"], tmp_path)
    assert_refused(out, "obs.npz")
    assert "DECENTRAL_MAX_AGENTS" in out.lines[0]


def test_unobserved_modules_are_laid_out_at_once(ensemble_arrays, tmp_path):
    """A tiny file declaring 10**6 modules and no observation is localized quickly (each module alone)."""
    arrays = {**ensemble_arrays, "n": np.asarray(10**6), "i": np.zeros(0, np.int64), "j": np.zeros(0, np.int64),
              "z": np.zeros((0, 2))}
    obs = write_npz(tmp_path / "obs.npz", **arrays)
    out = run_in_process(["ensemble", obs, "-o", tmp_path / "est.npz"], tmp_path, trace_memory=False)
    assert out.status == 0 and out.seconds < 10, out.stderr
    with np.load(tmp_path / "est.npz") as est:
        assert est["position"].shape == (10**6, 2) and np.unique(est["component"]).size == 10**6


def _npy_header(shape, dtype="<f8") -> bytes:
    header = repr({"descr": dtype, "fortran_order": False, "shape": shape}).encode() + b" "
    header += b" " * (-(len(header) + 11) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header


def test_a_member_declaring_a_huge_array_is_refused(ensemble_arrays, tmp_path):
    """A member whose .npy header declares (10**9, 2) but holds 16 bytes is refused without allocating."""
    obs = write_npz(tmp_path / "obs.npz", **{k: v for k, v in ensemble_arrays.items() if k != "z"})
    with zipfile.ZipFile(obs, "a") as zf:
        zf.writestr("z.npy", _npy_header((10**9, 2)) + bytes(16))
    out = run_in_process(["ensemble", obs, "-o", tmp_path / "est.npz"], tmp_path)
    assert_refused(out, "obs.npz")
    assert out.peak_bytes < 50e6


def test_a_plain_npy_given_as_npz_is_refused(tmp_path):
    """A .npy file is not an .npz archive."""
    obs = tmp_path / "obs.npz"
    with open(obs, "wb") as fh:
        np.save(fh, np.zeros(4))
    assert_refused(run_in_process(["ensemble", obs, "-o", tmp_path / "est.npz"], tmp_path), "obs.npz")


def test_a_zip_bomb_is_refused_from_its_directory(ensemble_arrays, tmp_path, monkeypatch):
    """A deflated member inflating past the array budget is refused from the zip directory, unread."""
    monkeypatch.setenv("DECENTRAL_MAX_ARRAY_MB", "5")
    obs = tmp_path / "obs.npz"
    with zipfile.ZipFile(obs, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key, value in ensemble_arrays.items():
            with zf.open(f"{key}.npy", "w") as fh:
                np.lib.format.write_array(fh, np.asarray(value))
        with zf.open("pad.npy", "w") as fh:  # 8 MB of zeros, a few KB on disk
            np.lib.format.write_array(fh, np.zeros(10**6))
    assert obs.stat().st_size < 100_000
    out = run_in_process(["ensemble", obs, "-o", tmp_path / "est.npz"], tmp_path)
    assert_refused(out, "obs.npz")
    assert "DECENTRAL_MAX_ARRAY_MB" in out.lines[0] and out.peak_bytes < 50e6


def _with_directory_size(path, member: str, change):
    """Rewrite the uncompressed size of ``member`` in the zip's central directory (entry signature PK\\1\\2)."""
    raw = bytearray(path.read_bytes())
    at = raw.index(member.encode(), raw.index(b"PK\x01\x02"))
    entry = raw.rindex(b"PK\x01\x02", 0, at)
    struct.pack_into("<I", raw, entry + 24, change(struct.unpack_from("<I", raw, entry + 24)[0]))
    path.write_bytes(bytes(raw))
    return path


def test_a_member_declaring_gigabytes_is_refused_at_the_default_limits(ensemble_arrays, tmp_path):
    """A zip directory entry declaring 4 GB of decompressed data is refused from the directory alone."""
    obs = _with_directory_size(write_npz(tmp_path / "obs.npz", **ensemble_arrays), "z.npy", lambda size: 4_000_000_000)
    out = run_in_process(["ensemble", obs, "-o", tmp_path / "est.npz"], tmp_path)
    assert_refused(out, "obs.npz")
    assert "DECENTRAL_MAX_ARRAY_MB" in out.lines[0] and out.peak_bytes < 50e6


def test_a_zip_directory_that_understates_a_member_is_refused(ensemble_arrays, tmp_path):
    """A member inflating beyond what its directory entry says is cut there and fails its checksum."""
    obs = _with_directory_size(write_npz(tmp_path / "obs.npz", **ensemble_arrays), "z.npy", lambda size: size - 16)
    assert_refused(run_in_process(["ensemble", obs, "-o", tmp_path / "est.npz"], tmp_path), "obs.npz")


@pytest.mark.parametrize("field, value", [
    ("z", 1e308), ("radius", 1e-308), ("radius", 1e308), ("radius", np.nan), ("dim", 7), ("n", -3), ("n", 2.5),
    ("i", 2**63 + 5), ("format", "decentral.log/1"),
])
def test_ensemble_values_out_of_range_are_refused(field, value, ensemble_arrays, tmp_path):
    """Absurd radius, z, dim, n, ids and format are refused naming the field, not by the solver later."""
    arrays = dict(ensemble_arrays)
    if field == "z":
        arrays["z"] = arrays["z"].copy()
        arrays["z"][3, 0] = value
    elif field == "i":
        arrays["i"] = arrays["i"].astype(np.uint64)
        arrays["i"][0] = np.uint64(value)
    else:
        arrays[field] = np.asarray(value)
    obs = write_npz(tmp_path / "obs.npz", **arrays)
    out = run_in_process(["ensemble", obs, "-o", tmp_path / "est.npz"], tmp_path)
    assert_refused(out, "obs.npz")
    assert field in out.lines[0]


def test_ensemble_output_equal_to_input_or_a_directory_is_refused(ensemble_arrays, tmp_path):
    """The observations are never overwritten by the estimate; a directory is not an output file."""
    obs = write_npz(tmp_path / "obs.npz", **ensemble_arrays)
    before = obs.read_bytes()
    assert_refused(run_in_process(["ensemble", obs, "-o", obs], tmp_path), "obs.npz")
    assert_refused(run_in_process(["ensemble", obs, "-o", tmp_path], tmp_path), str(tmp_path))
    assert obs.read_bytes() == before


# --- `perceive` --------------------------------------------------------------------------------------


def _png(path, width, height, rows: bytes | None = None):
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)  # 8-bit grey
    idat = zlib.compress(rows if rows is not None else b"\0" * 64)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b""))
    return path


@pytest.mark.parametrize("width, height, words", [
    (100_000, 100_000, "DECENTRAL_MAX_PIXELS"), (32_000, 32_000, "DECENTRAL_MAX_PIXELS"), (1, 1, "at least"),
])
def test_image_dimensions_are_checked_from_the_header(width, height, words, tmp_path):
    """Huge or tiny images are refused from their PNG header, before any decoding."""
    img = _png(tmp_path / "frame.png", width, height)
    out = run_in_process(["perceive", img, "-o", tmp_path / "dets.json"], tmp_path)
    assert_refused(out, "frame.png")
    assert words in out.lines[0] and out.peak_bytes < 50e6


@pytest.mark.parametrize("option, value", [("--min-radius", "nan"), ("--max-radius", "inf"), ("--min-radius", "0"),
                                           ("--max-radius", "1e308"), ("--log-min-score", "nan")])
def test_absurd_perceive_options_are_refused(option, value, tmp_path):
    """Non-finite or absurd radius options are refused naming the option."""
    img = _png(tmp_path / "frame.png", 64, 64, b"".join(b"\0" + bytes(64) for _ in range(64)))
    assert_refused(run_in_process(["perceive", img, "-o", tmp_path / "d.json", option, value], tmp_path), option)


@pytest.mark.parametrize("text, words", [(DEEP, "nesting"), ('{"1": 2, "1": 3}', "twice"), ('{"1": "10"}', "integer"),
                                         ('{"x": 3}', "decimal integer"), ("[1, 2]", "object")])
def test_bad_tag_tables_are_refused(text, words, tmp_path):
    """A tag table must be a flat object of decimal-integer keys and integer values."""
    img = _png(tmp_path / "frame.png", 64, 64, b"".join(b"\0" + bytes(64) for _ in range(64)))
    table = write_json_text(tmp_path / "tags.json", text)
    out = run_in_process(["perceive", img, "-o", tmp_path / "d.json", "--tag-table", table], tmp_path)
    assert_refused(out, "tags.json")
    assert words in out.lines[0]


def test_image_files_over_the_size_limit_are_refused_before_reading(tmp_path, monkeypatch):
    """An image file larger than DECENTRAL_MAX_FILE_MB is refused from its size on disk."""
    monkeypatch.setenv("DECENTRAL_MAX_FILE_MB", "0.01")
    img = _png(tmp_path / "frame.png", 64, 64, b"".join(b"\0" + bytes(64) for _ in range(64)))
    with open(img, "ab") as fh:
        fh.write(bytes(20_000))
    out = run_in_process(["perceive", img, "-o", tmp_path / "d.json"], tmp_path)
    assert_refused(out, "frame.png")
    assert "DECENTRAL_MAX_FILE_MB" in out.lines[0]


def test_a_bad_limit_variable_is_refused_naming_it(log_doc, tmp_path, monkeypatch):
    """A limit variable that is not a positive number is itself a one-line error naming the variable."""
    monkeypatch.setenv("DECENTRAL_MAX_JSON_DEPTH", "deep")
    log = write_json_text(tmp_path / "log.json", log_doc)
    assert_refused(run_in_process(["localize", log, "-o", tmp_path / "e.json"], tmp_path), "DECENTRAL_MAX_JSON_DEPTH")


def test_raising_a_limit_lets_the_input_through(tmp_path, monkeypatch):
    """The same image refused under a lowered pixel limit is processed once the limit is raised again."""
    img = _png(tmp_path / "frame.png", 64, 64, b"".join(b"\0" + bytes(64) for _ in range(64)))
    monkeypatch.setenv("DECENTRAL_MAX_PIXELS", "1000")
    assert_refused(run_in_process(["perceive", img, "-o", tmp_path / "d.json"], tmp_path), "frame.png")
    monkeypatch.setenv("DECENTRAL_MAX_PIXELS", "5000")
    out = run_in_process(["perceive", img, "-o", tmp_path / "d.json"], tmp_path)
    assert out.status == 0 and (tmp_path / "d.json").exists(), out.stderr


def test_video_frame_size_is_checked_before_frames_are_read(tmp_path, monkeypatch):
    """A video whose frames exceed the pixel limit is refused from the container's frame size."""
    import cv2

    writer = cv2.VideoWriter(str(tmp_path / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 5, (32, 24))
    for _ in range(3):
        writer.write(np.zeros((24, 32, 3), np.uint8))
    writer.release()
    monkeypatch.setenv("DECENTRAL_MAX_PIXELS", "500")
    out = run_in_process(["perceive", tmp_path / "clip.avi", "-o", tmp_path / "d.json"], tmp_path)
    assert_refused(out, "clip.avi")
    assert "32 x 24" in out.lines[0]


def test_perceive_output_equal_to_a_frame_is_refused(tmp_path):
    """Writing the detections over an input frame is refused."""
    img = _png(tmp_path / "frame.png", 64, 64, b"".join(b"\0" + bytes(64) for _ in range(64)))
    before = img.read_bytes()
    assert_refused(run_in_process(["perceive", img, "-o", img], tmp_path), "frame.png")
    assert img.read_bytes() == before


def test_usage_errors_are_one_line(tmp_path):
    """argparse's own errors (missing arguments, bad choices, non-numbers) are one line and exit 2 too."""
    for argv in (["localize"], ["ensemble", "x.npz", "-o", "y.npz", "--method", "magic"],
                 ["localize", "x.json", "-o", "y.json", "--window", "five"], []):
        out = run_in_process(argv, tmp_path, trace_memory=False)
        assert out.status == 2 and len(out.lines) == 1, out.stderr


@pytest.mark.parametrize("option, value", [("-n", str(10**9)), ("--radius", "1e308"), ("--radius", "nan"),
                                           ("--jitter", "inf"), ("-n", "-5")])
def test_absurd_make_ensemble_options_are_refused(option, value, tmp_path):
    """A module count over the limit or a non-physical radius is refused before generating anything."""
    out = run_in_process(["make-ensemble", "triple", "-o", tmp_path / "obs.npz", option, value], tmp_path)
    assert_refused(out, option.lstrip("-").split("-")[0])


@pytest.mark.parametrize("path, value", [(["steps", 1, "detections", "A0/cam0", 0, "r"], 1e-3),
                                         (["steps", 1, "odometry", "A1", "dp", 0], 1e6),
                                         (["assemblies", "A0", "cameras", "cam0", "K", 0, 0], 1e7)])
def test_extremes_inside_the_ranges_are_localized_not_crashed(path, value, log_doc, tmp_path):
    """Values at the edge of the accepted ranges give an estimate, never a crash (a 1e-3 px radius made a
    Cholesky factorization fail)."""
    log = write_json_text(tmp_path / "log.json", _set(log_doc, path, value))
    for mode in ("centralized", "admm"):
        out = run_in_process(["localize", log, "-o", tmp_path / f"{mode}.json", "--mode", mode], tmp_path,
                             trace_memory=False)
        # exit 3: a decentralized run that placed nothing says so (its estimate is still written)
        assert out.status in ((0,) if mode == "centralized" else (0, 3)) and "error" not in out.stderr, out.stderr
        json.loads((tmp_path / f"{mode}.json").read_text())
