"""config.yaml: our schema, ILCC's schema, validation messages, Roi, round trip."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcc_graph.board import Board
from ilcc_graph.config import Config, Roi, config_to_dict, load_config, parse_config
from ilcc_graph.errors import InputError
from ilcc_graph.lidars import lidar_model

OURS_PANO = """
board:
  squares: [6, 8]
  square_size: 0.075
  margin: 0.0
  lower_left: white
lidar:
  model: hdl32
  intensity_column: 6
camera:
  model: equirectangular
  width: 8000
  height: 4000
"""

# mfxox/ILCC's config.yaml layout: quoted keys, tuples written as strings
ILCC_PANO = """
'base_dir': ""
'image_res': (4000,8000) #image resolution for panoramic image only
'backend': 'matlab'
'output_img_with_dectected_corners': True
'back_proj_corners': True
'camera_type': 'panoramic'
'file_name_digits': 4
'LiDAR_type': 'hdl32'
'laser_beams_num': 32
'jdc_thre_ratio': 5
'agglomerative_cluster_th_ratio': 5
'pattern_size': (6,8)
'grid_length': 0.075
'chessboard_detect_planar_PCA_ratio': 0.01
'marker_range_limit': 5
'start_pattern_corner': 1
'intensity_col_ind': 6
'multi_proc': True
'proc_num': 4
'poses_num': 20
"""


def _write(tmp_path: Path, text: str, name: str = "config.yaml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def _same(a: Config, b: Config) -> None:
    assert a.board == b.board
    assert a.lidar == b.lidar
    assert a.camera == b.camera
    assert a.roi == b.roi
    assert a.intensity_column == b.intensity_column


def test_ilcc_and_ours_give_the_same_objects(tmp_path: Path) -> None:
    ours = load_config(_write(tmp_path, OURS_PANO, "ours.yaml"))
    ilcc = load_config(_write(tmp_path, ILCC_PANO, "ilcc.yaml"))
    _same(ours, ilcc)
    assert ilcc.schema == "ILCC" and ours.schema == "ilcc_graph"
    assert ours.board == Board(6, 8, 0.075, 0.0, 0.0, "white")
    assert ours.lidar == lidar_model("hdl32")
    assert ours.camera.kind == "equirectangular" and (ours.camera.width, ours.camera.height) == (8000, 4000)
    assert ours.roi is None


def test_ilcc_perspective_reads_image_size(tmp_path: Path) -> None:
    import cv2

    (tmp_path / "img").mkdir()
    cv2.imwrite(str(tmp_path / "img" / "0001.png"), np.zeros((480, 640, 3), np.uint8))
    text = """
    'camera_type': 'perspective'
    'instrinsic_para': (500., 0., 320.,  0., 510., 240.,   0., 0., 1.)
    'LiDAR_type': 'vlp16_puck'
    'pattern_size': (5,7)
    'grid_length': 0.1
    'image_res': (4000,8000)
    """
    ilcc = load_config(_write(tmp_path, text))
    ours = parse_config(
        {
            "board": {"squares": [5, 7], "square_size": 0.1},
            "lidar": {"model": "vlp16"},
            "camera": {
                "model": "pinhole",
                "width": 640,
                "height": 480,
                "K": [[500.0, 0, 320], [0, 510, 240], [0, 0, 1]],
                "dist": [0, 0, 0, 0, 0],
            },
        }
    )
    _same(ours, ilcc)


def test_ilcc_without_lidar_type_uses_beam_count(tmp_path: Path) -> None:
    text = "'image_res': (1000,2000)\n'pattern_size': (6,8)\n'grid_length': 0.075\n'laser_beams_num': 64\n"
    cfg = load_config(_write(tmp_path, text))
    assert cfg.lidar.name == "hdl64" and cfg.board.lower_left == "black"


def test_recorded_config_loads(acfr_data: Path) -> None:
    cfg = load_config(acfr_data / "config.yaml")
    assert cfg.board == Board(6, 8, 0.095, 0.045, 0.020, "white")
    assert cfg.lidar.name == "vlp16" and cfg.lidar.n_beams == 16
    assert cfg.camera.kind == "fisheye" and (cfg.camera.width, cfg.camera.height) == (1920, 1208)
    assert cfg.roi is None


def test_config_to_dict_round_trip(tmp_path: Path) -> None:
    text = OURS_PANO.replace("margin: 0.0", "margin: [0.045, 0.02]").replace(
        "lower_left: white", "lower_left: white\n  roi: {azimuth_deg: [170, -170], elevation_deg: [-20, 5]}"
    )
    cfg = load_config(_write(tmp_path, text))
    d = config_to_dict(cfg)
    assert d["board"]["margin"] == [0.045, 0.02]
    assert d["board"]["roi"] == {"azimuth_deg": [170.0, -170.0], "elevation_deg": [-20.0, 5.0]}
    again = load_config(_write(tmp_path, yaml.safe_dump(d), "again.yaml"))
    _same(cfg, again)
    generic = parse_config(
        {
            "board": {"squares": [4, 4], "square_size": 0.2},
            "lidar": {
                "model": "generic",
                "vertical_angles_deg": [-2.0, 0.0, 2.0],
                "horizontal_resolution_deg": 0.1,
                "range_sigma_m": 0.01,
            },
            "camera": {
                "model": "pinhole",
                "width": 100,
                "height": 80,
                "K": [[90, 0, 50], [0, 90, 40], [0, 0, 1]],
                "dist": [0.1, 0.0, 0.0, 0.0],
            },
        }
    )
    _same(generic, parse_config(yaml.safe_load(yaml.safe_dump(config_to_dict(generic)))))
    assert generic.lidar.range_sigma_m == 0.01


def test_roi_contains_with_wrap() -> None:
    az = np.deg2rad(np.array([175.0, -175.0, 0.0, 160.0]))
    p = np.stack([np.cos(az) * 3, np.sin(az) * 3, np.zeros(4)], axis=1)
    np.testing.assert_array_equal(Roi(azimuth_deg=(170.0, -170.0)).contains(p), [True, True, False, False])
    np.testing.assert_array_equal(Roi(azimuth_deg=(-10.0, 170.0)).contains(p), [False, False, True, True])
    q = np.array([[1.0, 0, 0.5], [10.0, 0, 0.0], [1.0, 0.0, -2.0]])
    np.testing.assert_array_equal(
        Roi(elevation_deg=(-30.0, 30.0), range_m=(0.0, 5.0)).contains(q), [True, False, False]
    )
    assert Roi().contains(q).all()


BAD = [
    # (replace this, with that, words the message must contain)
    ("squares: [6, 8]", "squares: [6]", ["board.squares", "[6]", "[rows, cols]"]),
    ("squares: [6, 8]", "squares: [8, 6]", ["board.squares", "[8, 6]", "rows <= cols"]),
    ("squares: [6, 8]", "squares: [6, 8.5]", ["board.squares[1]", "8.5", "integer"]),
    ("square_size: 0.075", "square_size: -0.075", ["board.square_size", "-0.075", "number in (0.0, 1.0]"]),
    ("square_size: 0.075", "square_size: '7.5cm'", ["board.square_size", "'7.5cm'", "number"]),
    ("margin: 0.0", "margin: [0.1, 0.2, 0.3]", ["board.margin", "[0.1, 0.2, 0.3]", "list of 2 numbers"]),
    ("lower_left: white", "lower_left: red", ["board.lower_left", "'red'", "black", "white"]),
    ("lower_left: white", "lower_left: white\n  colour: red", ["board.colour", "'red'", "no such key"]),
    (
        "lower_left: white",
        "lower_left: white\n  roi: {range_m: [5.0, 1.0]}",
        ["board.roi.range_m", "[5.0, 1.0]", "min < max"],
    ),
    (
        "lower_left: white",
        "lower_left: white\n  roi: {azimuth_deg: [10, 10]}",
        ["board.roi.azimuth_deg", "[10, 10]", "min < max"],
    ),
    (
        "lower_left: white",
        "lower_left: white\n  roi: {azimuth_deg: [0, 200]}",
        ["board.roi.azimuth_deg[1]", "200", "-180"],
    ),
    ("lower_left: white", "lower_left: white\n  roi: {height: [0, 1]}", ["board.roi.height", "no such key"]),
    ("model: hdl32", "model: hdl16", ["lidar.model", "'hdl16'", "vlp16"]),
    ("model: hdl32", "model: generic", ["lidar.vertical_angles_deg", "missing", "generic"]),
    ("intensity_column: 6", "intensity_column: 1", ["lidar.intensity_column", "1", ">= 3"]),
    ("width: 8000", "width: 7000", ["camera.width", "7000", "2 * height"]),
    ("height: 4000", "height: -4", ["camera.height", "-4", "integer"]),
    ("model: equirectangular", "model: fisheye\n  K: [[1, 0], [0, 1]]", ["camera.K", "3x3"]),
    (
        "model: equirectangular",
        "model: pinhole\n  K: [[500, 0, 4000], [0, 500, 2000], [0, 0, 1]]\n  dist: [0, 0, 0]",
        ["camera.dist", "[0, 0, 0]", "4 or 5 or 8"],
    ),
    (
        "model: equirectangular",
        "model: fisheye\n  K: [[500, 0, 4000], [0, 500, 2000], [0, 0, 1]]\n  dist: [0, 0, 0, 0, 0]",
        ["camera.dist", "list of 4 numbers"],
    ),
    (
        "model: equirectangular",
        "model: pinhole\n  K: [[-5, 0, 1], [0, 5, 1], [0, 0, 1]]",
        ["camera.K", "fx, fy > 0"],
    ),
    ("model: equirectangular", "model: sphere", ["camera.model", "'sphere'", "pinhole"]),
    ("camera:", "kamera:", ["kamera", "no such key"]),
]


@pytest.mark.parametrize("old, new, words", BAD)
def test_config_errors_name_file_key_value_and_expectation(
    tmp_path: Path, old: str, new: str, words: list
) -> None:
    assert old in OURS_PANO
    p = _write(tmp_path, OURS_PANO.replace(old, new, 1), "my_config.yaml")
    with pytest.raises(InputError) as e:
        load_config(p)
    msg = str(e.value)
    assert str(p) in msg
    for w in words:
        assert w in msg, msg


def test_missing_section_and_file_level_errors(tmp_path: Path) -> None:
    no_cam = OURS_PANO[: OURS_PANO.index("camera:")]
    with pytest.raises(InputError, match=r"camera = missing: expected a mapping"):
        load_config(_write(tmp_path, no_cam))
    with pytest.raises(InputError, match="not valid YAML"):
        load_config(_write(tmp_path, "board: [1, 2\n", "broken.yaml"))
    with pytest.raises(InputError, match="empty"):
        load_config(_write(tmp_path, "", "empty.yaml"))
    with pytest.raises(InputError, match="not found"):
        load_config(tmp_path / "nope.yaml")


@pytest.mark.parametrize(
    "old, new, words",
    [
        ("'pattern_size': (6,8)", "'pattern_size': (6,8,2)", ["pattern_size", "[rows, cols]"]),
        ("'pattern_size': (6,8)", "'pattern_size': 'six'", ["pattern_size", "tuple"]),
        ("'grid_length': 0.075", "'grid_length': 0", ["grid_length", "0"]),
        ("'LiDAR_type': 'hdl32'", "'LiDAR_type': 'ouster'", ["LiDAR_type", "'ouster'", "vlp16_puck"]),
        ("'camera_type': 'panoramic'", "'camera_type': 'fish'", ["camera_type", "'fish'", "perspective"]),
        ("'image_res': (4000,8000)", "'image_res': (4000,4000)", ["image_res", "width = 2 * height"]),
        ("'start_pattern_corner': 1", "'start_pattern_corner': 2", ["start_pattern_corner", "0 (black)"]),
        ("'proc_num': 4", "'proc_num': 4\n'mystery': 1", ["mystery", "no such key"]),
        ("'LiDAR_type': 'hdl32'", "'LiDAR_type': 'hdl32'\nboard: {}", ["board", "not both"]),
    ],
)
def test_ilcc_config_errors(tmp_path: Path, old: str, new: str, words: list) -> None:
    assert old in ILCC_PANO
    p = _write(tmp_path, ILCC_PANO.replace(old, new), "ilcc.yaml")
    with pytest.raises(InputError) as e:
        load_config(p)
    msg = str(e.value)
    assert str(p) in msg
    for w in words:
        assert w in msg, msg


@pytest.mark.parametrize(
    "written, name",
    [("VLP-16", "vlp16"), ("Velodyne VLP-16", "vlp16"), ("velodyne_puck", "vlp16"), ("HDL-32E", "hdl32"),
     ("hdl64e", "hdl64"), ("VLP-32C", "vlp32c"), ("Ouster OS1-64", "os1-64"), ("os1_64_gen2", "os1-64-gen2"),
     ("Hesai Pandar XT-32", "pandar-xt32"), ("Pandar40P", "pandar40p"), ("Livox Mid-70", "livox-mid70")],
)  # fmt: skip
def test_lidar_model_as_users_and_data_sheets_write_it(written: str, name: str) -> None:
    d = {"board": {"squares": [6, 8], "square_size": 0.1}, "lidar": {"model": written},
         "camera": {"model": "equirectangular", "width": 2000, "height": 1000}}  # fmt: skip
    assert parse_config(d).lidar.name == name


def test_lidar_model_of_several_revisions_takes_the_newest_and_says_so(
    caplog: pytest.LogCaptureFixture,
) -> None:
    d = {"board": {"squares": [6, 8], "square_size": 0.1}, "lidar": {"model": "OS1-128"},
         "camera": {"model": "equirectangular", "width": 2000, "height": 1000}}  # fmt: skip
    assert parse_config(d, "c.yaml").lidar.name == "os1-128-rev6"
    assert "c.yaml: lidar.model 'OS1-128' read as os1-128-rev6 (also os1-128-gen2)" in caplog.text
    d["lidar"]["model"] = "VLP-17"
    with pytest.raises(InputError, match=r"c\.yaml: lidar\.model = 'VLP-17': expected one of \['hdl32'"):
        parse_config(d, "c.yaml")


@pytest.mark.parametrize(
    "written, kind",
    [("Pinhole", "pinhole"), ("OpenCV", "pinhole"), ("plumb_bob", "pinhole"), ("radtan", "pinhole"),
     ("kannala-brandt", "fisheye"), ("equidistant", "fisheye"), ("Double Sphere", "double_sphere"),
     ("ds", "double_sphere"), ("omni", "unified"), ("Mei", "unified")],
)  # fmt: skip
def test_camera_model_by_the_names_tools_give_it(written: str, kind: str) -> None:
    cam = {"model": written, "width": 640, "height": 480, "K": [[300, 0, 320], [0, 300, 240], [0, 0, 1]]}
    cam |= {"pinhole": {}, "fisheye": {"dist": [0, 0, 0, 0]}, "double_sphere": {"xi": -0.2, "alpha": 0.6},
            "unified": {"xi": 0.9}}[kind]  # fmt: skip
    d = {"board": {"squares": [6, 8], "square_size": 0.1}, "camera": cam}
    assert parse_config(d).camera.kind == kind


def test_panorama_by_its_common_names_and_an_unknown_name_refused() -> None:
    d = {"board": {"squares": [6, 8], "square_size": 0.1}, "camera": {"width": 2000, "height": 1000}}
    for written in ("Panorama", "spherical", "equirect", "360"):
        d["camera"]["model"] = written
        assert parse_config(d).camera.kind == "equirectangular"
    d["camera"]["model"] = "cylindrical"
    with pytest.raises(InputError, match=r"camera\.model = 'cylindrical': expected one of .*\(panorama, "):
        parse_config(d, "c.yaml")
