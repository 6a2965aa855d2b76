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
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ..board import Board
from ..errors import BoardNotFound, InputError
from ..lidars import LidarModel, beam_index, choose_model, cropped_table, measure_beams, with_intensity_ring
from ..types import BoardFit, ExpectedBoard, RangeCorrection, Scan
from .board_tests import PrintUnreadable, intensity_contrast, print_visible
from .choice import beyond_expected, candidate_order, expected_mask, fit_score
from .detection import Candidate, find_candidates
from .options import LidarOptions, breach
from .pose import fit_board_points
from .ringless import find_ringless_candidates, one_pseudo_beam, pseudo_rings

__all__ = [
    "estimate_board",
    "LidarOptions",
    "check_intensity",
    "fit_board_points",
    "ExpectedBoard",
    "INTENSITY_UNUSABLE",
]


#: why a scan's intensity cannot show the print (``BoardFit.diagnostics["intensity_unusable"]``)
INTENSITY_UNUSABLE = {
    1.0: "the scans have no intensity field, by any of the names intensity, reflectance, reflectivity, "
    "signal, i",
    2.0: "the intensity field has no finite value",
    3.0: "the intensity field holds one value everywhere",
    4.0: "the intensity field follows the beams (the ring number or the elevation)",
}


def check_intensity(scan: Scan) -> float:
    """Whether the scan's intensity can show a print: 0.0 when it may, else the key of the reason in
    ``INTENSITY_UNUSABLE`` (absent, no finite value, constant, the ring number or the elevation).
    InputError when it does not match the points (wrong length): a file that is wrong."""
    if scan.intensity is None or not scan.has_intensity:  # a caller's Scan may carry None
        return 1.0
    inten = np.asarray(scan.intensity)
    if inten.shape != (len(scan),):
        raise InputError(
            f"{scan.source or 'scan'}: intensity has shape {inten.shape}, expected ({len(scan)},)"
        )
    fin = np.isfinite(inten)
    if not fin.any():
        return 2.0
    if float(inten[fin].max()) == float(inten[fin].min()):
        return 3.0
    pts = np.asarray(scan.points, dtype=np.float64)[fin]
    el = np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1]))
    for other in (el, None if scan.ring is None else np.asarray(scan.ring, np.float64)[fin]):
        if (
            other is not None
            and np.ptp(other) > 0
            and abs(float(np.corrcoef(inten[fin], other)[0, 1])) > 0.98
        ):
            return 4.0
    return 0.0


def _fit_candidate(
    cand: Candidate,
    pts: np.ndarray,
    inten: np.ndarray,
    ring: np.ndarray,
    board: Board,
    model: LidarModel,
    options: LidarOptions,
    rng: np.random.Generator,
    contrast: bool | None = None,
) -> BoardFit:
    """The chessboard fitted to one candidate and the points around it (the pool); every point of the
    scan is the outline's evidence (rays that pass the board's plane). contrast: False without a
    print to fit (the outline alone), None to judge from the candidate's intensities."""
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
        pts[near], inten[near], cand.normal, cand.offset, board, model, options, rng, ring=ring[near],
        scan_points=pts, contrast=contrast,
    )  # fmt: skip


def estimate_board(
    scan: Scan,
    board: Board,
    lidar_model: LidarModel | None = None,
    roi: Any | None = None,
    options: LidarOptions = LidarOptions(),
    expected: ExpectedBoard | None = None,
    correction: RangeCorrection | None = None,
) -> BoardFit:
    """Find the chessboard in one scan; its pose, covariance and inner corners in the LiDAR frame.

    scan: points (N, 3) LiDAR frame, intensity (N,) in any unit, ring (N,) in the file's numbering
    or None. lidar_model: the beam table (None: measured from this scan, ``lidars.measure``); the
    scan's rings are mapped onto it by elevation (``lidars.beam_index``); a cropped scan's by its own
    beams (``lidars.cropped_table``). An intensity that is the ring number of a scan without a ring
    field is its ring field (``lidars.with_intensity_ring``).
    roi: optional ``config.Roi`` (azimuth_deg, elevation_deg, range_m limits) narrowing the search.
    expected: optional predicted board (e.g. from the image and an extrinsic): the search keeps to
    a box around it and candidates are ranked by closeness to it; a fit beyond its tolerances is
    refused.
    correction: what the ranges read too long (the graph's estimate of the LiDAR's own errors): the
    board is found and fitted on the returns moved back along their rays by it, so that its plane and
    in-plane pose are the board's; the fit's points and returns stay the measured ones.
    Of the candidates that pass the board tests, the chessboard is fitted to at most
    ``options.max_fits`` and the fit that explains the intensities best is returned (choice.py).
    A scan whose intensity cannot show a print (``check_intensity``) is searched by the board's shape
    and fitted by its outline. Raises InputError when the scan is malformed (points or intensity of
    the wrong shape), BoardNotFound (with the reason) when no segment passes the chessboard tests or
    no fit is good.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    scan = with_intensity_ring(scan)  # an intensity that is the ring number is the ring field
    unusable = check_intensity(scan)
    pts = np.asarray(scan.points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"{scan.source or 'scan'}: points must be (N, 3), got {pts.shape}")
    # None from a caller: no intensity (zeros)
    inten = np.zeros(len(pts)) if scan.intensity is None else np.asarray(scan.intensity, np.float64)
    valid = np.isfinite(pts).all(axis=1) & (pts != 0).any(axis=1)  # (0, 0, 0): an organised "no return"
    if not valid.all():
        ring_v = None if scan.ring is None else np.asarray(scan.ring)[valid]
        scan = Scan(pts[valid], inten[valid], ring_v, scan.source, scan.columns, scan.has_intensity)
        pts, inten = scan.points, inten[valid]
    if lidar_model is None:
        lidar_model = choose_model(measure_beams(scan), None, scan.source)[0]
    lidar_model = cropped_table(scan, lidar_model)  # a cropped scan's own beams
    ring = pseudo_rings(pts) if lidar_model.ringless else beam_index(scan, lidar_model)  # no scanlines
    if correction is not None:
        pts = correction.corrected(pts, np.zeros(len(pts), np.int64) if lidar_model.ringless else ring)
    inputs = (pts, np.nan_to_num(inten), ring, board, lidar_model, roi, expected)
    found, why, unreadable = None, "", []
    if not unusable:  # the print first: the paper's search with the contrast test
        try:
            found = _search(*inputs, options, True)
        except BoardNotFound as e:
            why, unreadable = str(e), e.unreadable if isinstance(e, _NoFit) else []
    if found is None:  # the board by its shape and size, fitted by its outline
        try:  # (a candidate with a print was fitted by it above, or refused: its pattern is not a chessboard,
            # or it cannot be read: fitted by its outline here, with the others)
            found = _search(
                *inputs, replace(options, contrast_min=None), False, None if unusable else options, unreadable
            )
        except BoardNotFound as e:
            raise BoardNotFound(
                f"{why}; by its shape alone: {e}" if why and str(e) != why else str(e)
            ) from None
    score, cand, fit, n_cands, n_fitted = found
    fit = one_pseudo_beam(fit) if lidar_model.ringless else fit
    if correction is not None:
        fit = _measured(fit, correction, lidar_model)
    t_all, c_all = time.perf_counter() - t0, time.process_time() - c0
    fit.diagnostics.update(
        {"time_total_s": t_all, "cpu_total_s": c_all,
         "time_detect_s": t_all - fit.diagnostics["time_fit_s"],
         "cpu_detect_s": c_all - fit.diagnostics["cpu_fit_s"],
         "uniformity": cand.uniformity, "contrast": cand.contrast, "range_noise_m": cand.noise_sigma,
         "candidates_tested": float(cand.tested), "candidates_passed": float(n_cands),
         "candidates_fitted": float(n_fitted), "choice_score": score, "intensity_unusable": unusable}
    )  # fmt: skip
    return fit


def _measured(fit: BoardFit, correction: RangeCorrection, model: LidarModel) -> BoardFit:
    """A fit made on corrected returns with its points and returns the measured ones again (its pose,
    corners and covariance stay the corrected fit's)."""
    pts = np.asarray(fit.points_lidar, dtype=np.float64)
    ring = np.zeros(len(pts), np.int64) if model.ringless else model.ring_from_points(pts)
    c = correction.along_ray(ring, np.linalg.norm(pts, axis=1))
    fit.diagnostics["range_correction_mm"] = 1e3 * float(np.mean(c)) if len(c) else 0.0
    returns = fit.returns
    if returns is not None:
        measured = correction.corrected(returns.points, returns.ring, sign=-1.0)
        returns = replace(returns, points=measured, corrected=True)
    return replace(fit, points_lidar=correction.corrected(pts, ring, sign=-1.0), returns=returns)


def _search(
    pts: np.ndarray, inten: np.ndarray, ring: np.ndarray, board: Board, model: LidarModel, roi: Any | None,
    expected: ExpectedBoard | None, options: LidarOptions, contrast: bool | None,
    skip_printed: LidarOptions | None = None, unreadable: Sequence[Candidate] = (),
) -> tuple[float, Candidate, BoardFit, int, int]:  # fmt: skip
    """The candidates that pass the board tests, the chessboard fitted to the best few, the best fit:
    (score, candidate, fit, candidates passed, candidates fitted); BoardNotFound with the reasons.
    contrast: as ``fit_board_points`` takes it. A pattern fit must score ``min_fit_score``; an outline
    fit is refused by the outline's own rules only (``outline.refuse_outline``, the in-plane uncertainty
    in ``pose``), its score ranks it and ends the search at ``good_fit_score``.
    skip_printed: candidates whose intensities show a print (``board_tests.print_visible`` with these
    options' ``print_contrast_min``) are not fitted. unreadable: candidates whose print shows but could
    not be read (a search with the print refused them with ``board_tests.PrintUnreadable``: scanlines
    along the squares' edges), fitted by their outline beside the others (``print_unreadable`` in the
    fit's diagnostics). When no candidate fits: ``_NoFit``, with the candidates refused so."""
    rng = np.random.default_rng(0)
    mask = None if expected is None else expected_mask(pts, board, expected)
    fits: list[tuple[float, Candidate, BoardFit]] = []
    refused: list[str] = []
    unread: list[Candidate] = []  # refused with PrintUnreadable
    budget = [3 * max(1, options.max_fits)]  # fits over all batches of candidates

    def accept(cands: list[Candidate]) -> bool:
        """Fit the best few new candidates; True (stop searching) once a fit is good."""
        for cand in candidate_order(cands, pts, board, expected)[: max(1, options.max_fits)]:
            if budget[0] <= 0:
                break
            budget[0] -= 1
            if (
                skip_printed is not None
                and print_visible(
                    inten[cand.indices],
                    pts[cand.indices],
                    skip_printed.print_contrast_min,
                    ring[cand.indices],
                )[0]
            ):
                sep = intensity_contrast(inten[cand.indices])[0]
                refused.append(
                    "its intensities show a print that is not the chessboard "
                    + breach("print_contrast_min, d'", sep, ">", skip_printed.print_contrast_min)
                )
                continue
            try:
                fit = _fit_candidate(cand, pts, inten, ring, board, model, options, rng, contrast)
            except BoardNotFound as e:
                refused.append(str(e))
                if isinstance(e, PrintUnreadable):
                    unread.append(cand)
                continue
            score = fit_score(fit, board, expected)
            # an outline fit was judged by the outline's own rules (refuse_outline, the in-plane
            # uncertainty); its score only ranks it (choice.fit_score)
            if not np.isfinite(score):
                refused.append(beyond_expected(fit, board, expected))
            elif not fit.diagnostics.get("no_contrast") and score < options.min_fit_score:
                refused.append(_poor_fit(fit, board, score, options.min_fit_score))
            else:
                fits.append((score, cand, fit))
        return any(f[0] >= options.good_fit_score for f in fits) or budget[0] <= 0

    find = find_ringless_candidates if model.ringless else find_candidates
    cands = find(pts, ring, inten, board, model, roi, options, rng, mask, accept)
    for cand in unreadable:  # a print that shows but cannot be read: its outline, as without a print
        try:
            fit = _fit_candidate(cand, pts, inten, ring, board, model, options, rng, False)
        except BoardNotFound as e:
            refused.append(f"a print that cannot be read, by its outline: {e}")
            continue
        fit.diagnostics["print_unreadable"] = 1.0
        if np.isfinite(score := fit_score(fit, board, expected)):
            fits.append((score, cand, fit))
        else:
            refused.append(beyond_expected(fit, board, expected))
    if not fits:
        raise _NoFit(
            refused[0]
            if len(refused) == 1
            else f"{len(refused)} board-shaped candidates, none fits: " + "; ".join(refused[:3]),
            unread,
        )
    score, cand, fit = max(fits, key=lambda t: t[0])
    return score, cand, fit, len(cands) + len(unreadable), len(fits) + len(refused)


class _NoFit(BoardNotFound):
    """No candidate of a search fits (the reasons); ``unreadable``: those refused because their print
    shows but cannot be read (``board_tests.PrintUnreadable``), for a search by the outline."""

    def __init__(self, reason: str, unreadable: list[Candidate]) -> None:
        super().__init__(reason)
        self.unreadable = unreadable


def _poor_fit(fit: BoardFit, board: Board, score: float, limit: float) -> str:
    """Why a pattern fit scoring below ``min_fit_score`` is refused: the rule and its figures."""
    d = fit.diagnostics
    off = np.nan_to_num(fit.cost) / max(d["n_points"], 1.0) / board.square_size
    return (
        f"a board-shaped object at {d['range_m']:.2f} m, but the fitted chessboard explains it poorly: "
        f"colour agreement {d['colour_agreement']:.2f} less {off:.2f} squares off the pattern per return "
        + breach("min_fit_score", score, "<", limit)
    )
