"""The rig's commands the way a user takes them (issue 24): ``simulate-rig`` as folders and as one
bag (both calibrate to the same result through ``rig_calibrate.calibrate_rig``), and ``verify`` of a
rig and of a single pair: the verdict printed, written (verify.yaml, verdict.txt) and as the exit
status."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from accuracy import NEES_BOUND, pose_nees

from ilcc_graph.app import main
from ilcc_graph.io import read_ground_truth, write_calibration
from ilcc_graph.io.rig_results import read_rig_calibration, write_rig_calibration
from ilcc_graph.io.rig_truth import read_rig_ground_truth
from ilcc_graph.run.rig_calibrate import calibrate_rig, to_calibration
from ilcc_graph.run.rig_verify import EXIT_CODES
from ilcc_graph.types import Calibration

RIG = ["--rig", "backpack", "--width", "1200"]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A backpack rig simulated as folders and as a bag; (the folders, the rig's calibration.yaml)."""
    d = tmp_path_factory.mktemp("rig")
    assert main(["simulate-rig", str(d / "folders"), *RIG, "--moments", "6", "--seed", "1"]) == 0
    assert main(["simulate-rig", str(d / "bag"), *RIG, "--moments", "6", "--seed", "1", "--as", "bag"]) == 0
    for layout in ("folders", "bag"):  # the folder's marker records the command that wrote it
        marker = yaml.safe_load((d / layout / ".ilcc-graph-run").read_text(encoding="utf-8"))
        assert marker["command"].startswith(f"ilcc-graph simulate-rig {d / layout}"), marker
    a, b = calibrate_rig(d / "folders"), calibrate_rig(d / "bag")
    assert a.sensors == b.sensors == ("vlp16", "os1", "pano") and not a.unsolved
    # the same graph: each LiDAR's beam table is measured from its scans as a pair's run measures it,
    # whose azimuth step the bag's and the folder's scans give to 1e-9 deg (the pair's bag test's bound)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-9, atol=1e-15)
    for s in a.sensors:
        np.testing.assert_allclose(a.T_ref_sensor[s], b.T_ref_sensor[s], rtol=0, atol=1e-9)
    assert [f.used for f in a.fates] == [f.used for f in b.fates] and all(f.used for f in a.fates)
    truth = read_rig_ground_truth(d / "folders")
    for x, y in (("vlp16", "os1"), ("vlp16", "pano"), ("os1", "pano")):
        e = a.relative(x, y)
        T = truth.T_a_b(x, y)
        assert np.degrees(np.arccos(np.clip((np.trace(e.T[:3, :3].T @ T[:3, :3]) - 1) / 2, -1, 1))) < 0.1
        assert np.linalg.norm(e.T[:3, 3] - T[:3, 3]) < 0.005
    return d / "folders", write_rig_calibration(d / "calibration.yaml", to_calibration(a))


def _verify(cal: Path, data: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, dict, str]:
    code = main(["verify", str(cal), str(data), "--out", str(out), "--jobs", "1"])
    printed = capsys.readouterr().out
    doc = yaml.safe_load((out / "verify.yaml").read_text())
    word = (out / "verdict.txt").read_text().strip()
    assert word == doc["verdict"] and code == doc["exit_status"] == EXIT_CODES[word]
    assert f"verdict: {word}" in printed
    assert all(len(line) <= 80 for line in printed.splitlines() if not line.startswith("wrote "))
    return code, doc, printed


def test_verify_a_rig(
    calibrated: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, cal = calibrated
    args = ["--moments", "5", "--seed", "9"]
    assert main(["simulate-rig", str(tmp_path / "same"), *RIG, *args]) == 0
    assert (
        main(
            [
                "simulate-rig",
                str(tmp_path / "knock"),
                *RIG,
                *args,
                "--moved",
                "os1",
                "--rotation-deg",
                "0,0,0.5",
            ]
        )
        == 0
    )
    code, doc, _ = _verify(cal, tmp_path / "same", tmp_path / "v1", capsys)
    assert doc["verdict"] != "fail" and set(doc["sensors"]) == {"os1", "pano"}
    code, doc, printed = _verify(cal, tmp_path / "knock", tmp_path / "v2", capsys)
    assert (
        code == 5
        and doc["sensors"]["os1"]["verdict"] == "fail"
        and doc["sensors"]["pano"]["verdict"] != "fail"
    )
    rz = doc["sensors"]["os1"]["axes"]["rz_deg"]
    assert rz["verdict"] == "fail" and abs(rz["change"] - 0.5) < 4 * rz["sigma"]
    assert "os1: FAIL" in printed
    # no data set there: one line, exit 2
    assert main(["verify", str(cal), str(tmp_path / "nothing"), "--out", str(tmp_path / "v3")]) == 2


def test_verify_a_pair(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A pair's calibration.yaml (the truth with a stated covariance) against a new single-pair data set;
    the same file turned 1 deg fails."""
    data = tmp_path / "pair"
    assert (
        main(["simulate", str(data), "--camera", "fisheye", "--width", "640", "--frames", "5", "--seed", "3"])
        == 0
    )
    T = read_ground_truth(data).T_cam_lidar
    cov = np.diag([np.radians(0.02)] * 3 + [1e-3] * 3) ** 2
    write_calibration(tmp_path / "ok.yaml", Calibration(T, cov, ()))
    code, doc, _ = _verify(tmp_path / "ok.yaml", data, tmp_path / "v1", capsys)
    assert doc["verdict"] != "fail" and list(doc["sensors"]) == ["camera"]
    turn = np.eye(4)
    turn[:3, :3] = np.array(
        [[1, 0, 0], [0, np.cos(0.0175), -np.sin(0.0175)], [0, np.sin(0.0175), np.cos(0.0175)]]
    )
    write_calibration(tmp_path / "off.yaml", Calibration(turn @ T, cov, ()))
    code, doc, _ = _verify(tmp_path / "off.yaml", data, tmp_path / "v2", capsys)
    assert code == 5 and doc["sensors"]["camera"]["verdict"] == "fail"


def test_calibrate_a_rig_through_the_command_line(
    calibrated: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``calibrate RIG_FOLDER`` writes the rig's calibration.yaml, the same as ``calibrate_rig``'s,
    prints every sensor's pose in the reference frame within 80 columns, and each pose is within
    its own covariance of the truth."""
    folders, stored = calibrated
    out = tmp_path / "out"
    # an option of a pair's or sessions' run that a rig's graph does not take is refused, before
    # anything is written; a pair's solve options (here the sensor model) apply to the rig as to a pair
    assert main(["calibrate", str(folders), "--out", str(out), "--refine", "paper"]) == 2
    assert "(mode)" in capsys.readouterr().err and not out.exists()
    forced = tmp_path / "forced"
    args = ["--out", str(forced), "--no-report", "--jobs", "1", "--sensor-model", "beams"]
    assert main(["calibrate", str(folders), *args]) == 0
    model = read_rig_calibration(forced / "calibration.yaml").extra["sensor_model"]
    assert model["chosen"] == "beams" and model["forced"], model
    assert "sensor model: beams (as asked)" in capsys.readouterr().out
    assert main(["calibrate", str(folders), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    printed = capsys.readouterr().out
    assert all(len(line) <= 80 for line in printed.splitlines() if not line.startswith("wrote ")), printed
    got, want = read_rig_calibration(out / "calibration.yaml"), read_rig_calibration(stored)
    assert got.sensors == want.sensors and got.reference == want.reference == "vlp16"
    np.testing.assert_array_equal(got.covariance, want.covariance)
    truth = read_rig_ground_truth(folders)
    for s in got.sensors:
        assert f"  {s}" in printed or s == got.reference
        np.testing.assert_array_equal(got.T_ref_sensor[s], want.T_ref_sensor[s])
        if s != got.reference:
            T_true = truth.T_a_b(got.reference, s)
            assert pose_nees(got.T_ref_sensor[s], got.block(s), T_true) < NEES_BOUND, s
    # export reads what calibrate wrote: each rig format, read back, holds every sensor's pose
    for fmt in ("ros-tf", "urdf", "json"):
        f = tmp_path / f"rig.{fmt}"
        assert main(["export", str(out / "calibration.yaml"), "--format", fmt, "--out", str(f)]) == 0
        _exported_poses_are_the_calibration(f, fmt, got)
    assert main(["export", str(out / "calibration.yaml"), "--format", "kitti"]) == 2
    # the backpack's camera is a panorama, which Kalibr has no model for: refused, not written wrong
    assert main(["export", str(out / "calibration.yaml"), "--format", "kalibr"]) == 2
    # verify reads what calibrate wrote
    code = main(["verify", str(out / "calibration.yaml"), str(folders), "--out", str(tmp_path / "v")])
    assert code in (0, 4) and (tmp_path / "v" / "verdict.txt").read_text().strip() in ("pass", "warn")


def _tree_poses(edges: dict[str, tuple[str, np.ndarray]], root: str) -> dict[str, np.ndarray]:
    """{frame: T_root_frame} of a transform tree given as {child: (parent, T_parent_child)}."""

    def pose(frame: str) -> np.ndarray:
        if frame == root:
            return np.eye(4)
        parent, T = edges[frame]
        return pose(parent) @ T

    return {frame: pose(frame) for frame in [root, *edges]}


def _exported_poses_are_the_calibration(f: Path, fmt: str, cal) -> None:  # noqa: ANN001
    """The file ``f`` (rig export ``fmt``) read back with a parser of its own format: every sensor's
    frame (a camera's ``_optical`` frame when it has one: OpenCV axes, as ``T_ref_sensor``) sits at
    the calibration's ``T_ref_sensor`` from the reference, to the printed digits."""
    import json
    import xml.etree.ElementTree as ET

    from scipy.spatial.transform import Rotation

    def T_of(R: np.ndarray, t) -> np.ndarray:  # noqa: ANN001
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, np.asarray(t, float)
        return T

    if fmt == "json":
        doc = json.loads(f.read_text())
        assert doc["reference"] == cal.reference and doc["sensors"] == list(cal.sensors)
        np.testing.assert_allclose(np.array(doc["covariance"]), cal.covariance, rtol=1e-12, atol=0)
        poses = {s: np.array(doc["T_ref_sensor"][s]) for s in cal.sensors}
    else:
        edges = {}
        if fmt == "ros-tf":  # static_transform_publisher args: x y z qx qy qz qw parent child
            for node in ET.parse(f).getroot().iter("node"):
                *v, parent, child = node.get("args").split()
                R = Rotation.from_quat([float(x) for x in v[3:]]).as_matrix()
                edges[child] = (parent, T_of(R, [float(x) for x in v[:3]]))
        else:  # URDF fixed joints: origin xyz, rpy about fixed axes
            for joint in ET.parse(f).getroot().iter("joint"):
                o = joint.find("origin")
                R = Rotation.from_euler("xyz", [float(x) for x in o.get("rpy").split()]).as_matrix()
                xyz = [float(x) for x in o.get("xyz").split()]
                edges[joint.find("child").get("link")] = (joint.find("parent").get("link"), T_of(R, xyz))
        tree = _tree_poses(edges, cal.reference)
        poses = {s: tree.get(f"{s}_optical", tree.get(s)) for s in cal.sensors}
    T_ref = np.asarray(cal.T_ref_sensor[cal.reference])
    for s in cal.sensors:
        want = np.linalg.solve(T_ref, np.asarray(cal.T_ref_sensor[s]))
        np.testing.assert_allclose(poses[s], want, atol=1e-9, err_msg=f"{fmt}: {s}")


def test_verify_a_ring_whose_lenses_were_refined(tmp_path: Path) -> None:
    """Four pinholes stated alike, calibrated with ``--refine-intrinsics``: each camera gets its own
    lens (before: one set shared by all four), written per camera, and ``verify`` observes the
    calibration's own capture through them. Every camera then shows no change to 0.1 deg / 3 mm
    (through the stated lenses the back camera moved 0.63 deg / 7.1 mm on this capture)."""
    ring = tmp_path / "ring"
    preset = ["--rig", "ring-pinhole", "--moments", "12", "--width", "640"]
    assert main(["simulate-rig", str(ring), *preset]) == 0
    out = tmp_path / "cal"
    flags = ["--out", str(out), "--no-report", "--jobs", "1", "--refine-intrinsics"]
    assert main(["calibrate", str(ring), *flags]) == 0
    cal = read_rig_calibration(out / "calibration.yaml")
    lenses = cal.refined_intrinsics()
    assert sorted(lenses) == ["back", "front", "left", "right"], sorted(lenses)
    assert not np.allclose(lenses["front"]["values"], lenses["back"]["values"])
    assert main(["verify", str(out / "calibration.yaml"), str(ring), "--out", str(tmp_path / "v")]) in (0, 4)
    doc = yaml.safe_load((tmp_path / "v" / "verify.yaml").read_text())
    for camera in lenses:
        got = doc["sensors"][camera]
        assert got["rotation_deg"] < 0.1 and got["translation_mm"] < 3.0, (camera, got)
