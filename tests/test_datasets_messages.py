"""The bag source's message decoders on messages built with rosbags' typestores (ROS 1 and ROS 2).

PointCloud2 from its own field list (any offsets, point_step, endianness, organised rows with
padding, aliases, NaN and (0, 0, 0) dropped, sweep time); Image encodings and CompressedImage;
CameraInfo -> our camera section -> the config parser's camera models.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ilcc_graph.cameras import Fisheye, Pinhole
from ilcc_graph.config import parse_config
from ilcc_graph.datasets.ros_messages import camera_section, decode_cloud, decode_image, sweep_offset
from ilcc_graph.datasets.timeline import still_runs
from ilcc_graph.errors import InputError
from ilcc_graph.simulate.bag import RosMessages

BOARD = {"board": {"squares": [6, 8], "square_size": 0.075}, "lidar": {"model": "vlp16"}}
PF = "sensor_msgs/msg/PointField"


@pytest.fixture(params=[True, False], ids=["ros1", "ros2"])
def msgs(request) -> RosMessages:
    return RosMessages(request.param)


def _cloud(m: RosMessages, rec: np.ndarray, fields, h: int, w: int, row_step: int, big: bool = False):
    data = rec.view(np.uint8).reshape(h, -1)
    pad = row_step - data.shape[1]
    data = np.hstack([data, np.full((h, pad), 7, np.uint8)]).reshape(-1)
    pfs = [m.make(PF, name=n, offset=o, datatype=d, count=c) for n, o, d, c in fields]
    return m.make("sensor_msgs/msg/PointCloud2", header=m.header(0, "lidar"), height=h, width=w, fields=pfs,
                  is_bigendian=big, point_step=rec.dtype.itemsize, row_step=row_step, data=data,
                  is_dense=False)  # fmt: skip


def test_cloud_from_its_field_list_any_layout(msgs) -> None:
    rng = np.random.default_rng(0)
    h, w = 2, 5
    xyz = rng.uniform(-20, 20, (h * w, 3))
    xyz[3] = np.nan  # no return, NaN
    xyz[6] = 0.0  # no return, (0, 0, 0)
    refl = rng.integers(0, 65535, h * w)
    ring = rng.integers(0, 64, h * w)
    # big-endian float64 coordinates, intensity named "reflectivity" (uint16), "laser_id" (uint8),
    # a 3-count field, padding between fields and 8 bytes at the end of every row
    dt = np.dtype({"names": ["laser_id", "x", "y", "z", "rgb", "reflectivity"],
                   "formats": ["u1", ">f8", ">f8", ">f8", (">f4", (3,)), ">u2"],
                   "offsets": [0, 8, 16, 24, 32, 48], "itemsize": 56})  # fmt: skip
    rec = np.zeros(h * w, dt)
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["reflectivity"], rec["laser_id"] = refl, ring
    fields = [("laser_id", 0, 2, 1), ("x", 8, 8, 1), ("y", 16, 8, 1), ("z", 24, 8, 1), ("rgb", 32, 7, 3),
              ("reflectivity", 48, 4, 1)]  # fmt: skip
    scan = decode_cloud(_cloud(msgs, rec, fields, h, w, w * 56 + 8, big=True), "bag:/points")
    keep = np.ones(h * w, bool)
    keep[[3, 6]] = False
    np.testing.assert_array_equal(scan.points, xyz[keep])
    np.testing.assert_array_equal(scan.intensity, refl[keep].astype(np.float64))
    np.testing.assert_array_equal(scan.ring, ring[keep])
    assert scan.ring.dtype == np.int32 and scan.source == "bag:/points"


def test_cloud_sweep_time_and_missing_fields(msgs) -> None:
    n = 4
    dt = np.dtype({"names": ["x", "y", "z", "intensity", "t"], "formats": ["<f4"] * 4 + ["<u4"],
                   "offsets": [0, 4, 8, 12, 16], "itemsize": 20})  # fmt: skip
    rec = np.zeros(n, dt)
    rec["x"] = 1.0
    rec["t"] = [0, 25_000_000, 50_000_000, 99_000_000]  # Ouster: ns from the header stamp
    fields = [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 12, 7, 1), ("t", 16, 6, 1)]
    msg = _cloud(msgs, rec, fields, 1, n, 20 * n)
    assert sweep_offset(msg, "b") == pytest.approx(0.0495)
    assert decode_cloud(msg, "b").ring is None
    no_intensity = _cloud(msgs, rec, fields[:3], 1, n, 20 * n)  # x y z only (a depth camera's, a simulator's)
    assert not decode_cloud(no_intensity, "b").has_intensity
    short = _cloud(msgs, rec[:2], fields, 1, n, 20 * 2)  # width says 4 points, data holds 2
    with pytest.raises(InputError, match="do not hold 1 x 4 points"):
        decode_cloud(short, "b")


def _image(m: RosMessages, px: np.ndarray, enc: str, big: bool = False, pad: int = 4):
    h = px.shape[0]
    raw = px.reshape(h, -1).view(np.uint8) if px.dtype == np.uint8 else px.astype(">u2" if big else "<u2")
    raw = np.ascontiguousarray(raw.reshape(h, -1)).view(np.uint8).reshape(h, -1)
    data = np.hstack([raw, np.zeros((h, pad), np.uint8)])  # row padding: step > width * bytes
    return m.make("sensor_msgs/msg/Image", header=m.header(0, "camera"), height=h, width=px.shape[1],
                  encoding=enc, is_bigendian=int(big), step=data.shape[1], data=data.reshape(-1))  # fmt: skip


def test_image_encodings(msgs) -> None:
    rng = np.random.default_rng(1)
    bgr = rng.integers(0, 256, (6, 5, 3), dtype=np.uint8)
    alpha = np.full((6, 5, 1), 200, np.uint8)
    cases = {
        "bgr8": (bgr, bgr),
        "rgb8": (bgr[:, :, ::-1], bgr),
        "bgra8": (np.concatenate([bgr, alpha], 2), bgr),
        "rgba8": (np.concatenate([bgr[:, :, ::-1], alpha], 2), bgr),
        "mono8": (bgr[:, :, 0], np.repeat(bgr[:, :, :1], 3, 2)),
    }
    for enc, (px, want) in cases.items():
        np.testing.assert_array_equal(decode_image(_image(msgs, px, enc), "b:/img"), want, err_msg=enc)
    mono16 = rng.integers(0, 65536, (6, 5)).astype(np.uint16)
    want16 = np.repeat(np.round(mono16 / 257.0).astype(np.uint8)[:, :, None], 3, 2)
    for big in (False, True):
        np.testing.assert_array_equal(decode_image(_image(msgs, mono16, "mono16", big), "b"), want16)
    mono12 = (mono16 >> 4).astype(np.uint16)  # a 12-bit camera's mono16: its full scale is 4095
    mono12[0, 0] = 4095
    got = decode_image(_image(msgs, mono12, "mono16"), "b")[:, :, 0].astype(int)
    assert got[0, 0] == 255 and np.abs(got - np.round(mono12.astype(float) * 255 / 4095)).max() == 0
    with pytest.raises(InputError, match=r"b:/img: image encoding 'yuv422' is not supported"):
        decode_image(_image(msgs, bgr[:, :, :2], "yuv422"), "b:/img")


def test_compressed_images(msgs) -> None:
    bgr = np.random.default_rng(2).integers(0, 256, (8, 10, 3), dtype=np.uint8)
    for ext, fmt in ((".png", "bgr8; png compressed bgr8"), (".jpg", "jpeg")):
        data = np.frombuffer(cv2.imencode(ext, bgr)[1], np.uint8)
        msg = msgs.make("sensor_msgs/msg/CompressedImage", header=msgs.header(0, "c"), format=fmt, data=data)
        out = decode_image(msg, "b")
        assert out.shape == bgr.shape and out.dtype == np.uint8
        if ext == ".png":
            np.testing.assert_array_equal(out, bgr)
    bad = msgs.make("sensor_msgs/msg/CompressedImage", header=msgs.header(0, "c"), format="jpeg",
                    data=np.zeros(10, np.uint8))  # fmt: skip
    with pytest.raises(InputError, match="b: cannot decode the compressed image"):
        decode_image(bad, "b")


def _info(m: RosMessages, model: str, dist: list[float], K=None, P=None, w: int = 640, h: int = 480):
    K = np.array([[500.0, 0, 319.5], [0, 502.0, 239.5], [0, 0, 1]]) if K is None else np.asarray(K)
    P = np.hstack([K * 0.9 + np.diag([0, 0, 0.1]), np.zeros((3, 1))]) if P is None else np.asarray(P)
    roi = m.make("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0, width=0,
                 do_rectify=False)  # fmt: skip
    return m.make("sensor_msgs/msg/CameraInfo", header=m.header(0, "camera"), height=h, width=w,
                  distortion_model=model, d=np.array(dist, float), k=K.reshape(-1), r=np.eye(3).reshape(-1),
                  p=P.reshape(-1), binning_x=0, binning_y=0, roi=roi)  # fmt: skip


def test_camera_info_to_camera_models(msgs) -> None:
    plumb = parse_config(
        dict(BOARD, camera=camera_section(_info(msgs, "plumb_bob", [0.1, -0.02, 1e-3, 2e-3, 0.01]), "b"))
    )
    assert isinstance(plumb.camera, Pinhole) and (plumb.camera.width, plumb.camera.height) == (640, 480)
    np.testing.assert_array_equal(plumb.camera.dist, [0.1, -0.02, 1e-3, 2e-3, 0.01])
    assert plumb.camera.K[1, 1] == 502.0
    rational = camera_section(
        _info(msgs, "rational_polynomial", [0.1, 0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0]), "b"
    )
    assert len(parse_config(dict(BOARD, camera=rational)).camera.dist) == 8
    for model in ("equidistant", "fisheye"):
        fish = parse_config(
            dict(BOARD, camera=camera_section(_info(msgs, model, [0.02, -0.01, 0.003, -0.001]), "b"))
        )
        assert isinstance(fish.camera, Fisheye)
        np.testing.assert_array_equal(fish.camera.dist, [0.02, -0.01, 0.003, -0.001])
    rect = camera_section(_info(msgs, "plumb_bob", [0.1, 0.0, 0.0, 0.0, 0.0]), "b", rectified=True)
    assert rect["dist"] == [0.0] * 5 and rect["K"][0][0] == pytest.approx(450.0)
    with pytest.raises(InputError, match="b: CameraInfo distortion_model 'weird'"):
        camera_section(_info(msgs, "weird", []), "b")


def test_still_runs() -> None:
    t = np.arange(8) * 0.1
    changes = np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.9])  # step k: sample k -> k + 1
    assert still_runs(t, changes, 0.1) == [
        (0.0, pytest.approx(0.2)),
        (pytest.approx(0.3), pytest.approx(0.6)),
    ]
    assert still_runs(t, np.zeros(7), 0.1) == [(0.0, pytest.approx(0.7))]
    assert still_runs(t, np.ones(7), 0.1) == []
