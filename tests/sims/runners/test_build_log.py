"""``decentral build-log``: robot recordings (TUM, CSV, ROS 1 and ROS 2 bags, detections, frames) back
to the simulator's observation log, with explicit time association and one-line errors."""

import json

import numpy as np
import pytest

from decentral.errors import InputError
from decentral.estimator import EstimatorConfig, estimate_log
from decentral.odometry import increments, interpolate_planar
from sims.runners.build_log import associate, build_log
from sims.cli.main import main
from sims.io.log_json import read_log
from sims.io.rig import read_rig
from sims.simulation.robot_data import write_robot_data
from sims.simulation.scenarios import get_scenario, simulate
from sims.simulation.world.sensors import SensorNoise


@pytest.fixture(scope="module")
def sim():
    """A noisy 3-assembly ring (odometry always present, so every step's increment is recorded)."""
    return simulate(get_scenario("multi", n_assemblies=3, steps=20, sensors=SensorNoise(odom_missing=0.0)), seed=3)


def assert_same_log(built, original, *, odo_tol=1e-9, det_tol=1e-4):
    """Same assemblies, cameras, step times, configurations; odometry and detections within tolerance."""
    assert built.assemblies == original.assemblies and set(built.cameras) == set(original.cameras)
    assert len(built.steps) == len(original.steps)
    for a, b in zip(built.steps, original.steps):
        assert a.t == pytest.approx(b.t, abs=1e-9)
        assert a.config.keys() == b.config.keys()
        for name in a.config:
            assert a.config[name].keys() == b.config[name].keys()
            for node in a.config[name]:
                np.testing.assert_allclose(a.config[name][node], b.config[name][node], atol=1e-12)
        assert a.mounts.keys() == b.mounts.keys()
        for key in a.mounts:
            np.testing.assert_allclose(a.mounts[key].R, b.mounts[key].R, atol=1e-12)
            np.testing.assert_allclose(a.mounts[key].p, b.mounts[key].p, atol=1e-12)
        assert a.odometry.keys() == b.odometry.keys()
        for name in a.odometry:
            np.testing.assert_allclose(a.odometry[name].dp, b.odometry[name].dp, atol=odo_tol)
            assert a.odometry[name].dtheta == pytest.approx(b.odometry[name].dtheta, abs=odo_tol)
        for key in original.cameras:
            da, db = a.detections.get(key, ()), b.detections.get(key, ())
            assert [d.node for d in da] == [d.node for d in db]
            for x, y in zip(da, db):
                assert abs(x.u - y.u) <= det_tol and abs(x.v - y.v) <= det_tol and abs(x.r - y.r) <= det_tol


@pytest.mark.parametrize("fmt", ["tum", "csv", "ros1", "ros2"])
def test_recordings_rebuild_the_simulators_log_and_estimate(tmp_path, sim, fmt):
    """Odometry as TUM, CSV, ROS 1 or ROS 2 bag plus timed detections give back the log and the same estimate."""
    rig = write_robot_data(sim, tmp_path / "rec", odometry=fmt)
    assert main(["build-log", str(rig), "-o", str(tmp_path / "log.json")]) == 0
    built = read_log(tmp_path / "log.json")
    assert_same_log(built, sim.log)
    a, b = (estimate_log(log, EstimatorConfig(window=4)) for log in (built, sim.log))
    for sa, sb in zip(a.steps, b.steps):
        assert sa.poses.keys() == sb.poses.keys()
        for name in sa.poses:
            np.testing.assert_allclose(sa.poses[name].p, sb.poses[name].p, atol=1e-5)


def test_a_changing_layout_goes_through_a_layout_file(tmp_path):
    """reconfig's configuration changes over time: written as a layout file, rebuilt step by step."""
    run = simulate(get_scenario("reconfig", steps=40, sensors=SensorNoise(odom_missing=0.0)), seed=0)
    rig = write_robot_data(run, tmp_path / "rec")
    assert "layout = " in rig.read_text()
    log, _ = build_log(read_rig(rig))
    assert_same_log(log, run.log)


def test_interpolation_at_frame_times_is_linear_in_position_and_shortest_arc_in_yaw():
    """Between samples the pose is interpolated; yaw crosses +-pi the short way; far queries are refused."""
    t = np.array([0.0, 1.0, 2.0])
    p = np.array([[0.0, 0, 0], [1.0, 2, 0], [2.0, 2, 1]])
    yaw = np.array([3.0, -3.0, -2.0])  # 3.0 -> -3.0 is +0.283 rad through pi, not -6 rad
    pq, yq, ok = interpolate_planar(t, p, yaw, np.array([0.25, 1.25, 5.0]), tolerance=0.5)
    np.testing.assert_allclose(pq[0], [0.25, 0.5, 0.0])
    assert yq[0] == pytest.approx(3.0 + 0.25 * (2 * np.pi - 6.0))
    np.testing.assert_allclose(pq[1], [1.25, 2.0, 0.25])
    assert list(ok) == [True, True, False]


def test_increments_are_in_the_root_frame_at_the_earlier_step():
    """Moving 1 m along world y while facing +y is dp = (1, 0, 0) with the robot's yaw at the start."""
    dp, dth = increments(np.array([[0.0, 0, 0], [0.0, 1, 0]]), np.array([np.pi / 2, np.pi / 2 + 0.1]))
    np.testing.assert_allclose(dp[0], [1.0, 0.0, 0.0], atol=1e-12)
    assert dth[0] == pytest.approx(0.1)


def test_odometry_at_another_rate_is_interpolated_within_its_error(tmp_path, sim):
    """50 Hz odometry, offset from the frames: increments within the interpolation error of a smooth path."""
    rig = write_robot_data(sim, tmp_path / "rec", odometry="tum")
    truth = sim.truth.poses
    t_fine = np.arange(sim.log.steps[0].t - 0.01, sim.log.steps[-1].t + 0.01, 0.02) + 0.003
    for name in sim.log.assemblies:
        yaw = np.unwrap(np.arctan2(truth.R[name][:, 1, 0], truth.R[name][:, 0, 0]))
        p = np.stack([np.interp(t_fine, truth.times, truth.p[name][:, i]) for i in range(3)], axis=1)
        y = np.interp(t_fine, truth.times, yaw)
        q = np.stack([np.zeros_like(y), np.zeros_like(y), np.sin(y / 2), np.cos(y / 2)], axis=1)
        np.savetxt(tmp_path / "rec" / f"{name}.tum", np.column_stack([t_fine, p, q]))
    log, report = build_log(read_rig(rig))
    assert not any(report.missing_odometry.values())
    for k in range(1, len(log.steps)):
        for name in sim.log.assemblies:
            R0 = truth.R[name][k - 1]
            true_dp = R0.T @ (truth.p[name][k] - truth.p[name][k - 1])
            np.testing.assert_allclose(log.steps[k].odometry[name].dp, true_dp, atol=2e-3)


def test_frames_without_odometry_or_step_are_reported_not_dropped(tmp_path, sim, capsys):
    """Odometry samples cut around two steps and a camera's frame shifted past tolerance: counted in the report."""
    rig = write_robot_data(sim, tmp_path / "rec", odometry="tum")
    tum = np.loadtxt(tmp_path / "rec" / "A2.tum")
    np.savetxt(tmp_path / "rec" / "A2.tum", np.delete(tum, [5, 6], axis=0))
    dets = json.loads((tmp_path / "rec" / "A1_cam0.json").read_text())
    dets["frames"][3]["t"] += 0.09
    (tmp_path / "rec" / "A1_cam0.json").write_text(json.dumps(dets))
    assert main(["build-log", str(rig), "-o", str(tmp_path / "log.json"), "--report", str(tmp_path / "r.json")]) == 0
    line = capsys.readouterr().err.strip()
    assert "frames without a step: A1/cam0 1" in line and "steps without odometry: A2 2" in line
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["missing_odometry"]["A2"] == pytest.approx([sim.log.steps[5].t, sim.log.steps[6].t])
    log = read_log(tmp_path / "log.json")
    assert all("A2" not in log.steps[k].odometry for k in (5, 6, 7)) and "A2" in log.steps[8].odometry
    assert "A1/cam0" not in log.steps[3].detections and len(log.steps) == len(sim.log.steps)


def test_association_keeps_the_nearest_frame_per_step():
    """Two frames near one step: the nearer goes to it, the other is unmatched; far frames are unmatched."""
    matched, lost = associate(np.array([0.0, 0.21, 0.185, 0.7]), np.array([0.0, 0.2, 0.4]), 0.05)
    assert matched == {0: 0, 1: 1} and lost == [2, 3]


def test_bag_images_are_perceived_into_detections(tmp_path):
    """Rendered frames in a ROS 2 bag (Image + CameraInfo) and as PNG files with a times file are perceived
    alike; the ids found are the simulator's (the path of ``decentral perceive --log-template``)."""
    run = simulate(get_scenario("table1", steps=5, noise=False), seed=0)
    bag_log, report = build_log(read_rig(write_robot_data(run, tmp_path / "bag", odometry="ros2", images=True)))
    png_log, _ = build_log(read_rig(write_robot_data(run, tmp_path / "png", odometry="tum", images=True)))
    np.testing.assert_allclose(bag_log.cameras["A0/cam0"].K, run.log.cameras["A0/cam0"].K)
    found = {(k, d.node) for k, s in enumerate(bag_log.steps) for d in s.detections.get("A0/cam0", ())}
    truth_ids = {(k, d.node) for k, s in enumerate(run.log.steps) for d in s.detections.get("A0/cam0", ())}
    assert report.detections == len(found) and len(found & truth_ids) >= 0.5 * len(truth_ids)
    assert len(found - truth_ids) <= 0.1 * len(found)
    for a, b in zip(bag_log.steps, png_log.steps):
        assert a.detections["A0/cam0"] == b.detections["A0/cam0"]


BAD_RIGS = {
    "format": ('format = "x"\n', "format"),
    "unknown key": ('format = "decentral.rig/1"\nnode_radius = 0.06\nspeed = 3\n', "speed"),
    "radius": ('format = "decentral.rig/1"\nnode_radius = -1\n[assemblies.A0]\nnodes = {0 = [0, 0, 0]}\n', "node_radius"),
    "no cameras": ('format = "decentral.rig/1"\nnode_radius = 0.06\n[assemblies.A0]\nnodes = {0 = [0, 0, 0]}\n',
                   "assemblies"),
    "toml": ("format = \n", "not valid TOML"),
}


@pytest.mark.parametrize("case", sorted(BAD_RIGS))
def test_bad_rig_files_end_in_one_line_naming_the_field(tmp_path, capsys, case):
    """A bad rig file: exit 2, one line naming the file and the field, no log written."""
    text, field = BAD_RIGS[case]
    (tmp_path / "rig.toml").write_text(text)
    assert main(["build-log", str(tmp_path / "rig.toml"), "-o", str(tmp_path / "log.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rig.toml" in err[0] and field in err[0]
    assert not (tmp_path / "log.json").exists()


def test_bad_data_files_end_in_one_line_naming_file_and_field(tmp_path, sim, capsys):
    """A non-numeric TUM line, a missing bag topic, a detection frame without time: exit 2, file and field named."""
    rig = write_robot_data(sim, tmp_path / "rec", odometry="tum")
    good = (tmp_path / "rec" / "A1.tum").read_text()
    (tmp_path / "rec" / "A1.tum").write_text(good + "1e9 x 0 0 0 0 0 1\n")
    assert main(["build-log", str(rig), "-o", str(tmp_path / "log.json")]) == 2
    (tmp_path / "rec" / "A1.tum").write_text(good)
    dets = json.loads((tmp_path / "rec" / "A0_cam0.json").read_text())
    del dets["frames"][2]["t"]
    (tmp_path / "rec" / "A0_cam0.json").write_text(json.dumps(dets))
    assert main(["build-log", str(rig), "-o", str(tmp_path / "log.json")]) == 2
    bag_rig = write_robot_data(sim, tmp_path / "bag", odometry="ros1")
    bag_rig.write_text(bag_rig.read_text().replace('"/A1/odom"', '"/nope"'))
    assert main(["build-log", str(bag_rig), "-o", str(tmp_path / "log.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3
    assert "A1.tum: line 21" in err[0] and "A0_cam0.json: frames[2].t" in err[1] and "run.bag: /nope" in err[2]
    assert not (tmp_path / "log.json").exists()


@pytest.mark.parametrize("version,compressed", [(1, False), (2, False), (1, True), (2, True)])
def test_image_stamps_read_from_the_serialized_header_equal_the_decoded_ones(tmp_path, version, compressed):
    """image_times reads header.stamp from the raw bytes (no image decoded): same as deserializing, in ROS 1
    and 2 bags, for Image and CompressedImage; the images decode to what was written."""
    from sims.io.bags import IMAGE_TYPES, _messages, _stamp, image_times, iter_images
    from sims.simulation.robot_data import write_bag

    frames = [(t, np.full((4, 6, 3), 10 * k, np.uint8)) for k, t in enumerate((0.5, 1.25, 1.7e9 + 0.123456))]
    bag = write_bag(tmp_path / ("run.bag" if version == 1 else "run"), version, {}, {"/img": frames},
                    compressed=compressed)
    decoded = [_stamp(m) for m in _messages(bag, "/img", IMAGE_TYPES)]
    np.testing.assert_array_equal(image_times(bag, "/img"), decoded)
    np.testing.assert_allclose(decoded, [t for t, _ in frames], atol=1e-6)
    assert [int(image[0, 0, 0]) for _, image in iter_images(bag, "/img")] == [0, 10, 20]


#: a node identified in both the PNG frames and their MJPG video is placed alike within this many pixels
#: (centre and radius; JPEG compression moves the fitted circle by a fraction of a pixel)
VIDEO_PX = 2.0
#: share of the PNG frames' identified (step, node) pairs that the video must also identify (JPEG blurs
#: the tag cells, so some tags are lost; 21-28 of 28 here, depending on the CPU's BLAS and codec paths)
VIDEO_RECALL = 0.5


def test_a_video_with_a_frame_rate_is_perceived_like_its_frames(tmp_path):
    """The same rendered frames as PNG files (times file) and as an MJPG video (rate, start) give the same
    steps; the nodes identified in both are placed alike, and the video identifies at least half of them."""
    import cv2

    run = simulate(get_scenario("table1", steps=5, noise=False), seed=0)
    rig = write_robot_data(run, tmp_path / "rec", odometry="tum", images=True)
    png_log, _ = build_log(read_rig(rig))
    frames = sorted((tmp_path / "rec" / "frames" / "A0" / "cam0").glob("*.png"))
    first = cv2.imread(str(frames[0]))
    video = cv2.VideoWriter(str(tmp_path / "rec" / "cam0.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 5.0,
                            (first.shape[1], first.shape[0]))
    for f in frames:
        video.write(cv2.imread(str(f)))
    video.release()
    text = rig.read_text().replace('frames = "frames/A0/cam0/*.png"', 'video = "cam0.avi"')
    rig.write_text(text.replace('times = "A0_cam0.times.txt"', f"rate = 5.0\nstart = {run.log.steps[0].t}"))
    video_log, report = build_log(read_rig(rig))
    assert report.frames["A0/cam0"] == len(frames) and not report.unmatched_frames["A0/cam0"]
    assert [s.t for s in video_log.steps] == pytest.approx([s.t for s in png_log.steps], abs=1e-9)
    placed = lambda log: {(k, d.node): d for k, s in enumerate(log.steps) for d in s.detections.get("A0/cam0", ())}  # noqa: E731
    png, vid = placed(png_log), placed(video_log)
    both = png.keys() & vid.keys()
    assert png and len(both) >= VIDEO_RECALL * len(png), (len(both), len(png))
    for key in both:
        a, b = png[key], vid[key]
        assert np.hypot(a.u - b.u, a.v - b.v) < VIDEO_PX and abs(a.r - b.r) < VIDEO_PX, (key, a, b)


def test_quiet_silences_the_summary_and_the_summary_names_the_command(tmp_path, sim, capsys):
    """build-log prints its summary as `decentral build-log: ...`, and nothing at all under -q."""
    rig = write_robot_data(sim, tmp_path / "rec", odometry="tum")
    assert main(["build-log", str(rig), "-o", str(tmp_path / "log.json")]) == 0
    assert capsys.readouterr().err.startswith("decentral build-log: ")
    assert main(["-q", "build-log", str(rig), "-o", str(tmp_path / "log2.json")]) == 0
    assert capsys.readouterr().err == "" and (tmp_path / "log2.json").exists()


def test_frame_times_out_of_order_name_the_detections_file(tmp_path, sim, capsys):
    """Detection frames whose times go backwards: the error names that file and frames[i].t, not the rig."""
    rig = write_robot_data(sim, tmp_path / "rec", odometry="tum")
    dets = json.loads((tmp_path / "rec" / "A0_cam0.json").read_text())
    dets["frames"][3]["t"] = dets["frames"][1]["t"]
    (tmp_path / "rec" / "A0_cam0.json").write_text(json.dumps(dets))
    assert main(["build-log", str(rig), "-o", str(tmp_path / "log.json")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "A0_cam0.json: frames[3].t" in line and "rig.toml" not in line, line


def test_a_node_id_in_two_assemblies_names_the_layout_file_that_repeats_it(tmp_path, capsys):
    """A layout file giving a node that another assembly holds at the same time: that file and its field are named."""
    run = simulate(get_scenario("reconfig", steps=40, sensors=SensorNoise(odom_missing=0.0)), seed=0)
    rig = write_robot_data(run, tmp_path / "rec")
    layout_file = next((tmp_path / "rec").glob("*_layout.json"))
    owner = layout_file.name.removesuffix("_layout.json")
    other = next(name for name in run.log.assemblies if name != owner)
    taken = next(iter(run.log.steps[0].config[other]))
    doc = json.loads(layout_file.read_text())
    doc["layouts"][0]["nodes"][str(taken)] = [0.0, 0.4, 0.0]
    layout_file.write_text(json.dumps(doc))
    assert main(["build-log", str(rig), "-o", str(tmp_path / "log.json")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{layout_file.name}: layouts[0].nodes.{taken}" in line and "rig.toml" not in line, line


def test_a_node_may_move_to_another_assembly_over_time():
    """Node ids must be unique among the layouts in force at one time, not over the whole recording."""
    from sims.io.rig import RigAssembly, _check_unique_nodes
    from sims.io.robot_files import Layout

    node = {7: np.zeros(3)}
    a = RigAssembly("A", Layout(np.array([0.0, 5.0]), ({0: np.zeros(3), **node}, {0: np.zeros(3)}), (), "a.json"), None, ())
    b = RigAssembly("B", Layout(np.array([0.0, 5.0]), ({1: np.zeros(3)}, {1: np.zeros(3), **node}), (), "b.json"), None, ())
    _check_unique_nodes((a, b))
    early = RigAssembly("B", Layout(np.array([0.0, 4.0]), ({1: np.zeros(3)}, {1: np.zeros(3), **node}), (), "b.json"), None, ())
    with pytest.raises(InputError, match="node id 7 also belongs to A at t=4") as err:
        _check_unique_nodes((a, early))
    assert err.value.source == "b.json" and err.value.field == "layouts[1].nodes.7"
