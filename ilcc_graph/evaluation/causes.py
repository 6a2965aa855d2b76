"""Likely causes of a frame the estimation dropped, in words a person reads.

The gate says *that* a board disagrees with the rest; this says *where*: its image corners are
fitted alone as a flat board under the lens model (bearing angles, camera frame), and that board is
compared with the one the LiDAR saw, carried into the camera by the extrinsic.

- The image alone fits a flat board clearly worse than the used frames' images do: blur, a lens
  model that does not fit there (near the image edge: try ``--refine-intrinsics``), or a curled
  print.
- The image fits, but its board sits elsewhere than the LiDAR's: the board moved between the scan
  and the photo (sensors not synchronised), or the LiDAR's fit is off (its metric picture shows it).

``residual_causes``: what explains residuals far above the detectors' stated noise over all frames
(more poses do not mend them), in the order a user checks: boards cut off by the image's border, a
board size the print does not have, intrinsics or a lens model that do not fit the images, boards
placed by an outline whose margin may not be the configured one, boards that moved between the
scan and the photo (synchronisation).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.init.upnp import upnp
from ilcc_graph.types import FrameResult, ImageCorners

__all__ = [
    "SCALE_TOL",
    "ImageAlone",
    "board_scale",
    "camera_section",
    "causes_without_extrinsic",
    "dropped_frame_cause",
    "fit_image_alone",
    "image_fit_ratios",
    "moved_boards",
    "residual_causes",
    "stated_noise_mrad",
]

#: an image fits a flat board "clearly worse" above this multiple of the used frames' median
OWN_FIT_RATIO = 2.0
#: corners beyond this fraction of the half-diagonal from the image centre are "near the edge"
EDGE_RADIUS = 0.75
#: a corner within this many pixels of the image's border: the board may be cut off there
BORDER_PX = 3.0
#: an image whose corners fit a flat board alone at this multiple of their stated noise (RMS) or more
#: does not fit the camera model (intrinsics, lens model, blur, a curled print)
LENS_RATIO = 2.0
#: a board whose image puts it this many of the LiDAR pose's stated sigmas (and at least
#: ``MOVED_MIN_MM``) from where the scan saw it, through the one extrinsic, moved between them
MOVED_SIGMAS = 5.0
MOVED_MIN_MM = 10.0
#: the LiDAR's ranges are named when this share of the frames shows a gap along the rays of at least
#: ``RANGE_MIN_MM``, all to one side
RANGE_SHARE = 0.75
RANGE_MIN_MM = 10.0
#: the board's size is named only from this many pairs of frames (a moved board spoils its pairs)
SCALE_PAIRS = 6
#: ``board_scale`` within this of 1 is normal (the recorded sets: 1.003, 1.006)
SCALE_TOL = 0.03


@dataclass(frozen=True)
class ImageAlone:
    """The board fitted to one image's corners alone.

    corners_cam: (K, 3) the fitted board's corners in the camera frame (m), index as the board's.
    rms_mrad: RMS angle between the measured bearings and the fitted corners' directions.
    """

    corners_cam: np.ndarray
    rms_mrad: float


def fit_image_alone(bearings: np.ndarray, corners_board: np.ndarray) -> ImageAlone:
    """Least-squares board pose from unit bearings (K, 3) of the board's corners (K, 3, board frame)."""
    T0 = upnp(corners_board, bearings, prefer_front=True, tie_rtol=np.inf)[0].T_cam_points
    x0 = np.concatenate([Rotation.from_matrix(T0[:3, :3]).as_rotvec(), T0[:3, 3]])

    def residual(x: np.ndarray) -> np.ndarray:
        p = corners_board @ Rotation.from_rotvec(x[:3]).as_matrix().T + x[3:]
        return np.cross(bearings, p / np.linalg.norm(p, axis=1, keepdims=True)).ravel()

    x = least_squares(residual, x0, method="lm").x
    p = corners_board @ Rotation.from_rotvec(x[:3]).as_matrix().T + x[3:]
    d = p / np.linalg.norm(p, axis=1, keepdims=True)
    angles = np.arctan2(np.linalg.norm(np.cross(bearings, d), axis=1), np.sum(bearings * d, axis=1))
    return ImageAlone(p, float(1e3 * np.sqrt(np.mean(angles**2))))


def _edge_fraction(camera: CameraModel, uv: np.ndarray) -> float:
    """Largest distance of the corners from the image centre, as a fraction of the half-diagonal."""
    centre = np.array([camera.width / 2.0, camera.height / 2.0])
    return float(np.max(np.linalg.norm(uv - centre, axis=1)) / np.hypot(*centre))


def dropped_frame_cause(
    frame: FrameResult, board: Board, camera: CameraModel, T_cam_lidar: np.ndarray, typical_mrad: float
) -> str:
    """One sentence on the likely cause of a dropped frame, or "" when its stages' results are missing.

    typical_mrad: the median ``fit_image_alone`` rms of the used frames' images.
    """
    if frame.board is None or frame.corners is None:
        return ""
    alone = fit_image_alone(frame.corners.bearings, board.corners_board())
    lidar = frame.board.corners_lidar @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]
    # order-free (the half turn): each image-fit corner to the nearest LiDAR corner
    gap = np.linalg.norm(alone.corners_cam[:, None, :] - lidar[None, :, :], axis=2).min(axis=1)
    gap_mm = float(1e3 * np.sqrt(np.mean(gap**2)))
    edge = _edge_fraction(camera, frame.corners.uv)
    if alone.rms_mrad > OWN_FIT_RATIO * typical_mrad:
        where = (
            f"near the image edge ({edge:.0%} of the half-diagonal), where the lens model fits worst: "
            "--refine-intrinsics may keep it"
            if edge > EDGE_RADIUS
            else "blur, a curled print, or a lens model that does not fit there"
        )
        return (
            f"likely cause: the image corners fit a flat board worse than the used frames' do "
            f"(alone: rms {alone.rms_mrad:.3f} mrad, used frames' median {typical_mrad:.3f}): {where}"
        )
    return (
        f"likely cause: the image alone fits a flat board as well as the used frames' do (rms "
        f"{alone.rms_mrad:.3f} mrad, median {typical_mrad:.3f}) but it sits "
        f"{gap_mm:.0f} mm (corner rms) from where the LiDAR saw it: the board moved between the scan and "
        "the photo (sensors not synchronised), or the LiDAR's pattern fit is off (see its metric picture)"
    )


def stated_noise_mrad(corners: ImageCorners, camera: CameraModel) -> float:
    """RMS over the corners of the image stage's stated 1-sigma (``cov_px``) as an angle (mrad)."""
    uv = np.asarray(corners.uv, dtype=np.float64)
    a, b = camera.bearing(uv), camera.bearing(uv + np.array([1.0, 0.0]))
    per_px = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))
    sigma_px = np.sqrt(0.5 * np.trace(np.asarray(corners.cov_px), axis1=1, axis2=2))
    return float(1e3 * np.sqrt(np.nanmean((sigma_px * per_px) ** 2)))


def _names(names: list[str], most: int = 6) -> str:
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most else "")


def _partial(seen: list[FrameResult], camera: CameraModel) -> str | None:
    """Boards whose corners reach the image's border (the detector may have found part of the
    pattern). Boards partly beyond the LiDAR's top or bottom beam are not named: the LiDAR stage
    fits them as such (``lidar.outline``)."""
    size = np.array([camera.width - 1.0, camera.height - 1.0])
    edge = [
        f.name
        for f in seen
        if np.any(np.minimum(f.corners.uv, size - f.corners.uv) < BORDER_PX)  # type: ignore[union-attr]
    ]
    if not edge:
        return None
    return (
        f"partial boards ({_names(edge)} reach the image's border): a board cut off may be placed from "
        "the part that shows; leave such frames out or capture the whole board"
    )


def _image_fits(
    seen: list[FrameResult], board: Board, camera: CameraModel
) -> dict[str, tuple[ImageAlone, float]]:
    """Per frame its image fitted alone and that fit's RMS over the stated corner noise."""
    corners = board.corners_board()
    fits = {}
    for f in seen:
        alone = fit_image_alone(f.corners.bearings, corners)  # type: ignore[union-attr]
        fits[f.name] = (alone, alone.rms_mrad / max(stated_noise_mrad(f.corners, camera), 1e-9))  # type: ignore[arg-type]
    return fits


def image_fit_ratios(frames: Sequence[FrameResult], board: Board, camera: CameraModel) -> dict[str, float]:
    """Per frame with image corners the RMS of its image fitted alone (a flat board, the camera as
    stated) over its stated corner noise."""
    seen = [f for f in frames if f.corners is not None]
    return {n: ratio for n, (_, ratio) in _image_fits(seen, board, camera).items()}


def moved_boards(
    frames: list[FrameResult], board: Board, camera: CameraModel, T_cam_lidar: np.ndarray,
    consensus: bool = False,
) -> list[tuple[str, float, float]]:  # fmt: skip
    """(frame, gap mm, gap in the LiDAR pose's stated sigmas) of the frames whose image fits a flat
    board alone as its stated noise says but puts it ``MOVED_SIGMAS`` x the LiDAR fit's stated sigma
    (and ``MOVED_MIN_MM``) or more from where the scan saw it, through ``T_cam_lidar``; with
    ``consensus`` also through the extrinsic most of the frames agree on (``_consensus``, from
    ``T_cam_lidar``: boards that moved before the photo pull the solve's extrinsic towards them until
    no one of them lies far from its scan under it), each frame once with its larger gap."""
    seen = [f for f in frames if f.board is not None and f.corners is not None]
    fits = _image_fits(seen, board, camera)
    found = _moved(seen, board, T_cam_lidar, fits)
    if consensus:
        found += _moved(seen, board, _consensus(seen, fits, T_cam_lidar), fits)
    larger: dict[str, tuple[str, float, float]] = {}
    for m in found:
        if m[0] not in larger or m[2] > larger[m[0]][2]:
            larger[m[0]] = m
    return list(larger.values())


def _consensus(seen: list[FrameResult], fits: dict, T0: np.ndarray, rounds: int = 30) -> np.ndarray:
    """(4, 4) the rigid map of the boards' LiDAR corners onto their images' corners (each image fitted
    alone; a corner paired with the nearest) that most frames agree on: each frame weighted by a
    Cauchy weight of its RMS gap (scale: the frames' median gap), iterated from ``T0``."""
    pairs = [
        (f.board.corners_lidar, fits[f.name][0].corners_cam)  # type: ignore[union-attr]
        for f in seen
        if fits[f.name][1] <= LENS_RATIO
    ]
    if len(pairs) < 3:
        return T0
    T = np.array(T0, dtype=np.float64)
    for _ in range(rounds):
        src, dst, gaps = [], [], []
        for lidar, cam in pairs:
            p = lidar @ T[:3, :3].T + T[:3, 3]
            j = np.argmin(np.linalg.norm(p[:, None, :] - cam[None, :, :], axis=2), axis=1)
            gaps.append(float(np.sqrt(np.mean(np.sum((p - cam[j]) ** 2, axis=1)))))
            src.append(lidar)
            dst.append(cam[j])
        scale = max(float(np.median(gaps)), 1e-3)
        weights = [np.full(len(x), 1.0 / (1.0 + (g / scale) ** 2)) for x, g in zip(src, gaps, strict=True)]
        w = np.concatenate(weights)
        a, b = np.concatenate(src), np.concatenate(dst)
        ca, cb = w @ a / w.sum(), w @ b / w.sum()
        R = Rotation.align_vectors(b - cb, a - ca, weights=w)[0].as_matrix()  # weighted Kabsch
        new = np.eye(4)
        new[:3, :3], new[:3, 3] = R, cb - R @ ca
        done = np.abs(new - T).max() < 1e-9
        T = new
        if done:
            break
    return T


def _moved(
    seen: list[FrameResult], board: Board, T_cam_lidar: np.ndarray, fits: dict
) -> list[tuple[str, float, float]]:
    """(frame, gap mm, gap in the LiDAR pose's stated sigmas) of the boards whose image fits alone
    but sits far from where the scan saw them, through ``T_cam_lidar``."""
    radius = 0.5 * float(np.linalg.norm(np.ptp(board.corners_board(), axis=0)))
    out = []
    for f in seen:
        alone, ratio = fits[f.name]
        if ratio > LENS_RATIO:
            continue
        lidar = f.board.corners_lidar @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]  # type: ignore[union-attr]
        gap = np.linalg.norm(alone.corners_cam[:, None, :] - lidar[None, :, :], axis=2).min(axis=1)
        gap_mm = float(1e3 * np.sqrt(np.mean(gap**2)))
        C = np.asarray(f.board.covariance)  # type: ignore[union-attr]
        sigma_mm = 1e3 * float(np.sqrt(max(np.trace(C[3:, 3:]) + radius**2 * np.trace(C[:3, :3]), 1e-12)))
        if gap_mm > max(MOVED_MIN_MM, MOVED_SIGMAS * sigma_mm):
            out.append((f.name, gap_mm, gap_mm / sigma_mm))
    return out


def _range_offset(seen: list[FrameResult], T_cam_lidar: np.ndarray, fits: dict) -> str | None:
    """The LiDAR's ranges as the cause, or None: in most frames (``RANGE_SHARE``) the board's centre
    as the scan saw it sits ``RANGE_MIN_MM`` or more from where the image alone puts it, along the
    LiDAR's ray to it (at least twice the gap across the ray), all to one side."""
    T_lc = np.linalg.inv(T_cam_lidar)
    along = []
    for f in seen:
        alone, ratio = fits[f.name]
        if ratio > LENS_RATIO or f.board is None:
            continue
        c_img = T_lc[:3, :3] @ alone.corners_cam.mean(axis=0) + T_lc[:3, 3]
        d = f.board.corners_lidar.mean(axis=0) - c_img
        u = c_img / np.linalg.norm(c_img)
        a = float(d @ u)
        along.append(a if abs(a) >= 2.0 * float(np.linalg.norm(d - a * u)) else 0.0)
    a_mm = 1e3 * np.asarray(along)
    for sign, word in ((1.0, "beyond"), (-1.0, "short of")):
        hits = a_mm[sign * a_mm >= RANGE_MIN_MM]
        if len(a_mm) >= 3 and len(hits) >= RANGE_SHARE * len(a_mm):
            return (
                f"the LiDAR's ranges: in {len(hits)} of {len(a_mm)} frames the scan puts the board a median "
                f"{np.median(np.abs(hits)):.0f} mm {word} where the image does, along the LiDAR's ray to it: "
                "a range offset (--sensor-model auto, range or beams estimates it)"
            )
    return None


def camera_section(name: str | None = None) -> tuple[str, str]:
    """(where a camera's config lives, the flag that refines its intrinsics or ""): the pair's
    ``camera`` of config.yaml and ``--refine-intrinsics``; a rig's camera ``name``: its
    ``sensors.<name>.camera`` of rig.yaml and none (a rig's cameras are not refined)."""
    return ("camera", "--refine-intrinsics") if name is None else (f"sensors.{name}.camera", "")


def residual_causes(
    frames: list[FrameResult], board: Board, camera: CameraModel, T_cam_lidar: np.ndarray,
    name: str | None = None,
) -> list[str]:  # fmt: skip
    """The likely causes of residuals far above the detectors' stated noise (module docstring), one
    sentence each, from the frames both sensors saw; [] when none shows. ``name``: a rig's camera
    (its section of rig.yaml is named; None: the pair's config.yaml)."""
    seen = [f for f in frames if f.board is not None and f.corners is not None]
    if not seen:
        return []
    causes, fits = _causes_without_extrinsic(seen, board, camera, name=name)
    if along := _range_offset(seen, T_cam_lidar, fits):
        causes.append(along)
    if moved := _moved(seen, board, T_cam_lidar, fits):
        names = [n for n, _, _ in moved]
        gaps = [g for _, g, _ in moved]
        causes.append(
            f"synchronisation: the images of {_names(names)} fit a flat board as their stated noise says, "
            f"but it sits {min(gaps):.0f}-{max(gaps):.0f} mm from where the scans saw it (more than "
            f"{MOVED_SIGMAS:g} x the LiDAR fit's stated sigma): the board moved between the scan and the "
            "photo (sensors not synchronised), or the LiDAR's fit is off there"
        )
    return causes


def causes_without_extrinsic(
    frames: list[FrameResult], board: Board, camera: CameraModel, margin: bool = True,
    name: str | None = None,
) -> list[str]:  # fmt: skip
    """``residual_causes``' causes that need no extrinsic (boards cut off by the image's border, the
    board's size, the intrinsics or lens model, and with ``margin`` the margin of boards placed by
    their outline), from the frames both sensors saw: what to name when the frames do not even give
    one. ``name``: a rig's camera, as in ``residual_causes``."""
    seen = [f for f in frames if f.board is not None and f.corners is not None]
    return _causes_without_extrinsic(seen, board, camera, margin, name)[0] if seen else []


def _causes_without_extrinsic(
    seen: list[FrameResult], board: Board, camera: CameraModel, margin: bool = True,
    name: str | None = None,
) -> tuple[list[str], dict[str, tuple[ImageAlone, float]]]:  # fmt: skip
    """(``causes_without_extrinsic``, the images' fits alone) of frames both sensors saw."""
    causes = [c for c in (_partial(seen, camera),) if c]
    scale = board_scale([(f.corners, f.board.T_lidar_board) for f in seen], board)  # type: ignore[misc, union-attr]
    if (
        scale is not None
        and scale[2] >= SCALE_PAIRS
        and abs(scale[0] - 1) > SCALE_TOL
        and scale[1] < abs(scale[0] - 1) / 3
    ):
        causes.append(
            f"the board's size: the images make its moves between frames {scale[0]:.3f} x what the scans "
            f"give ({scale[2]} pairs): board.square_size is not the print's (measure the whole pattern)"
        )
    fits = _image_fits(seen, board, camera)
    bad = sorted(r for _, r in fits.values() if r > LENS_RATIO)
    if 2 * len(bad) >= len(seen):
        key, flag = camera_section(name)
        refine = f", or {flag}" if flag else ""
        causes.append(
            f"the camera's intrinsics or lens model: {len(bad)} of {len(seen)} images alone fit a flat board "
            f"at {np.median(bad):.1f} x their stated corner noise (median; check {key}.K, dist and the "
            f"model{refine}; blur or a curled print do this too)"
        )
    outline = len([f for f in seen if f.board is not None and f.board.diagnostics.get("no_contrast")])
    if margin and 2 * outline > len(seen):
        causes.append(
            f"the board's margin: {outline} of {len(seen)} boards were placed by their outline, which "
            "board.margin_long and board.margin_short define with the squares: a margin other than the "
            "board's moves every one"
        )
    return causes, fits


def _centre_image(corners: ImageCorners, board: Board) -> np.ndarray | None:
    """(3,) the pattern's centre in the camera frame from the image corners and the board (UPnP)."""
    b = corners.bearings / np.linalg.norm(corners.bearings, axis=1, keepdims=True)
    ok = np.all(np.isfinite(b), axis=1)
    if ok.sum() < 6:
        return None
    T = upnp(board.corners_board()[ok], b[ok], prefer_front=True)[0].T_cam_points
    return T[:3, :3] @ board.pattern_centre + T[:3, 3]


def board_scale(
    pairs: Sequence[tuple[ImageCorners, np.ndarray]], board: Board, min_apart_m: float = 0.3
) -> tuple[float, float, int] | None:
    """How much bigger the images say the board's moves are than the scans: (median k, spread, pairs).

    pairs: per frame the image corners and the LiDAR's (4, 4) ``T_lidar_board``. For two frames the
    distance between the pattern's centres is the same in either sensor's frame (no extrinsic
    needed); from the image it scales with the configured square size, from the scans it does not.
    So k = s_configured / s_print (1 when the square size is right; the recorded sets give 1.003 and
    1.006, a simulated square 6 % too small 0.940). Pairs closer than ``min_apart_m`` are left out.
    spread: the median absolute deviation of the pairs' ratios. None with fewer than two frames.
    """
    cam, lid = [], []
    for corners, T in pairs:
        c = _centre_image(corners, board)
        if c is not None:
            cam.append(c)
            lid.append(T[:3, :3] @ board.pattern_centre + T[:3, 3])
    C, P = np.asarray(cam).reshape(-1, 3), np.asarray(lid).reshape(-1, 3)
    parts = []
    for i in range(len(C) - 1):  # every pair once: frame i with the later ones, a row at a time
        d_cam, d_lid = np.linalg.norm(C[i] - C[i + 1 :], axis=1), np.linalg.norm(P[i] - P[i + 1 :], axis=1)
        ok = (d_cam >= min_apart_m) & (d_lid > 0)
        parts.append(d_cam[ok] / d_lid[ok])
    ratios = np.concatenate(parts) if parts else np.zeros(0)
    if not len(ratios):
        return None
    k = float(np.median(ratios))
    return k, float(np.median(np.abs(ratios - k))), len(ratios)
