"""A camera's intrinsics from its calibration tool's own file (``camera: {file: ...}`` in config.yaml):
ROS camera_calibration's ost.yaml, Kalibr camchains (each camera kind Kalibr holds, as our Kalibr export
writes it), OpenCV's FileStorage YAML and XML as OpenCV writes them; each gives the camera its inline
section gives. Wrong files are refused naming the file and the problem; the command line calibrates
with such a config."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.cameras import camera_class, camera_from_config, camera_kinds
from ilcc_graph.config import load_config, parse_rig_config
from ilcc_graph.errors import InputError
from ilcc_graph.simulate import RenderOptions, simulate_dataset, standard_spec

BOARD = {"squares": [6, 8], "square_size": 0.075}
OST = """image_width: 1280
image_height: 720
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [ 910.52917,    0.     ,  641.3112 ,
            0.     ,  908.91431,  358.47202,
            0.     ,    0.     ,    1.     ]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.334521, 0.118942, 0.000823, -0.000411, 0.000000]
rectification_matrix:
  rows: 3
  cols: 3
  data: [ 1.,  0.,  0.,
          0.,  1.,  0.,
          0.,  0.,  1.]
projection_matrix:
  rows: 3
  cols: 4
  data: [ 688.1,    0.     ,  645.2,    0.     ,
            0.     ,  842.3,  357.9,    0.     ,
            0.     ,    0.     ,    1.     ,    0.     ]
"""
INLINE = {"model": "pinhole", "width": 1280, "height": 720,
          "K": [[910.52917, 0, 641.3112], [0, 908.91431, 358.47202], [0, 0, 1]],
          "dist": [-0.334521, 0.118942, 0.000823, -0.000411, 0.0]}  # fmt: skip


def _config(folder: Path, camera: object) -> Path:
    p = folder / "config.yaml"
    p.write_text(yaml.safe_dump({"board": BOARD, "lidar": {"model": "vlp16"}, "camera": camera}))
    return p


def test_ros_ost_yaml(tmp_path: Path) -> None:
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib" / "ost.yaml").write_text(OST)
    want = camera_from_config(INLINE)
    assert load_config(_config(tmp_path, {"file": "calib/ost.yaml"})).camera == want
    assert load_config(_config(tmp_path, "calib/ost.yaml")).camera == want  # the short form
    sigma = dict.fromkeys(want.intrinsic_names, 0.5)
    sig = load_config(_config(tmp_path, {"file": "calib/ost.yaml", "intrinsics_sigma": sigma}))
    assert sig.camera.intrinsics_sigma.tolist() == [0.5] * len(sigma)
    assert sig.camera.K.tolist() == want.K.tolist()
    fisheye = OST.replace("distortion_model: plumb_bob", "distortion_model: equidistant")
    fisheye = fisheye.replace("cols: 5\n  data: [-0.334521, 0.118942, 0.000823, -0.000411, 0.000000]",
                              "cols: 4\n  data: [0.01, -0.002, 0.0003, -0.00004]")  # fmt: skip
    (tmp_path / "fe.yaml").write_text(fisheye)
    cam = load_config(_config(tmp_path, {"file": "fe.yaml"})).camera
    assert cam.kind == "fisheye" and cam.dist.tolist() == [0.01, -0.002, 0.0003, -0.00004]


@pytest.mark.parametrize("kind", [k for k in camera_kinds() if k != "equirectangular"])
def test_kalibr_camchain_of_each_kind(tmp_path: Path, kind: str) -> None:
    """Our Kalibr export's fields of each camera kind (``CameraModel.kalibr``), in a camchain of two
    cameras as Kalibr writes it (cam1 with its T_cn_cnm1), read back as the same camera."""
    cams = [camera_class(k).default(640) for k in (kind, "pinhole")]
    chain = {}
    for i, cam in enumerate(cams):
        fields, _ = cam.kalibr()
        chain[f"cam{i}"] = {**fields, "resolution": [cam.width, cam.height], "rostopic": f"/cam{i}/image_raw",
                            "cam_overlaps": [1 - i]}  # fmt: skip
    chain["cam1"]["T_cn_cnm1"] = np.eye(4).tolist()
    (tmp_path / "camchain.yaml").write_text(yaml.safe_dump(chain, sort_keys=False))
    got = load_config(_config(tmp_path, {"file": "camchain.yaml", "name": "cam0"})).camera
    want = cams[0].to_dict()
    assert got.to_dict().keys() == want.keys() and got.kind == kind
    for key, v in want.items():
        if key != "model":
            have = np.asarray(got.to_dict()[key], float)
            np.testing.assert_allclose(have, np.asarray(v, float), rtol=1e-12, err_msg=key)
    with pytest.raises(InputError, match=r"camchain\.yaml: a camchain of 2 cameras \(cam0, cam1\): say"):
        load_config(_config(tmp_path, {"file": "camchain.yaml"}))
    with pytest.raises(InputError, match=r"camchain\.yaml: no camera 'cam7' in this camchain"):
        load_config(_config(tmp_path, {"file": "camchain.yaml", "name": "cam7"}))


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_opencv_filestorage(tmp_path: Path, suffix: str) -> None:
    """As OpenCV's calibration sample writes it: image_width, image_height, camera_matrix and
    distortion_coefficients as opencv-matrix nodes; ``fisheye_model: 1`` for its fisheye."""
    import cv2

    p = tmp_path / f"out_camera_data{suffix}"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("calibration_time", "Thu Dec  3 07:00:00 2026")
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("board_width", 9)
    fs.write("camera_matrix", np.array(INLINE["K"], dtype=np.float64))
    fs.write("distortion_coefficients", np.array(INLINE["dist"], dtype=np.float64).reshape(5, 1))
    fs.write("avg_reprojection_error", 0.21)
    fs.release()
    assert p.read_bytes().startswith(b"%YAML" if suffix == ".yml" else b"<?xml")
    assert load_config(_config(tmp_path, {"file": p.name})).camera == camera_from_config(INLINE)
    q = tmp_path / f"fisheye{suffix}"
    fs = cv2.FileStorage(str(q), cv2.FILE_STORAGE_WRITE)
    fs.write("image_size", np.array([[1280, 720]], dtype=np.int32))  # a Mat, as some tools write it
    fs.write("fisheye_model", 1)
    fs.write("camera_matrix", np.array(INLINE["K"], dtype=np.float64))
    fs.write("distortion_coefficients", np.array([0.01, -0.002, 0.0003, -0.00004]).reshape(4, 1))
    fs.release()
    cam = load_config(_config(tmp_path, {"file": q.name})).camera
    assert (cam.kind, cam.width, cam.height) == ("fisheye", 1280, 720)
    # a cv::fisheye result saved without the flag: the section says its model in ROS's names
    r = tmp_path / f"plain{suffix}"
    fs = cv2.FileStorage(str(r), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("K", np.array(INLINE["K"], dtype=np.float64))
    fs.write("D", np.array([0.01, -0.002, 0.0003, -0.00004]).reshape(1, 4))
    fs.release()
    assert load_config(_config(tmp_path, {"file": r.name})).camera.kind == "pinhole"
    assert load_config(_config(tmp_path, {"file": r.name, "distortion_model": "equidistant"})).camera == cam


def test_wrong_camera_files_are_refused_naming_file_and_problem(tmp_path: Path) -> None:
    cases = {
        "missing": ({"file": "nope.yaml"}, r"config\.yaml: camera\.file = 'nope\.yaml': expected an"),
        "other": ({"file": "other.yaml"}, r"other\.yaml: not a camera file we read"),
        "short": ({"file": "short.yaml"}, r"short\.yaml: camera_matrix = .*: expected 9 finite numbers"),
        "eucm": ({"file": "eucm.yaml"}, r"eucm\.yaml: cam0: Kalibr camera_model 'eucm'"),
        "key": ({"file": "short.yaml", "dist": [0, 0, 0, 0]}, r"camera\.dist = .*: expected no such key"),
        "cut": ({"file": "cut.yml"}, r"cut\.yml: OpenCV cannot read this FileStorage file"),
    }
    (tmp_path / "other.yaml").write_text("board: 1\n")
    (tmp_path / "cut.yml").write_text("%YAML:1.0\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: [")
    (tmp_path / "short.yaml").write_text(OST.replace("0.     ,    0.     ,    1.     ]", "1.]"))
    (tmp_path / "eucm.yaml").write_text(yaml.safe_dump({"cam0": {
        "camera_model": "eucm", "intrinsics": [0.6, 1.1, 300, 300, 320, 240], "distortion_model": "none",
        "distortion_coeffs": [], "resolution": [640, 480]}}))  # fmt: skip
    for name, (section, words) in cases.items():
        with pytest.raises(InputError, match=words):
            load_config(_config(tmp_path, section))
        print(name, "refused")


def test_rig_camera_from_its_file(tmp_path: Path) -> None:
    (tmp_path / "ost.yaml").write_text(OST)
    rig = parse_rig_config(
        {"reference": "front", "board": BOARD,
         "sensors": {"front": {"camera": {"file": "ost.yaml"}}, "top": {"lidar": {"model": "vlp16"}}}},
        str(tmp_path / "rig.yaml"),
    )  # fmt: skip
    assert rig.sensor("front").camera == camera_from_config(INLINE)


def test_command_line_calibrates_with_a_camera_file(tmp_path: Path) -> None:
    """A simulated set whose config names the camera by its ost.yaml: calibrated by the command line,
    its resolved config holding the file's camera."""
    spec = standard_spec("vlp16", "pinhole", width=640, frames=6, seed=3, image=RenderOptions(supersample=1))
    data = simulate_dataset(tmp_path / "data", spec)
    cfg = yaml.safe_load((data / "config.yaml").read_text())
    cam = cfg["camera"]
    K = np.asarray(cam["K"], float)
    ost = {"image_width": cam["width"], "image_height": cam["height"], "camera_name": "sim",
           "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
           "distortion_model": "plumb_bob",
           "distortion_coefficients": {"rows": 1, "cols": len(cam["dist"]),
                                       "data": list(cam["dist"])}}  # fmt: skip
    (data / "ost.yaml").write_text(yaml.safe_dump(ost, sort_keys=False))
    inline = load_config(data / "config.yaml").camera
    cfg["camera"] = {"file": "ost.yaml"}
    (data / "config.yaml").write_text(yaml.safe_dump(cfg))
    assert load_config(data / "config.yaml").camera == inline
    out = tmp_path / "out"
    assert main(["calibrate", str(data), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    resolved = yaml.safe_load((out / "config.resolved.yaml").read_text())
    assert camera_from_config(resolved["camera"]) == inline
    (data / "ost.yaml").unlink()
    assert main(["calibrate", str(data), "--out", str(tmp_path / "out2"), "--no-report"]) == 2
