"""The LiDAR stage: find the chessboard in one scan and estimate its pose and inner corners.

``estimate_board(scan, board, lidar_model=None, roi=None, options=LidarOptions(), expected=None)
-> BoardFit`` (raises ``BoardNotFound`` with the reason, ``InputError`` for a scan without usable
intensity). Pipeline: segmentation.py (scanlines -> objects; ringless.py for a scan without
scanlines), detection.py (the paper's board tests), choice.py (the best of the candidates, the
expected-board hint), pose.py (a candidate's points -> BoardFit) with cost.py (the paper's intensity
cost), fit.py (the in-plane fit, Powell), soft_edge.py (soft-edged refinement) and covariance.py
(plane fit, sampling, coupling).
See docs/lidar_stage.md.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..board import Board
from ..errors import BoardNotFound, InputError
from ..lidars import LidarModel, beam_index, choose_model, measure_beams
from ..types import BoardFit, ExpectedBoard, Scan
from .choice import candidate_order, expected_mask, fit_score
from .detection import Candidate, find_candidates
from .options import LidarOptions
from .pose import fit_board_points
from .ringless import find_ringless_candidates, one_pseudo_beam, pseudo_rings

__all__ = ["estimate_board", "LidarOptions", "check_intensity", "fit_board_points", "ExpectedBoard"]


def check_intensity(scan: Scan) -> None:
    """Raise InputError when the scan has no usable reflectance intensity (absent, wrong size, constant)."""
    src = scan.source or "scan"
    inten = scan.intensity
    if inten is None:
        raise InputError(
            f"{src}: the scan has no intensity field; the chessboard is found by its reflectance"
        )
    inten = np.asarray(inten)
    if inten.shape != (len(scan),):
        raise InputError(f"{src}: intensity has shape {inten.shape}, expected ({len(scan)},)")
    fin = inten[np.isfinite(inten)]
    if fin.size == 0 or float(fin.max()) == float(fin.min()):
        value = "no finite value" if fin.size == 0 else f"every value is {float(fin[0]):g}"
        raise InputError(
            f"{src}: the intensity field carries no information ({value}); the chessboard's squares "
            "are told apart by reflectance intensity (check lidar.intensity_column for a CSV)"
        )


def _fit_candidate(
    cand: Candidate,
    pts: np.ndarray,
    inten: np.ndarray,
    ring: np.ndarray,
    board: Board,
    model: LidarModel,
    options: LidarOptions,
    rng: np.random.Generator,
) -> BoardFit:
    """The chessboard fitted to one candidate and the points around it (the pool)."""
    # the pool: every point near the board's plane and not farther from its centre than the board's size
    x0, x1, y0, y1 = board.extent()
    centre = pts[cand.indices].mean(axis=0)
    near = (
        np.abs(pts @ cand.normal - cand.offset) < max(options.ransac_threshold_m, 3 * cand.noise_sigma)
    ) & (np.linalg.norm(pts - centre, axis=1) < 0.75 * np.hypot(x1 - x0, y1 - y0))
    # the fit sees the whole pool: detection may have kept only part of the board (a piece cut off by
    # a person or the stand); off-board returns in the pool cost their distance, as in the paper
    near[cand.indices] = True
    return fit_board_points(
        pts[near], inten[near], cand.normal, cand.offset, board, model, options, rng, ring=ring[near]
    )


def estimate_board(
    scan: Scan,
    board: Board,
    lidar_model: LidarModel | None = None,
    roi: Any | None = None,
    options: LidarOptions = LidarOptions(),
    expected: ExpectedBoard | None = None,
) -> BoardFit:
    """Find the chessboard in one scan; its pose, covariance and inner corners in the LiDAR frame.

    scan: points (N, 3) LiDAR frame, intensity (N,) in any unit, ring (N,) in the file's numbering
    or None. lidar_model: the beam table (None: measured from this scan, ``lidars.measure``); the
    scan's rings are mapped onto it by elevation (``lidars.beam_index``).
    roi: optional ``config.Roi`` (azimuth_deg, elevation_deg, range_m limits) narrowing the search.
    expected: optional predicted board (e.g. from the image and an extrinsic): the search keeps to
    a box around it and candidates are ranked by closeness to it; a fit beyond its tolerances is
    refused.
    Of the candidates that pass the board tests, the chessboard is fitted to at most
    ``options.max_fits`` and the fit that explains the intensities best is returned (choice.py).
    Raises InputError when the scan has no usable intensity, BoardNotFound (with the reason) when
    no segment passes the chessboard tests or no fit is good.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    check_intensity(scan)
    pts = np.asarray(scan.points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"{scan.source or 'scan'}: points must be (N, 3), got {pts.shape}")
    valid = np.isfinite(pts).all(axis=1) & (pts != 0).any(
        axis=1
    )  # (0, 0, 0): an organised cloud's "no return"
    if not valid.all():
        ring_v = None if scan.ring is None else np.asarray(scan.ring)[valid]
        scan = Scan(pts[valid], np.asarray(scan.intensity)[valid], ring_v, scan.source, scan.columns)
        pts = scan.points
    if lidar_model is None:
        lidar_model = choose_model(measure_beams(scan), None, scan.source)[0]
    ring = pseudo_rings(pts) if lidar_model.ringless else beam_index(scan, lidar_model)  # no scanlines
    rng = np.random.default_rng(0)
    inten = np.asarray(scan.intensity, np.float64)
    mask = None if expected is None else expected_mask(pts, board, expected)
    fits: list[tuple[float, Candidate, BoardFit]] = []
    refused: list[str] = []
    budget = [3 * max(1, options.max_fits)]  # fits over all batches of candidates

    def accept(cands: list[Candidate]) -> bool:
        """Fit the best few new candidates; True (stop searching) once a fit is good."""
        for cand in candidate_order(cands, pts, board, expected)[: max(1, options.max_fits)]:
            if budget[0] <= 0:
                break
            budget[0] -= 1
            try:
                fit = _fit_candidate(cand, pts, inten, ring, board, lidar_model, options, rng)
            except BoardNotFound as e:
                refused.append(str(e))
                continue
            score = fit_score(fit, board, expected)
            if not np.isfinite(score):
                refused.append("the fitted board lies beyond the expected board's tolerances")
            elif score < options.min_fit_score:
                off = fit.cost / max(fit.diagnostics["n_points"], 1.0) / board.square_size
                refused.append(
                    f"a board-shaped object at {fit.diagnostics['range_m']:.2f} m, but the fitted chessboard "
                    f"explains it poorly (colour agreement {fit.diagnostics['colour_agreement']:.0%}, "
                    f"returns {off:.2f} squares off the pattern on average)"
                )
            else:
                fits.append((score, cand, fit))
        return any(f[0] >= options.good_fit_score for f in fits) or budget[0] <= 0

    find = find_ringless_candidates if lidar_model.ringless else find_candidates
    cands = find(pts, ring, inten, board, lidar_model, roi, options, rng, mask, accept)
    if not fits:
        raise BoardNotFound(
            refused[0]
            if len(refused) == 1
            else f"{len(refused)} board-shaped candidates, none fits: " + "; ".join(refused[:3])
        )
    score, cand, fit = max(fits, key=lambda t: t[0])
    fit = one_pseudo_beam(fit) if lidar_model.ringless else fit
    t_all, c_all = time.perf_counter() - t0, time.process_time() - c0
    fit.diagnostics.update(
        {"time_total_s": t_all, "cpu_total_s": c_all,
         "time_detect_s": t_all - fit.diagnostics["time_fit_s"],
         "cpu_detect_s": c_all - fit.diagnostics["cpu_fit_s"],
         "uniformity": cand.uniformity, "contrast": cand.contrast, "range_noise_m": cand.noise_sigma,
         "candidates_tested": float(cand.tested), "candidates_passed": float(len(cands)),
         "candidates_fitted": float(len(fits) + len(refused)), "choice_score": score}
    )  # fmt: skip
    return fit
