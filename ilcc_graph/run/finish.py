"""A strategy's answer for one source back into a ``Calibration``: every frame with its fate.

``Answer`` is what every strategy gives per source, as plain data (``from_batch`` makes it from
the estimation core's ``BatchSolution``; the paper's refinement gives no covariance: None).
``finish``: every frame in input order with its fate (used, or why not, with the likely cause of a
dropped frame, ``evaluation.causes``), the refined board poses, the sensors' own errors. calibration.yaml
writes a covariance the method does not give as NaN (interface.md).

No answer the data do not support: when the frames that agree within their noise are fewer than
``MIN_DISTINCT_POSES`` distinct board poses (each used frame is one: ``prepare`` drops repeats) and
others disagree beyond it, nothing tells which group is right, and a covariance from two poses
cannot reveal a placement's error: ``finish`` raises ``CalibrationImpossible`` (exit 3) naming the
frames that agree, those that disagree with each one's likely cause, and the likely cause over
all frames (``evaluation.causes.residual_causes``). When the residuals are far above the detectors' stated
noise (``gate.FAR_ABOVE``) the calibration carries those causes (``Calibration.causes``), unless a
used frame's board sits far from its scan (``require_within_noise``) or most images do not fit the
camera as stated (``require_images_fit``): then exit 3 too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NoReturn

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.config import Config
from ilcc_graph.errors import DISAGREEING, CalibrationImpossible
from ilcc_graph.estimation.batch import BatchSolution
from ilcc_graph.estimation.effects import SQUARE_SIZE_KEY
from ilcc_graph.estimation.gate import far_above
from ilcc_graph.estimation.geometry import MIN_DISTINCT_POSES
from ilcc_graph.estimation.lidar_errors import errors_entry
from ilcc_graph.evaluation.causes import (
    camera_section,
    dropped_frame_cause,
    fit_image_alone,
    image_fit_ratios,
    moved_boards,
    residual_causes,
)
from ilcc_graph.lidar.margin import margin_summary
from ilcc_graph.lidar.outline import BEYOND_FOV_SHARE
from ilcc_graph.run.prepare import Prepared, drop, frame_issues
from ilcc_graph.types import Calibration, FrameResult, PoseTerms, rotation_angle_deg

__all__ = ["Answer", "finish", "from_batch", "lidar_view_counts", "require_supported"]


@dataclass(frozen=True)
class Answer:
    """A strategy's answer for one source.

    T_cam_lidar: (4, 4); covariance: (6, 6) of it (rotation first) or None when the method gives
    none. rms_mrad: each used frame's RMS bearing error (mrad). T_lidar_board: refined board poses.
    dropped: ``(frame, reason)`` the strategy left out. iterations, variance_factor,
    variance_components (board priors, bearings): the solve's figures. diagnostics: further
    calibration.yaml diagnostics; sensors: ``Calibration.sensors``. failing: ``(frame, reason)`` of
    used frames that fail the chi-square gate though it may drop no more (the noise found does not
    cover them). with_terms: ``T_cam_lidar`` with the LiDAR's range terms (``Calibration.with_terms``).
    """

    T_cam_lidar: np.ndarray
    covariance: np.ndarray | None
    rms_mrad: dict[str, float]
    T_lidar_board: dict[str, np.ndarray] = field(default_factory=dict)
    dropped: list[tuple[str, str]] = field(default_factory=list)
    iterations: int = 0
    variance_factor: float = 1.0
    variance_components: tuple[float, float] = (1.0, 1.0)
    diagnostics: dict[str, float] = field(default_factory=dict)
    sensors: dict[str, Any] = field(default_factory=dict)
    failing: list[tuple[str, str]] = field(default_factory=list)
    with_terms: PoseTerms | None = None


def from_batch(sol: BatchSolution, config: Config) -> Answer:
    """The estimation core's answer (batch, incremental's last, a session's part) as an ``Answer``."""
    diagnostics = {}
    if sol.square_size is not None:  # what a print 0.1 % larger than board.square_size moves
        e = sol.square_size.extrinsic
        diagnostics[f"{SQUARE_SIZE_KEY}_rotation_deg"] = e.rotation_deg
        diagnostics[f"{SQUARE_SIZE_KEY}_translation_mm"] = e.translation_mm
        diagnostics[f"{SQUARE_SIZE_KEY}_sigmas"] = e.mahalanobis
        if sol.square_size.beams_mm is not None:
            diagnostics[f"{SQUARE_SIZE_KEY}_beams_mm"] = sol.square_size.beams_mm
    rms = {n: s.rms_bearing_error_mrad for n, s in sol.per_frame.items()}
    return Answer(
        sol.T_cam_lidar, sol.covariance, rms, sol.T_lidar_board, list(sol.dropped), sol.iterations,
        sol.variance_factor, sol.variance_components, diagnostics, _sensors(sol, config), list(sol.failing),
        _with_terms(sol),
    )  # fmt: skip


def _with_terms(sol: BatchSolution) -> PoseTerms | None:
    """The chosen model's extrinsic with its range terms (``next_board.SolvedGlobals``), or None; the
    joint covariance times the model's held-out factor (``Selection.factor``; 1 for a forced model),
    as the reported covariance is (``batch.solve``)."""
    factor = 1.0 if sol.selection is None else sol.selection.factor
    return None if sol.solved is None else sol.solved.pose_terms(factor)


def finish(
    prep: Prepared, observed: Sequence[FrameResult], config: Config, method: str, answer: Answer,
    agree: bool = True,
) -> Calibration:  # fmt: skip
    """The Calibration of one source from a strategy's answer: every frame in input order with its fate.

    agree: raise ``CalibrationImpossible`` when fewer than ``MIN_DISTINCT_POSES`` frames agree and
    others disagree beyond their noise, or the answer's noise hides frames from the gate (module
    docstring; a session of several is judged with them; off where the strategy runs without a gate)."""
    results = dict(prep.results)
    if answer.dropped:
        causes = _dropped_causes(results, [n for n, _ in answer.dropped], config, answer.T_cam_lidar)
        for name, reason in answer.dropped:
            drop(results, name, f"{reason}; {causes[name]}" if causes.get(name) else reason)
    order = [n for n, r in results.items() if not r.used and (r.reason or "").startswith(DISAGREEING)]
    order = [n for n in order if "likely cause" not in (results[n].reason or "")]  # the corner order's
    if order:
        causes = _dropped_causes(results, order, config, answer.T_cam_lidar)
        for name in order:
            if causes.get(name):
                drop(results, name, f"{results[name].reason}; {causes[name]}")
    frames = []
    for r in (results[o.name] for o in observed):
        if r.used:
            r = dataclasses.replace(
                r,
                rms_bearing_error_mrad=answer.rms_mrad.get(r.name),
                T_lidar_board_refined=answer.T_lidar_board.get(r.name),
            )
        frames.append(r)
    far = {} if answer.covariance is None else far_above(answer.variance_components)
    if agree:
        refined = "camera_intrinsics" in answer.sensors
        require_supported(frames, answer.failing, far, config, answer.T_cam_lidar, refined=refined)
    diagnostics = {
        **lidar_view_counts(frames, config.board),
        "iterations": float(answer.iterations),
        "variance_factor": answer.variance_factor,
        "variance_component_board": answer.variance_components[0],
        "variance_component_bearing": answer.variance_components[1],
        "upnp_rotation_deg": rotation_angle_deg(prep.T_init[:3, :3].T @ answer.T_cam_lidar[:3, :3]),
        **answer.diagnostics,
    }
    cov = np.full((6, 6), np.nan) if answer.covariance is None else answer.covariance
    T, cam, sensors = answer.T_cam_lidar, config.camera.to_dict(), answer.sensors
    residual = tuple(residual_causes(frames, config.board, config.camera, T)) if far else ()
    return Calibration(T, cov, tuple(frames), method, diagnostics, cam, sensors, residual, answer.with_terms)


def require_supported(
    frames: Sequence[FrameResult],
    failing: Sequence[tuple[str, str]],
    far: dict[str, float],
    config: Config,
    T_cam_lidar: np.ndarray,
    camera: str | None = None,
    refined: bool = False,
) -> None:
    """Every door's refusals of a camera's extrinsic with its LiDAR (the pair's; each of a rig's
    cameras with its base LiDAR, ``camera`` named): fewer than ``MIN_DISTINCT_POSES`` frames agree
    (``require_agreement``); used frames fail the gate, which may drop no more (``require_covered``);
    the residuals far above the stated noise (``far``) and boards far from their scans
    (``require_within_noise``), or the image corners far above theirs, intrinsics as stated (not
    ``refined``), and most images not fitting the camera (``require_images_fit``)."""
    require_agreement(frames, config, T_cam_lidar, camera)
    require_covered(frames, failing, config, T_cam_lidar, camera)
    if far:
        require_within_noise(frames, far, config, T_cam_lidar, camera)
    if "bearing" in far and not refined:
        require_images_fit(frames, config, T_cam_lidar, camera)


def require_agreement(
    frames: Sequence[FrameResult], config: Config, T_cam_lidar: np.ndarray, camera: str | None = None
) -> None:
    """Raise ``CalibrationImpossible`` when the frames used (one per distinct board pose) are fewer
    than ``MIN_DISTINCT_POSES`` and frames seen by both sensors were dropped for disagreeing with
    them (``errors.DISAGREEING``): which frames agree, which disagree and why, the likely cause."""
    used = [f for f in frames if f.used]
    disagree = [f for f in frames if not f.used and (f.reason or "").startswith(DISAGREEING)]
    if len(used) >= MIN_DISTINCT_POSES or not disagree:
        return
    agree_names, other_names = [f.name for f in used], [f.name for f in disagree]
    k = len(used)
    message = (
        f"{_whose(camera)}only {k} distinct board pose{'s' * (k != 1)} agree ({', '.join(agree_names)}) and "
        f"{len(disagree)} disagree with {'them' if k != 1 else 'it'} beyond their noise "
        f"({', '.join(other_names)}): with fewer than {MIN_DISTINCT_POSES} poses that agree nothing tells "
        "which frames are right, and their covariance could not reveal a placement's error"
    )
    issues = [
        (f.name, "agreement", "agrees with " + (", ".join(n for n in agree_names if n != f.name) or "none"))
        for f in used
    ]
    issues += [(f.name, "agreement", f.reason or "disagrees") for f in disagree]
    _refuse(message, issues, frames, config, T_cam_lidar, camera)


def _whose(camera: str | None) -> str:
    """The start of a refusal's message: "" for the pair, ``camera 'X': `` for a rig's camera X."""
    return "" if camera is None else f"camera '{camera}': "


def _refuse(
    message: str,
    issues: list[tuple[str, str, str]],
    frames: Sequence[FrameResult],
    config: Config,
    T_cam_lidar: np.ndarray,
    camera: str | None = None,
) -> NoReturn:
    """Raise the exit 3 of frames that do not agree: ``issues`` (frame, stage, reason) with every other
    frame's own issue (``frame_issues``), in the frames' order, and the likely cause over all frames
    (``evaluation.causes.residual_causes``; ``camera``: a rig's) as the advice, else ``_CHECK``."""
    named = {n for n, _, _ in issues}
    issues = issues + [i for i in frame_issues(frames) if i[0] not in named]
    order = {f.name: i for i, f in enumerate(frames)}
    issues.sort(key=lambda i: order.get(i[0], len(order)))
    found = residual_causes(list(frames), config.board, config.camera, T_cam_lidar, camera)
    advice = f"likely: {found[0]}" if found else _CHECK
    raise CalibrationImpossible(message, tuple(issues), advice)


#: the advice of an exit 3 for disagreeing frames when no cause shows in them
_CHECK = (
    "check what differs between the frames that agree and those that do not (the board cut off in the "
    "image, the board moving while captured, the camera's intrinsics, board.square_size and its margin) "
    "before capturing more poses"
)


def lidar_view_counts(frames: Sequence[FrameResult], board: Board | None = None) -> dict[str, float]:
    """How the LiDAR saw the used frames' boards: ``lidar_boards_no_print`` (fitted by the outline
    alone), ``lidar_boards_beyond_fov`` (partly above the top beam or below the lowest) and
    ``lidar_boards_on_corrected_ranges`` (fitted again on the ranges corrected by the LiDAR's
    estimated errors, ``run.range_refit``; with ``lidar_range_correction_mm``, their mean), counts,
    each only when not 0; with ``board``, the margin the boards measured when it contradicts the
    configured one (``lidar.margin.margin_summary``)."""
    boards = [f.board.diagnostics for f in frames if f.used and f.board is not None]
    corrected = [d["range_correction_mm"] for d in boards if "range_correction_mm" in d]
    counts = {
        "lidar_boards_no_print": float(sum(1 for d in boards if d.get("no_contrast"))),
        "lidar_boards_beyond_fov": float(
            sum(1 for d in boards if d.get("outside_fov_share", 0.0) > BEYOND_FOV_SHARE)
        ),
        "lidar_boards_on_corrected_ranges": float(len(corrected)),
        "lidar_range_correction_mm": float(np.mean(corrected)) if corrected else 0.0,
    }
    margin = margin_summary(boards, board) if board is not None else {}
    return {k: v for k, v in counts.items() if v} | margin


def require_covered(
    frames: Sequence[FrameResult],
    failing: Sequence[tuple[str, str]],
    config: Config,
    T_cam_lidar: np.ndarray,
    camera: str | None = None,
) -> None:
    """Raise ``CalibrationImpossible`` when used frames fail the chi-square gate though it may drop no
    more (``Answer.failing``): no majority of the frames agrees within the noise the solve found, so
    the covariance would not cover the frames the result uses."""
    if not failing:
        return
    used = [f for f in frames if f.used]
    gone = [f for f in frames if not f.used and (f.reason or "").startswith(DISAGREEING)]
    names = [n for n, _ in failing]
    message = (
        f"{_whose(camera)}{len(failing)} of the {len(used)} frames left ({', '.join(names)}) still "
        f"disagree beyond their noise after {len(gone)} were dropped for disagreeing, the most the test "
        "may drop: no majority of the frames agrees, so no covariance would cover the frames a result uses"
    )
    results = {f.name: f for f in frames}
    causes = _dropped_causes(results, names, config, T_cam_lidar)
    issues = [(n, "agreement", f"{why}; {causes[n]}" if causes.get(n) else why) for n, why in failing]
    issues += [(f.name, "agreement", f.reason or "disagrees") for f in gone]
    _refuse(message, issues, frames, config, T_cam_lidar, camera)


def require_within_noise(
    frames: Sequence[FrameResult],
    far: dict[str, float],
    config: Config,
    T_cam_lidar: np.ndarray,
    camera: str | None = None,
) -> None:
    """Raise ``CalibrationImpossible`` when the residuals are far above the detectors' stated noise
    (``far``: the variance components, ``gate.far_above``) and used frames' images put their board
    far from where the scans saw it, through ``T_cam_lidar`` or through the extrinsic most frames
    agree on (``evaluation.causes.moved_boards`` with ``consensus``: boards that moved together
    pull the solve's): the noise estimated from the frames then hides those frames from
    the gate, so the covariance would not cover them."""
    found = moved_boards(list(frames), config.board, config.camera, T_cam_lidar, consensus=True)
    moved = {n: (g, s) for n, g, s in found}
    used = [f for f in frames if f.used and f.name in moved]
    if not used:
        return
    what = {"bearing": "image corners", "board": "LiDAR board poses"}
    sizes = ", ".join(f"{what[k]} {np.sqrt(v):.1f} x their stated sigma" for k, v in far.items())
    names = [f.name for f in used]
    message = (
        f"{_whose(camera)}the residuals are far above the detectors' stated noise ({sizes}) and the "
        f"result uses frames whose image puts the board far from where the scan saw it ({', '.join(names)}): "
        "the noise estimated from the frames hides them from the test, so no covariance would cover the "
        "frames used"
    )
    issues = [
        (n, "agreement", f"used, but its image puts the board {moved[n][0]:.0f} mm ({moved[n][1]:.0f} x the "
         "LiDAR fit's stated sigma) from where the scan saw it: the board moved between the scan and the "
         "photo, or the LiDAR's fit is off there") for n in names
    ]  # fmt: skip
    _refuse(message, issues, frames, config, T_cam_lidar, camera)


#: the images used fit a flat board alone at this many times their stated corner noise (the median of
#: the majority that do): the camera as stated does not describe them (a focal length twice the
#: lens's gave 24-26 x); the recorded sets' image corners sit at 1.2-1.3 x their stated noise over all
#: frames (the square root of their variance components)
IMAGES_UNFIT_RATIO = 10.0


def require_images_fit(
    frames: Sequence[FrameResult], config: Config, T_cam_lidar: np.ndarray, camera: str | None = None
) -> None:
    """Raise ``CalibrationImpossible`` when most used frames' images alone (a flat board through the
    camera as stated, ``evaluation.causes.image_fit_ratios``) fit at more than ``IMAGES_UNFIT_RATIO``
    times their stated corner noise: the camera's intrinsics or model are not the images' (or their
    corner noise is stated far too small), and an extrinsic through that camera is off by more than the
    noise the solve estimated can cover; variance components absorb a noise stated wrongly, not a
    camera model that is wrong."""
    used = [f for f in frames if f.used and f.corners is not None]
    ratios = image_fit_ratios(used, config.board, config.camera)
    bad = {n: r for n, r in ratios.items() if r > IMAGES_UNFIT_RATIO}
    if not used or 2 * len(bad) <= len(used):
        return
    whose = "the camera" if camera is None else f"camera '{camera}'"
    key, flag = camera_section(camera)
    refine = f"; or {flag}" if flag else ""
    message = (
        f"the images do not fit {whose} as stated: {len(bad)} of the {len(used)} images used fit a flat "
        f"board alone at {np.median(list(bad.values())):.0f} x their stated corner noise (median): the "
        f"camera's intrinsics or model are not the images' (check {key}.K in pixels of this image size, "
        f"{key}.dist and {key}.model{refine}), so no covariance would cover an extrinsic through it"
    )
    issues = [
        (n, "image", f"fits a flat board alone at {r:.0f} x its stated corner noise") for n, r in bad.items()
    ]
    _refuse(message, issues, frames, config, T_cam_lidar, camera)


def _dropped_causes(
    results: dict[str, FrameResult], dropped: Sequence[str], config: Config, T_cam_lidar: np.ndarray
) -> dict[str, str]:
    """Per dropped frame the likely cause (``evaluation.causes``), judged against the used frames' images."""
    used = [r.corners for n, r in results.items() if r.used and n not in dropped and r.corners is not None]
    if len(used) < 3:  # too few to tell the typical image fit: every frame's with corners judges it
        used = [r.corners for n, r in results.items() if r.corners is not None and (r.used or n in dropped)]
    if len(used) < 3:
        return {}
    corners = config.board.corners_board()
    typical = float(np.median([fit_image_alone(c.bearings, corners).rms_mrad for c in used]))
    return {
        n: dropped_frame_cause(results[n], config.board, config.camera, T_cam_lidar, typical) for n in dropped
    }


def _sensors(sol: BatchSolution, config: Config) -> dict:
    """``Calibration.sensors`` of a strategy's answer: the sensor model chosen and the evidence, the
    LiDAR's errors, the camera's intrinsics and what each moved the extrinsic."""
    out: dict = {}
    if sol.selection is not None:
        out["model"] = sol.selection.to_dict()
    plane = getattr(sol, "board_plane", None)
    planes = None if plane is None else dataclasses.asdict(plane)
    el = None if config.lidar is None else config.lidar.vertical_angles_deg
    errors = errors_entry(sol.lidar, sol.lidar_layout, sol.lidar_covariance, planes, el)
    if errors:
        out["lidar_errors"] = errors
    if sol.effects:
        out["effects"] = {k: dataclasses.asdict(v) for k, v in sol.effects.items()}
    if sol.intrinsics is not None:
        names, values, sigmas = sol.intrinsics
        stated = config.camera.intrinsics()
        out["camera_intrinsics"] = {
            "names": list(names),
            "stated": stated,
            "values": values,
            "sigmas": sigmas,
        }
    return out
