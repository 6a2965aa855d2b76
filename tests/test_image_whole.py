"""Issue 38, boards partly outside the image: a detected grid is used only when it is the whole
pattern (``image/whole.py``); a part of a larger checker pattern is refused with the reason, never
used with its corners' indices shifted by a square."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.board import Board
from ilcc_graph.errors import CornersNotFound, PartialPattern
from ilcc_graph.image import ImageOptions, detect_corners, detectors
from ilcc_graph.simulate import SceneOptions, board_placements, simulate_frames, standard_spec
from ilcc_graph.simulate.spec import SimulationSpec
from ilcc_graph.simulate.write_set import simulate_dataset

CONFIG = Board(5, 8, 0.09, margin_long=0.05, margin_short=0.03)  # 5 + 8 odd: the order is exact
WIDER = Board(5, 9, 0.09, margin_long=0.05, margin_short=0.03)  # a column more


def _facing(spec: SimulationSpec, print_: Board, angle: float, dist: float = 2.0) -> np.ndarray:
    """T_lidar_board: the print ``dist`` m from the camera, ``angle`` rad to the right of its axis
    (pinhole, OpenCV axes), facing it, turned a little about all three axes."""
    from scipy.spatial.transform import Rotation

    d = np.array([np.sin(angle), 0.0, np.cos(angle)])
    x = np.cross([0.0, -1.0, 0.0], -d)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(-d, x), -d]) @ Rotation.from_rotvec([0.15, -0.2, 0.3]).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = dist * d - R @ print_.pattern_centre
    return np.linalg.inv(spec.T_cam_lidar) @ T


def _outline_u(spec: SimulationSpec, print_: Board, T: np.ndarray) -> tuple[float, float]:
    """(largest column of the print's pattern outline, its square's size) in image px."""
    w, h = print_.cols * print_.square_size, print_.rows * print_.square_size
    p = np.array([[0, 0, 0, 1], [w, 0, 0, 1], [w, h, 0, 1], [0, h, 0, 1]], dtype=float)
    uv = spec.camera.project((spec.T_cam_lidar @ T @ p.T)[:3].T)
    return float(uv[:, 0].max()), float(np.linalg.norm(uv[1] - uv[0]) / print_.cols)


def _at_edge(spec: SimulationSpec, print_: Board, squares: float) -> np.ndarray:
    """The pose whose pattern's outer edge lies ``squares`` squares beyond the image's right edge
    (negative: inside), by bisection on the angle."""
    lo, hi = 0.0, 1.2
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        u, sq = _outline_u(spec, print_, _facing(spec, print_, mid))
        lo, hi = (mid, hi) if u < spec.camera.width - 0.5 + squares * sq else (lo, mid)
    return _facing(spec, print_, lo)


def _truth(spec: SimulationSpec, T: np.ndarray, board: Board = CONFIG) -> np.ndarray:
    """(K, 2) image px of the inner corners of ``board`` at the pose T_lidar_board."""
    p = np.c_[board.corners_board(), np.ones(board.n_corners)]
    return spec.camera.project((spec.T_cam_lidar @ T @ p.T)[:3].T)


EDGES = (-2.0, -1.0, -0.5, -0.2, 0.2, 0.5, 0.8, 1.2)  # the pattern's edge against the image's, squares


@pytest.fixture(scope="module")
def sliding() -> dict[str, tuple[SimulationSpec, list]]:
    """The configured print and a wider one, slid out across the right edge of a 960 px pinhole."""
    out = {}
    for name, print_ in (("right", CONFIG), ("wider", WIDER)):
        base = standard_spec(camera="pinhole", width=960, frames=1, board=print_)
        poses = tuple(_at_edge(base, print_, k) for k in EDGES)
        spec = dataclasses.replace(base, placements=poses, scene=SceneOptions(clutter=False))
        out[name] = (spec, list(simulate_frames(spec)))
    return out


def _detect(spec: SimulationSpec, image: np.ndarray) -> object:
    try:
        return detect_corners(image, spec.camera, CONFIG, ImageOptions())
    except CornersNotFound as err:
        return err


def test_a_board_leaving_the_image_is_refused_or_indexed_right(sliding):
    """Used, with its true corners, while the pattern is in the picture (its outermost corner 0.2
    square inside the edge); refused with the reason once it reaches out of it, never used with
    other corners."""
    spec, frames = sliding["right"]
    results = [_detect(spec, f.image) for f in frames]
    for k, f, r in zip(EDGES, frames, results, strict=True):
        if k < 0:
            assert not isinstance(r, CornersNotFound), (k, str(r))
            err = np.linalg.norm(r.uv - _truth(spec, f.T_lidar_board), axis=1).max()
            assert err < 0.5, (k, err)
        else:
            assert isinstance(r, PartialPattern), (k, r)
            assert str(r).startswith("the detected grid is not provably the whole pattern: ")
    said = [str(r) for r in results if isinstance(r, PartialPattern)]
    assert any("the image ends within a square of the pattern's edge" in r for r in said), said
    assert any("run out of the image" in r for r in said), said


def test_a_part_of_a_wider_print_is_never_used(sliding, monkeypatch):
    """A detector made to return either part of the configured size of a print with a column more
    (its true corners, or those shifted by a square), the print whole in the picture or leaving it:
    none is used. Seen whole, the pattern goes on beyond the part; leaving the picture, the rule
    that refuses it is the one that sees first (the pattern going on where the turned print's
    last column is still in the picture, else the squares that would tell being outside it)."""
    spec, frames = sliding["wider"]
    part: list[np.ndarray | None] = [None]

    def parts(gray: np.ndarray, board: Board) -> np.ndarray | None:  # the full image only
        return part[0] if gray.shape == (spec.camera.height, spec.camera.width) else None

    monkeypatch.setitem(detectors.DETECTORS, "sb", parts)
    options = ImageOptions(quick=(("sb", spec.camera.width),), cascade=("sb",), tile_views=False)
    said: dict[tuple[float, int], str] = {}
    for k, f in zip(EDGES, frames, strict=True):
        true = _truth(spec, f.T_lidar_board, WIDER).reshape(*WIDER.inner_shape, 2)
        for b in (0, 1):
            grid = true[:, b : b + CONFIG.cols - 1].reshape(-1, 2)
            if not np.all(spec.camera.in_image(grid)):
                continue  # no detector returns corners outside the picture
            part[0] = grid.copy()
            with pytest.raises(CornersNotFound) as err:
                detect_corners(f.image, spec.camera, CONFIG, options)
            said[(k, b)] = f"{type(err.value).__name__}: {err.value}"
    inside = [r for (k, _), r in said.items() if k < 0]
    assert len(inside) == 2 * sum(k < 0 for k in EDGES), said  # both parts tried where all is seen
    continues = "PartialPattern: the detected grid is not the whole pattern: the pattern continues beyond"
    assert all(r.startswith(continues) and "board.squares [5, 8]" in r for r in inside), inside
    leaving = [r for (k, _), r in said.items() if k > 0]
    assert len(leaving) >= 4 and all(r.startswith("PartialPattern: the detected grid is") for r in leaving)


@pytest.mark.parametrize(
    ("camera", "width", "frames"),
    [("pinhole", 960, [0, 1, 2]), ("fisheye", 1280, [1, 2]), ("equirectangular", 2000, [0, 2])],
)
def test_a_larger_print_is_refused_and_its_own_config_finds_it(camera, width, frames):
    """Images of a [7, 9] print read with the paper's [6, 8] board, in which a detector finds a part
    of it (before issue 38 six of these seven were used as the configured board, one refused as a
    colour mismatch with the wrong advice): refused, the reason names the rule, its figures and the
    config's size; with [7, 9] the same images give the true corners."""
    true = Board(7, 9, 0.075)
    spec = standard_spec(camera=camera, width=width, frames=4, seed=3, board=true)
    for f in simulate_frames(spec, frames):
        with pytest.raises(PartialPattern) as err:
            detect_corners(f.image, spec.camera, Board(6, 8, 0.075), ImageOptions())
        said = str(err.value)
        assert "the detected grid is not the whole pattern: the pattern continues beyond its" in said
        assert "points; a larger print than board.squares [6, 8]?" in said
        res = detect_corners(f.image, spec.camera, true, ImageOptions())
        ref = _truth(spec, f.T_lidar_board, true)
        d = [res.uv - r for r in (ref, ref[true.half_turn_permutation()])]
        for e in d:
            e[:, 0] = spec.camera.wrap_du(e[:, 0])
        assert min(np.linalg.norm(e, axis=1).max() for e in d) < 0.6
        assert res.diagnostics["alternating_beyond"] == 0.0 and res.diagnostics["border_matching"] == 1.0


# ---------------------------------------------------------------------------------- the CLI
def _calibrate(data, out) -> int:
    return main(["calibrate", str(data), "--out", str(out), "--no-report", "--jobs", "1"])


def test_calibrate_skips_a_board_partly_out_of_the_image_with_its_reason(tmp_path, capsys):
    """Five frames and one whose board's border squares leave the picture: the run uses the five,
    the sixth is skipped at the image stage with the reason."""
    base = standard_spec(camera="pinhole", width=960, frames=5, seed=1, board=CONFIG)
    poses = (*board_placements(base), _at_edge(base, CONFIG, 0.2))
    simulate_dataset(tmp_path / "data", dataclasses.replace(base, placements=poses))
    assert _calibrate(tmp_path / "data", tmp_path / "out") == 0
    capsys.readouterr()
    written = yaml.safe_load((tmp_path / "out" / "calibration.yaml").read_text())
    frames = {f["name"]: f for f in written["frames"]}
    assert all(frames[n]["used"] for n in ("0001", "0002", "0003", "0004", "0005")), frames
    last = frames["0006"]
    assert not last["used"] and "image: the detected grid is not provably the whole pattern" in last["reason"]


def test_calibrate_refuses_every_frame_of_a_larger_print(tmp_path, capsys):
    """A [6, 8] print configured as [5, 7]: no frame is used (each refused at the image stage with
    the rule's reason), the run ends saying board.squares is wrong."""
    data = tmp_path / "data"
    argv = ["simulate", str(data), "--camera", "pinhole", "--width", "640", "--frames", "6", "--seed", "1"]
    assert main(argv) == 0
    cfg = yaml.safe_load((data / "config.yaml").read_text())
    cfg["board"]["squares"] = [5, 7]
    (data / "config.yaml").write_text(yaml.safe_dump(cfg))
    assert _calibrate(data, tmp_path / "out") == 3
    err = capsys.readouterr().err
    assert "board.squares [5, 7] looks wrong" in err, err
    failed = yaml.safe_load((tmp_path / "out" / "failure.yaml").read_text())
    image = {f["frame"]: f["reason"] for f in failed["frames"] if f["stage"] == "image"}
    assert sorted(image) == ["0001", "0002", "0003", "0004", "0005", "0006"], failed
    assert all(
        "the detected grid is not the whole pattern: the pattern continues beyond its" in r
        and "a larger print than board.squares [5, 7]?" in r
        for r in image.values()
    ), image
