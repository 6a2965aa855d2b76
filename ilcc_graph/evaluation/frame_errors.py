"""The numbers of an extrinsic on frames: the paper's metric per frame and overall, corner errors.

``evaluate(frames, camera, board, T_cam_lidar)`` gives an :class:`~.metric.Evaluation`; frames come
from the pipeline's results (``eval_frame``, ``eval_frames``) or a calibration file with its scans
(``eval_frame_with_scan``, ``evaluate_calibration``). The metric itself is ``metric.metric_points``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import replace

import numpy as np

from ..board import Board
from ..cameras import CameraModel
from ..types import Calibration, FrameResult, Scan
from .metric import (
    EPSILON_G,
    EvalFrame,
    Evaluation,
    FrameEvaluation,
    MetricPoints,
    metric_points,
    metric_points_many,
    transform_points,
)

__all__ = [
    "board_points_from_scan",
    "corner_errors",
    "eval_frame",
    "eval_frame_with_scan",
    "eval_frames",
    "evaluate",
    "evaluate_calibration",
    "evaluate_frame",
    "evaluate_many",
    "evaluation_rows",
    "evaluation_to_dict",
    "expected_corner_px",
]


def corner_errors(
    corners_lidar: np.ndarray,
    uv: np.ndarray,
    camera: CameraModel,
    T_cam_lidar: np.ndarray,
    board: Board | None = None,
) -> tuple[float, float, float, bool]:
    """(rms px, max px, rms mrad, half_turn) of LiDAR corners re-projected against image corners.

    Panorama columns are compared across the seam. With a half-turn symmetric ``board`` the better
    of the two corner orders is used (a frame whose order was never fixed, e.g. one held out of a
    fit, is still compared fairly); ``half_turn`` says the turned order won.
    """
    p_cam = transform_points(T_cam_lidar, corners_lidar)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    orders = [np.arange(len(uv))]
    if board is not None and board.half_turn_symmetric:
        orders.append(board.half_turn_permutation())
    pred = camera.project(p_cam)
    b_pred = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
    b_meas = camera.bearing(uv)
    best: tuple[float, float, float, bool] | None = None
    for n, perm in enumerate(orders):
        d = pred - uv[perm]
        d[:, 0] = camera.wrap_du(d[:, 0])
        e = np.linalg.norm(d, axis=1)
        bm = b_meas[perm]
        ang = np.arctan2(np.linalg.norm(np.cross(b_pred, bm), axis=1), np.sum(b_pred * bm, axis=1))
        cand = (
            float(np.sqrt(np.mean(e**2))),
            float(np.max(e)),
            float(1e3 * np.sqrt(np.mean(ang**2))),
            n == 1,
        )
        if best is None or (np.isfinite(cand[2]) and not cand[2] >= best[2]):
            best = cand
    assert best is not None
    return best


def evaluate_frame(
    frame: EvalFrame,
    camera: CameraModel,
    board: Board,
    T_cam_lidar: np.ndarray,
    epsilon: float = EPSILON_G,
) -> FrameEvaluation:
    """The paper's metric and the corner errors for one frame (see the module docstring)."""
    return _frame_evaluation(frame, metric_points(frame, camera, board, T_cam_lidar, epsilon), camera, board,
                             T_cam_lidar)  # fmt: skip


def _frame_evaluation(
    frame: EvalFrame, mp: MetricPoints, camera: CameraModel, board: Board, T_cam_lidar: np.ndarray
) -> FrameEvaluation:
    """A frame's numbers from its metric's workings ``mp`` under ``T_cam_lidar``."""
    n_in = int(mp.inside.sum())
    n_exp = int(mp.expected.sum())
    attendance = min(1.0, n_in / n_exp) if n_exp > 0 else float("nan")
    if n_in > 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = float(np.sum(mp.f_d[mp.inside] / mp.range_m[mp.inside]) / n_in)
        value = 1e3 * mean / (attendance if np.isfinite(attendance) else 1.0)
    else:
        value = float("inf") if n_exp > 0 else float("nan")
    rms_px = max_px = rms_mrad = float("nan")
    half = False
    if frame.corners_lidar is not None and len(frame.corners_lidar) == len(frame.uv):
        rms_px, max_px, rms_mrad, half = corner_errors(
            frame.corners_lidar, frame.uv, camera, T_cam_lidar, board
        )
    return FrameEvaluation(
        name=frame.name,
        intensity_mrad=value,
        n_points=int(len(mp.inside)),
        n_inside=n_in,
        n_mismatch=int(mp.mismatch.sum()),
        attendance=attendance,
        corner_rms_px=rms_px,
        corner_max_px=max_px,
        corner_rms_mrad=rms_mrad,
        half_turn=half,
        range_m=float(np.median(mp.range_m)) if len(mp.range_m) else float("nan"),
    )


def evaluate(
    frames: Sequence[EvalFrame],
    camera: CameraModel,
    board: Board,
    T_cam_lidar: np.ndarray,
    epsilon: float = EPSILON_G,
) -> Evaluation:
    """Per-frame and overall numbers of ``T_cam_lidar`` (4x4, p_cam = T p_lidar) on ``frames``."""
    return evaluate_many(frames, camera, board, [T_cam_lidar], epsilon)[0]


def evaluate_many(
    frames: Sequence[EvalFrame],
    camera: CameraModel,
    board: Board,
    Ts: Sequence[np.ndarray],
    epsilon: float = EPSILON_G,
) -> list[Evaluation]:
    """``evaluate`` under each extrinsic of ``Ts`` (4x4 each), in order: each frame's metric worked
    out for all of them at once (``metric.metric_points_many``)."""
    Ts = [np.asarray(T, dtype=np.float64) for T in Ts]
    for T in Ts:
        if T.shape != (4, 4):
            raise ValueError(f"evaluate: T_cam_lidar must be 4x4, got {T.shape}")
    per_frame = []
    for f in frames:
        mps = metric_points_many(f, camera, board, Ts, epsilon)
        per_frame.append([_frame_evaluation(f, mp, camera, board, T) for mp, T in zip(mps, Ts, strict=True)])
    return [Evaluation(tuple(fe[k] for fe in per_frame), T.copy()) for k, T in enumerate(Ts)]


# ------------------------------------------------------------------- from our types
def eval_frame(result: FrameResult) -> EvalFrame | None:
    """The :class:`EvalFrame` of a pipeline frame, or None when it lacks the board or the corners."""
    b, c = result.board, result.corners
    if b is None or c is None or len(c.uv) == 0:
        return None
    return EvalFrame(
        name=result.name,
        points_lidar=np.asarray(b.points_lidar, dtype=np.float64).reshape(-1, 3),
        intensity=np.asarray(b.intensity, dtype=np.float64).ravel(),
        uv=np.asarray(c.uv, dtype=np.float64),
        corners_lidar=np.asarray(b.corners_lidar, dtype=np.float64),
        T_lidar_board=np.asarray(b.T_lidar_board, dtype=np.float64),
    )


def eval_frames(frames: Calibration | Sequence[FrameResult], used_only: bool = False) -> list[EvalFrame]:
    """EvalFrames of every frame that has both the board fit and the image corners."""
    seq = frames.frames if isinstance(frames, Calibration) else frames
    out = []
    for r in seq:
        if used_only and not r.used:
            continue
        e = eval_frame(r)
        if e is not None:
            out.append(e)
    return out


def board_points_from_scan(
    scan: Scan, T_lidar_board: np.ndarray, board: Board, max_distance_m: float = 0.05, pad_m: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    """The scan's points on the fitted board: within ``max_distance_m`` of its plane and inside its
    outline grown by ``pad_m``. Returns (points (M, 3) LiDAR frame, intensity (M,)).

    For evaluating a calibration file (which stores the board poses but not the segments).
    """
    q = transform_points(np.linalg.inv(np.asarray(T_lidar_board, dtype=np.float64)), scan.points)
    x0, x1, y0, y1 = board.extent()
    keep = (np.abs(q[:, 2]) <= max_distance_m) & (q[:, 0] >= x0 - pad_m) & (q[:, 0] <= x1 + pad_m)
    keep &= (q[:, 1] >= y0 - pad_m) & (q[:, 1] <= y1 + pad_m)
    return np.asarray(scan.points, dtype=np.float64)[keep], np.asarray(scan.intensity, dtype=np.float64)[keep]


def eval_frame_with_scan(
    result: FrameResult, scan: Scan, board: Board, max_distance_m: float = 0.05
) -> EvalFrame | None:
    """:func:`eval_frame`, with the board points rebuilt from ``scan`` when the result lacks them.

    A calibration read back from ``calibration.yaml`` keeps each frame's corners and board pose but
    not its board segment; the segment is then the scan's points on the fitted board
    (:func:`board_points_from_scan`). None when the frame has no corners or no board pose.
    """
    e = eval_frame(result)
    if e is None:
        return None
    if len(e.points_lidar) == 0:
        T = e.T_lidar_board
        if T is None or not np.all(np.isfinite(T)):
            return None
        pts, inten = board_points_from_scan(scan, T, board, max_distance_m)
        e = replace(e, points_lidar=pts, intensity=inten)
    return e


def evaluate_calibration(
    calibration: Calibration,
    camera: CameraModel,
    board: Board,
    scans: Iterable[tuple[str, Scan]] = (),
    T_cam_lidar: np.ndarray | None = None,
    used_only: bool = False,
) -> Evaluation:
    """Evaluate a calibration (e.g. read from ``calibration.yaml``) on its own frames.

    scans: (name, scan) pairs, consumed one at a time, to rebuild board segments a calibration file
    does not keep. T_cam_lidar: another extrinsic to judge on these frames (default: the
    calibration's own).
    """
    results = {f.name: f for f in calibration.frames if f.used or not used_only}
    frames: dict[str, EvalFrame | None] = {}
    for name, scan in scans:
        if name in results:
            frames[name] = eval_frame_with_scan(results[name], scan, board)
    out = [frames[n] if n in frames else eval_frame(r) for n, r in results.items()]
    T = calibration.T_cam_lidar if T_cam_lidar is None else T_cam_lidar
    return evaluate([e for e in out if e is not None], camera, board, T)


def evaluation_rows(ev: Evaluation) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
    """(header, rows) of a plain-text table: one row per frame, then the mean and 3 x the SD over frames."""
    header: tuple[str, ...] = (
        "frame", "intensity mrad", "corner px", "corner mrad", "attendance", "inside/points"
    )  # fmt: skip

    def f(x: float, fmt: str = ".3f") -> str:
        return "inf" if np.isinf(x) else "-" if np.isnan(x) else format(x, fmt)

    rows: list[tuple[str, ...]] = [
        (e.name, f(e.intensity_mrad), f(e.corner_rms_px), f(e.corner_rms_mrad), f(e.attendance, ".2f"),
         f"{e.n_inside}/{e.n_points}")
        for e in ev.frames
    ]  # fmt: skip
    (im, i3), (pm, p3), (cm, c3) = ev.intensity_mrad, ev.corner_px, ev.corner_mrad
    rows.append(("mean", f(im), f(pm), f(cm), "", ""))
    rows.append(("3 x SD", f(i3), f(p3), f(c3), "", ""))
    return header, rows


def evaluation_to_dict(ev: Evaluation) -> dict:
    """Plain numbers (per frame and overall) for YAML."""
    return {
        "metric": "Wang et al. 2017 Eq. 14 (gray zone epsilon_g = 4), mrad; corner errors px and mrad",
        "overall": ev.summary(),
        "frames": [
            {
                "name": e.name,
                "intensity_mrad": e.intensity_mrad,
                "corner_rms_px": e.corner_rms_px,
                "corner_max_px": e.corner_max_px,
                "corner_rms_mrad": e.corner_rms_mrad,
                "attendance": e.attendance,
                "n_points": e.n_points,
                "n_inside": e.n_inside,
                "n_mismatch": e.n_mismatch,
                "range_m": e.range_m,
                "half_turn": e.half_turn,
            }
            for e in ev.frames
        ],
    }


def _skew(p: np.ndarray) -> np.ndarray:
    """(N, 3, 3) cross-product matrices of p (N, 3)."""
    z = np.zeros(len(p))
    x, y, w = p[:, 0], p[:, 1], p[:, 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], axis=1)


def expected_corner_px(
    result: FrameResult, camera: CameraModel, board: Board, T_cam_lidar: np.ndarray
) -> float:
    """RMS pixel error of a frame's re-projected corners that its stated uncertainties explain.

    Sums, per corner, the image corner's covariance (``ImageCorners.cov_px``) and the LiDAR
    board pose's covariance (``BoardFit.covariance``, tangent ``T_lidar_board * Exp(xi)``) carried
    to pixels through ``T_cam_lidar`` and the camera's Jacobian; returns sqrt of the mean trace.
    A corner error well above it means something the uncertainties do not cover. NaN when the
    frame lacks either covariance.
    """
    b, c = result.board, result.corners
    if b is None or c is None or c.cov_px is None:
        return float("nan")
    cov_b = np.asarray(b.covariance, dtype=np.float64)
    cov_px = np.asarray(c.cov_px, dtype=np.float64)
    if cov_b.shape != (6, 6) or not np.all(np.isfinite(cov_b)) or cov_px.shape != (board.n_corners, 2, 2):
        return float("nan")
    T_lb = np.asarray(b.T_lidar_board, dtype=np.float64)
    T_cl = np.asarray(T_cam_lidar, dtype=np.float64)
    p_b = board.corners_board()
    J_xi = np.concatenate(
        [-T_lb[:3, :3] @ _skew(p_b), np.broadcast_to(T_lb[:3, :3], (len(p_b), 3, 3))], axis=2
    )
    p_cam = transform_points(T_cl @ T_lb, p_b)
    J = camera.d_uv_d_point(p_cam) @ T_cl[:3, :3] @ J_xi  # (K, 2, 6)
    cov_uv = J @ cov_b @ np.swapaxes(J, 1, 2) + cov_px
    tr = np.trace(cov_uv, axis1=1, axis2=2)
    tr = tr[np.isfinite(tr)]
    return float(np.sqrt(np.mean(tr))) if tr.size else float("nan")
