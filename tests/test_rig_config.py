"""rig.yaml (docs/rig.md): good files parse into the rig they describe, bad ones name file, key, value."""

from __future__ import annotations

import copy
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcc_graph.cameras import RefinedIntrinsics, camera_class, camera_kinds
from ilcc_graph.config import load_config, load_rig_config, parse_rig_config, rig_config_to_dict
from ilcc_graph.config.rig_config import flu_from_pose, pose_from_flu
from ilcc_graph.errors import InputError

ROOT = Path(__file__).resolve().parents[1]


def _doc_example() -> dict:
    """The complete example of docs/rig.md (its first yaml block), so the documentation stays true."""
    text = (ROOT / "docs" / "rig.md").read_text(encoding="utf-8")
    return yaml.safe_load(re.search(r"```yaml\n(.*?)```", text, re.S).group(1))


def _write(tmp_path: Path, d: dict) -> Path:
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False))
    return p


def test_the_documented_example_parses_into_the_rig_it_describes(tmp_path) -> None:
    rig = load_rig_config(_write(tmp_path, _doc_example()))
    assert rig.reference == "top" and rig.names == ("top", "rear", "front", "left", "back")
    assert rig.lidars == ("top", "rear") and rig.cameras == ("front", "left", "back")
    assert rig.sensor("top").lidar.name == "os1-64" and rig.sensor("top").roi.range_m == (0.5, 8.0)
    assert rig.sensor("rear").lidar.name == "vlp16"
    assert rig.sensor("front").camera.kind == "pinhole" and rig.sensor("left").camera.kind == "fisheye"
    assert rig.folder("front") == tmp_path / "cam_front" and rig.folder("left") == tmp_path / "left"
    assert rig.sensor("top").T_ref_sensor is None and rig.sensor("back").T_ref_sensor is None
    # the rear LiDAR: 1.2 m behind, 30 cm lower, looking back: its x axis is the reference's -x
    T_rear = rig.sensor("rear").T_ref_sensor
    np.testing.assert_allclose(T_rear[:3, 3], [-1.2, 0.0, -0.3])
    np.testing.assert_allclose(T_rear[:3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-12)
    # the front camera looks 5 deg down: its optical axis (OpenCV z) is forward and a little down
    z_front = rig.sensor("front").T_ref_sensor[:3, 2]
    np.testing.assert_allclose(z_front, [np.cos(np.deg2rad(5)), 0.0, -np.sin(np.deg2rad(5))], atol=1e-12)
    # the matrix written for the left camera is the FLU guess "30 cm left, 15 cm down, looking left"
    R_flu = camera_class("fisheye").R_flu_cam
    np.testing.assert_allclose(
        rig.sensor("left").T_ref_sensor,
        pose_from_flu([0, 0.3, -0.15], [90, 0, 0], np.eye(3), R_flu),
        atol=1e-12,
    )
    pair = rig.pair_config("front", "top")
    assert pair.camera is rig.sensor("front").camera and pair.lidar is rig.sensor("top").lidar
    assert pair.roi == rig.sensor("top").roi and pair.board == rig.board


@pytest.mark.parametrize("ref_kind", camera_kinds())
@pytest.mark.parametrize("sensor_kind", [*camera_kinds(), "lidar"])
def test_flu_guesses_round_trip_for_every_pair_of_sensor_kinds(ref_kind, sensor_kind) -> None:
    rng = np.random.default_rng(len(ref_kind) * 31 + len(sensor_kind))
    R_ref = camera_class(ref_kind).R_flu_cam
    R_s = np.eye(3) if sensor_kind == "lidar" else camera_class(sensor_kind).R_flu_cam
    for _ in range(5):
        xyz, ypr = rng.uniform(-2, 2, 3), rng.uniform([-180, -80, -180], [180, 80, 180])
        T = pose_from_flu(xyz, ypr, R_ref, R_s)
        assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3)) and np.isclose(np.linalg.det(T[:3, :3]), 1)
        xyz2, ypr2 = flu_from_pose(T, R_ref, R_s)
        np.testing.assert_allclose(xyz2, xyz, atol=1e-12)
        np.testing.assert_allclose(ypr2, ypr, atol=1e-9)


def test_written_rig_reads_back_the_same(tmp_path) -> None:
    rig = load_rig_config(_write(tmp_path, _doc_example()))
    for flu in (True, False):
        again = parse_rig_config(rig_config_to_dict(rig, flu_guesses=flu), str(tmp_path / "again.yaml"))
        assert again.names == rig.names and again.reference == rig.reference and again.board == rig.board
        for a, b in zip(rig.sensors, again.sensors, strict=True):
            assert (a.kind, a.folder, a.topic, a.roi) == (b.kind, b.folder, b.topic, b.roi)
            assert a.camera == b.camera and a.lidar == b.lidar
            if a.T_ref_sensor is None:
                assert b.T_ref_sensor is None
            else:
                np.testing.assert_allclose(b.T_ref_sensor, a.T_ref_sensor, atol=1e-6)


def test_a_single_pair_config_is_a_rig_of_one_lidar_and_one_camera(tmp_path) -> None:
    K = [[32, 0, 31.5], [0, 32, 19.5], [0, 0, 1]]
    d = {"board": {"squares": [6, 8], "square_size": 0.075, "roi": {"range_m": [1, 5]}},
         "lidar": {"model": "vlp16", "intensity_column": 3},
         "camera": {"model": "pinhole", "width": 64, "height": 40, "K": K}}  # fmt: skip
    p = tmp_path / "config.yaml"
    p.write_text(yaml.safe_dump(d))
    cfg, rig = load_config(p), load_rig_config(p)
    assert rig.names == ("lidar", "camera") and rig.reference == "lidar"
    assert rig.folder("lidar") == tmp_path / "pcd" and rig.folder("camera") == tmp_path / "img"
    pair = rig.pair_config("camera", "lidar")
    assert (pair.board, pair.lidar, pair.camera, pair.roi, pair.intensity_column) == (
        cfg.board,
        cfg.lidar,
        cfg.camera,
        cfg.roi,
        cfg.intensity_column,
    )


def _set(d: dict, path: str, value: object) -> dict:
    d = copy.deepcopy(d)
    keys = path.split(".")
    node = d
    for k in keys[:-1]:
        node = node[k]
    if value is _DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return d


_DELETE = object()
S, T = r"sensors\.", r"sensors\.front\.T_ref_sensor"
BAD = [
    ("sensors.front.camera.K", [[1, 2], [3, 4]], S + r"front\.camera\.K = \[\[1, 2\], \[3, 4\]\]: expected"),
    ("sensors.top.lidar.model", "vlp99", S + r"top\.lidar\.model = 'vlp99': expected one of \["),
    ("sensors.top.camera", {"model": "pinhole"}, S + r"top = \{.*\}: expected exactly one of the sections"),
    ("sensors.top.roi.range_m", [5, 1], S + r"top\.roi\.range_m = \[5, 1\]: expected \[min, max\] with min"),
    ("sensors.front.roi", {"range_m": [1, 2]}, S + r"front\.roi = .*: expected no roi on a camera"),
    ("sensors.front.lens", 1, S + r"front\.lens = 1: expected no such key; allowed keys here"),
    ("sensors.front.T_ref_sensor", [[1, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
     T + r" = .*: expected a rigid transform: its 3x3 block must be a rotation"),
    ("sensors.front.T_ref_sensor", {"ypr_deg": [0, 5]}, T + r"\.ypr_deg = \[0, 5\]: expected a list of 3"),
    ("sensors.front.T_ref_sensor", {"xyz": [0, 0, 0]}, T + r"\.xyz = .*: expected no such key"),
    ("sensors.top.T_ref_sensor", {"xyz_m": [0.1, 0, 0]}, S + r"top\.T_ref_sensor = .*: expected nothing, or"),
    ("sensors.left.folder", "cam_front", S + r"left\.folder = 'cam_front': expected a folder of its"),
    ("reference", "roof", r"reference = 'roof': expected the name of the sensor whose .* \['top', 'rear'"),
    ("reference", _DELETE, r"reference = missing: expected the name of the sensor"),
    ("board.roi", {"range_m": [1, 2]}, r"board\.roi = .*: expected no roi here: a roi belongs to a LiDAR"),
    ("board.squares", [8, 6], r"board\.squares = \[8, 6\]: expected \[rows, cols\] with rows <= cols"),
    ("data", {"select": "some"}, r"data\.select = 'some': expected one of \['auto', 'pauses', 'all'\]"),
    ("data", {"anchor": "roof"}, r"data\.anchor = 'roof': expected one of the sensors"),
    ("data", {"sync_tolerance": 0}, r"data\.sync_tolerance = 0: expected a number in \(0\.0, 10\.0\]"),
    ("rigg", 1, r"rigg = 1: expected no such key; allowed keys here: \['board', 'data', 'reference', 'sens"),
    ("sensors", {"top": {"lidar": {}}}, r"sensors = .*: expected at least two sensors"),
]  # fmt: skip


def _case_id(key: str, value: object) -> str:
    """The same name in every process (pytest-xdist's workers must collect alike)."""
    return f"{key}={'<deleted>' if value is _DELETE else repr(value)}"[:40]


@pytest.mark.parametrize(("key", "value", "message"), BAD, ids=[_case_id(k, v) for k, v, _ in BAD])
def test_a_bad_rig_file_names_the_file_the_key_the_value_and_what_was_expected(
    tmp_path, key, value, message
) -> None:
    p = _write(tmp_path, _set(_doc_example(), key, value))
    with pytest.raises(InputError, match=re.escape(str(p)) + ": " + message):
        load_rig_config(p)


def test_more_bad_rig_files(tmp_path) -> None:
    d = _doc_example()
    d["sensors"]["front"]["topic"] = d["sensors"]["left"]["topic"] = "/cam/image_raw"
    p = _write(tmp_path, d)
    with pytest.raises(
        InputError, match=r"sensors\.left\.topic = '/cam/image_raw': expected a topic of its own \(front"
    ):
        load_rig_config(p)
    d = _doc_example()
    d["sensors"]["front/left"] = d["sensors"].pop("left")
    with pytest.raises(
        InputError, match=r"rig\.yaml: sensors\.front/left = 'front/left': expected a sensor name of"
    ):
        load_rig_config(_write(tmp_path, d))
    (tmp_path / "empty.yaml").write_text("")
    with pytest.raises(InputError, match=r"empty\.yaml: rig file is empty"):
        load_rig_config(tmp_path / "empty.yaml")
    with pytest.raises(InputError, match=r"nope\.yaml: rig file not found"):
        load_rig_config(tmp_path / "nope.yaml")


def test_the_cameras_as_a_calibration_refined_them(tmp_path) -> None:
    """``RigConfig.with_intrinsics`` (verify's and the report's one rule): a camera stated as when
    calibrated takes the refined intrinsics; one stated otherwise keeps its own, with a note; the
    others and the LiDARs are untouched."""
    rig = load_rig_config(_write(tmp_path, _doc_example()))
    front, left = rig.sensor("front").camera, rig.sensor("left").camera
    moved = front.intrinsics() * 1.01
    def lens(cam, stated, values):  # noqa: ANN001, ANN202
        return RefinedIntrinsics(cam.intrinsic_names, stated, values, np.ones_like(values)).entry()

    other = left.intrinsics()  # stated otherwise than when calibrated
    refined = {"front": lens(front, front.intrinsics(), moved), "left": lens(left, other + 1, other)}
    got, notes = rig.with_intrinsics(refined)
    np.testing.assert_array_equal(got.sensor("front").camera.intrinsics(), moved)
    assert got.sensor("left").camera == left and got.sensor("back").camera == rig.sensor("back").camera
    assert got.sensor("top") == rig.sensor("top") and got.names == rig.names
    assert len(notes) == 1 and notes[0].startswith("left: ") and "stated otherwise" in notes[0]
    same, none = rig.with_intrinsics({})
    assert all(a is b for a, b in zip(same.sensors, rig.sensors, strict=True)) and none == []


def test_refined_intrinsics_are_taken_as_exact(tmp_path) -> None:
    """A stated ``intrinsics_sigma`` was the stated values' uncertainty: the refined ones replace them
    with their uncertainty in the calibration's covariance (else a capture verified through them
    propagated the stated sigma: 17 mm where its boards give 0.8 mm)."""
    import dataclasses

    from ilcc_graph.config.rig_config import as_calibrated
    from ilcc_graph.estimation.intrinsics import default_sigmas

    cam = load_rig_config(_write(tmp_path, _doc_example())).sensor("front").camera
    cam = dataclasses.replace(cam, intrinsics_sigma=default_sigmas(cam))
    values = cam.intrinsics() * 1.001
    refined = RefinedIntrinsics(cam.intrinsic_names, cam.intrinsics(), values, np.ones_like(values))
    got, note = as_calibrated(cam, refined, "front")
    assert note is None and got.intrinsics_sigma is None
    np.testing.assert_array_equal(got.intrinsics(), values)
