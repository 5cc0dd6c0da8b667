"""``decentral export``: per-assembly TUM/KITTI/CSV trajectories that evo reads and scores as we do."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from decentral.estimator import EstimatorConfig, estimate_log
from decentral.metrics import score_estimate
from decentral.observations import Estimate, EstimateStep, PlanarPose
from sims.cli.main import main
from sims.io.log_json import write_estimate
from sims.io.trajectories import estimate_trajectories, trajectory_lines
from sims.simulation.scenarios import SCENARIOS, get_scenario, simulate
from sims.simulation.scenarios.output import save_simulation

BIN = Path(sys.executable).parent


def evo(tool: str, *args: str, home: Path) -> str:
    """Run an evo command line tool (with its settings under ``home``) and return its stdout."""
    env = {**os.environ, "HOME": str(home), "MPLBACKEND": "Agg"}
    done = subprocess.run([str(BIN / tool), *args], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def evo_mean(output: str) -> float:
    return float(re.search(r"^\s*mean\s+([-+0-9.eE]+)", output, re.M).group(1))


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A simulated 3-assembly ring, its estimate and both exports."""
    root = tmp_path_factory.mktemp("export")
    sim = simulate(get_scenario("multi", n_assemblies=3, steps=25), seed=4)
    save_simulation(sim, root / "sim")
    write_estimate(root / "est.json", estimate_log(sim.log, EstimatorConfig(window=5)))
    assert main(["export", str(root / "est.json"), "-o", str(root / "est_tum")]) == 0
    assert main(["export", str(root / "sim" / "truth.json"), "-o", str(root / "truth_tum")]) == 0
    return root, sim


def test_tum_lines_hold_time_position_and_yaw_quaternion():
    """A TUM line is 't x y z qx qy qz qw' with the quaternion of the rotation about z by theta."""
    est = Estimate("A0", (EstimateStep(0.5, {"A1": PlanarPose(np.array([1.0, 2.0, 0.5]), np.pi / 2)}),), {})
    (line,) = trajectory_lines(estimate_trajectories(est)["A1"], "tum")[".tum"]
    values = np.array(line.split(), dtype=float)
    np.testing.assert_allclose(values, [0.5, 1.0, 2.0, 0.5, 0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-15)


def test_kitti_and_csv_carry_the_same_poses(tmp_path, run_dir):
    """KITTI's [R|p] rows with its times file and the CSV's columns give back the TUM poses."""
    root, _ = run_dir
    for fmt in ("kitti", "csv"):
        assert main(["export", str(root / "est.json"), "-o", str(tmp_path / fmt), "--format", fmt]) == 0
    tum = np.loadtxt(root / "est_tum" / "A1.tum")
    kitti = np.loadtxt(tmp_path / "kitti" / "A1.txt").reshape(-1, 3, 4)
    times = np.loadtxt(tmp_path / "kitti" / "A1.times.txt")
    csv = np.loadtxt(tmp_path / "csv" / "A1.csv", delimiter=",", skiprows=1)
    assert (tmp_path / "csv" / "A1.csv").read_text().splitlines()[0] == "t,x,y,z,theta,qx,qy,qz,qw"
    np.testing.assert_array_equal(times, tum[:, 0])
    np.testing.assert_array_equal(kitti[:, :, 3], tum[:, 1:4])
    np.testing.assert_allclose(np.arctan2(kitti[:, 1, 0], kitti[:, 0, 0]), csv[:, 4], atol=1e-12)
    np.testing.assert_array_equal(csv[:, [0, 1, 2, 3, 5, 6, 7, 8]], tum)


def test_evo_ape_gives_the_error_decentral_score_gives(tmp_path, run_dir):
    """evo_ape tum (no alignment) on the truth and estimate exports = score's per-assembly errors."""
    root, sim = run_dir
    from sims.io.log_json import read_estimate

    score = score_estimate(sim.truth.poses, read_estimate(root / "est.json"))
    for name, s in score.per_assembly.items():
        ref, est = str(root / "truth_tum" / f"{name}.tum"), str(root / "est_tum" / f"{name}.tum")
        trans = evo_mean(evo("evo_ape", "tum", ref, est, home=tmp_path))
        angle = evo_mean(evo("evo_ape", "tum", ref, est, "-r", "angle_deg", home=tmp_path))
        assert trans == pytest.approx(s.position_m, abs=2e-6)  # evo prints 6 decimals
        assert angle == pytest.approx(s.yaw_deg, abs=2e-6)


def test_evo_ape_kitti_agrees_on_a_fully_placed_assembly(tmp_path, run_dir):
    """KITTI files (no times) compare pose by pose; for an assembly placed at every step evo gets the same."""
    root, sim = run_dir
    from sims.io.log_json import read_estimate

    estimate = read_estimate(root / "est.json")
    score = score_estimate(sim.truth.poses, estimate)
    name = next(n for n, s in score.per_assembly.items() if s.placed == s.total)
    for src, dst in ((root / "est.json", "e"), (root / "sim" / "truth.json", "t")):
        assert main(["export", str(src), "-o", str(tmp_path / dst), "--format", "kitti"]) == 0
    out = evo("evo_ape", "kitti", str(tmp_path / "t" / f"{name}.txt"), str(tmp_path / "e" / f"{name}.txt"),
              home=tmp_path)
    assert evo_mean(out) == pytest.approx(score.per_assembly[name].position_m, abs=2e-6)


def test_reference_can_be_changed_on_export(tmp_path, run_dir):
    """--reference A1 writes the truth and the estimate relative to A1, and evo still matches score."""
    root, sim = run_dir
    from sims.io.log_json import read_estimate

    for src, dst in ((root / "est.json", "e"), (root / "sim" / "truth.json", "t")):
        assert main(["export", str(src), "-o", str(tmp_path / dst), "--reference", "A1"]) == 0
    assert sorted(p.name for p in (tmp_path / "e").iterdir()) == ["A0.tum", "A2.tum"]
    truth_tum = np.loadtxt(tmp_path / "t" / "A0.tum")
    # the truth of A0 in A1 is the inverse of A1 in A0
    direct = np.loadtxt(root / "truth_tum" / "A1.tum")
    np.testing.assert_allclose(truth_tum[:, 6] ** 2 + truth_tum[:, 7] ** 2, 1.0)
    np.testing.assert_allclose(np.linalg.norm(truth_tum[:, 1:3], axis=1), np.linalg.norm(direct[:, 1:3], axis=1))
    out = evo("evo_ape", "tum", str(tmp_path / "t" / "A0.tum"), str(tmp_path / "e" / "A0.tum"), home=tmp_path)
    assert evo_mean(out) < 0.05
    assert read_estimate(root / "est.json").reference == "A0"


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_every_scenario_export_is_accepted_by_evo(tmp_path, scenario):
    """Each shipped scenario's estimate and truth exports load in evo_traj and score in evo_ape."""
    sim = simulate(get_scenario(scenario, steps=30 if scenario == "reconfig" else 8), seed=1)
    save_simulation(sim, tmp_path / "sim")
    estimate = estimate_log(sim.log, EstimatorConfig(window=3))
    write_estimate(tmp_path / "est.json", estimate)
    assert main(["export", str(tmp_path / "est.json"), "-o", str(tmp_path / "e")]) == 0
    assert main(["export", str(tmp_path / "sim" / "truth.json"), "-o", str(tmp_path / "t")]) == 0
    placed = sorted(p.name for p in (tmp_path / "e").iterdir())
    truth_files = sorted(str(p) for p in (tmp_path / "t").iterdir())
    if scenario == "single_node":  # built to be unplaceable: no estimate file, the truth still loads
        assert not placed and set(estimate.stats["unplaced"]) <= {"yaw_unobservable", "no_data"}
        evo("evo_traj", "tum", *truth_files, "--full_check", home=tmp_path)
        return
    evo("evo_traj", "tum", *[str(tmp_path / "e" / f) for f in placed], "--ref", truth_files[0], "--full_check",
        home=tmp_path)
    for name in placed[:3] + placed[-2:]:  # ring64: 63 files; the first and last few are enough for evo_ape
        out = evo("evo_ape", "tum", str(tmp_path / "t" / name), str(tmp_path / "e" / name), home=tmp_path)
        assert evo_mean(out) < 0.5


def test_bad_inputs_end_in_one_line_and_write_nothing(tmp_path, run_dir, capsys):
    """Wrong format, unknown reference: exit 2, one line naming the file or option, no output folder."""
    root, _ = run_dir
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "decentral.log/1"}))
    assert main(["export", str(bad), "-o", str(tmp_path / "o1")]) == 2
    assert main(["export", str(root / "est.json"), "-o", str(tmp_path / "o2"), "--reference", "A9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "bad.json: format" in err[0] and "--reference" in err[1]
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()


@pytest.mark.parametrize("times", [(0.0, 0.2, 0.2), (0.0, 0.4, 0.2)])
def test_every_estimate_reader_refuses_step_times_that_do_not_increase(tmp_path, run_dir, capsys, times):
    """export and score refuse a repeated or backward estimate time, naming steps[2].t; nothing is written."""
    root, _ = run_dir
    est = tmp_path / "est.json"
    steps = [{"t": t, "poses": {"A1": {"p": [1.0, 0.0, 0.0], "theta": 0.0}}} for t in times]
    est.write_text(json.dumps({"format": "decentral.estimate/1", "reference": "A0", "steps": steps}))
    assert main(["export", str(est), "-o", str(tmp_path / "out")]) == 2
    assert main(["score", str(est), str(root / "sim" / "truth.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(f"{est}: steps[2].t" in line for line in err), err
    assert not (tmp_path / "out").exists()


def test_quiet_silences_the_summary_and_the_summary_names_the_command(tmp_path, run_dir, capsys):
    """export prints its summary as `decentral export: ...`, and nothing at all under -q."""
    root, _ = run_dir
    assert main(["export", str(root / "est.json"), "-o", str(tmp_path / "a")]) == 0
    assert capsys.readouterr().err.startswith("decentral export: ")
    assert main(["-q", "export", str(root / "est.json"), "-o", str(tmp_path / "b")]) == 0
    assert capsys.readouterr().err == "" and (tmp_path / "b" / "A1.tum").exists()


def test_assembly_names_are_percent_encoded_into_file_names(tmp_path):
    """A name that is no file name (`r/1`, `..`) is written as its percent-encoding, the one keys uses."""
    from urllib.parse import unquote

    from sims.io.keyfiles import key_paths

    est = tmp_path / "est.json"
    poses = {name: {"p": [1.0, 0.0, 0.0], "theta": 0.0} for name in ("r/1", "..", "robot 2")}
    est.write_text(json.dumps({"format": "decentral.estimate/1", "reference": "A0",
                               "steps": [{"t": 0.0, "poses": poses}]}))
    assert main(["export", str(est), "-o", str(tmp_path / "out")]) == 0
    files = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert files == ["%2E..tum", "r%2F1.tum", "robot%202.tum"]
    assert {unquote(f[:-4]) for f in files} == set(poses)
    assert key_paths(tmp_path, "r/1")[0].name == "r%2F1.key.json"


def test_a_name_without_a_file_name_writes_no_folder(tmp_path, capsys):
    """An empty assembly name: exit 2, one line naming the input file, and no output folder created."""
    est = tmp_path / "est.json"
    est.write_text(json.dumps({"format": "decentral.estimate/1", "reference": "A0",
                               "steps": [{"t": 0.0, "poses": {"": {"p": [1.0, 0.0, 0.0], "theta": 0.0}}}]}))
    assert main(["export", str(est), "-o", str(tmp_path / "a" / "b")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{est}: assembly ''" in line, line
    assert not (tmp_path / "a").exists()
