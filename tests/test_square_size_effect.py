"""What the board's printed scale moves (``estimation.effects.square_size_effect``)."""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
from test_board_plane import CAMERA, T_TRUE, bent_frames

from ilcc_graph.estimation import NoiseOptions
from ilcc_graph.estimation.effects import SCALE_STEP, SQUARE_SIZE_KEY, square_size_effect
from ilcc_graph.estimation.keys import L, X
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.noise import solve_problem
from ilcc_graph.estimation.problem import frames_problem
from ilcc_graph.report.sensors import square_size_text
from ilcc_graph.types import Calibration


def _resolved_with_scale(sol, k: float):
    """The same boards solved again (components fixed) with the views' board points scaled by k
    about the pattern's centre."""
    pts = np.concatenate([v.points_board for v in sol.problem.views])
    c = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    views = tuple(replace(v, points_board=c + k * (v.points_board - c)) for v in sol.problem.views)
    names = [sol.problem.boards[i].name for i in sol.boards]
    return solve_problem(replace(sol.problem, views=views), NoiseOptions(), boards=names, scales=sol.scales,
                         variance_factor=sol.variance_factor, gate=False)  # fmt: skip


def _camera_position(T: gtsam.Pose3) -> np.ndarray:
    R, t = T.rotation().matrix(), T.translation()
    return -R.T @ t


def test_square_size_effect_is_what_a_re_solve_with_a_bigger_print_gives() -> None:
    """The first-order move per 0.1 % matches re-solves with the print 0.5 % larger and smaller
    (central difference), for the extrinsic and the beams' common level (terms on), and without the
    LiDAR's terms."""
    rng = np.random.default_rng(5)
    frames = bent_frames(rng, 10, (0.002, np.radians(0.2)))
    T0 = T_TRUE.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))).matrix()
    for lo in (LidarErrorOptions(board_plane_estimate=True), None):
        sol = solve_problem(frames_problem(frames, CAMERA, T0, lidar_errors=lo), NoiseOptions())
        eff = square_size_effect(sol)
        h = 5e-3
        up, down = _resolved_with_scale(sol, 1 + h), _resolved_with_scale(sol, 1 - h)
        Tu, Td = up.values.atPose3(X(0)), down.values.atPose3(X(0))
        per = SCALE_STEP / (2 * h)
        rot = np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(Td.rotation().between(Tu.rotation())))) * per
        trans = 1e3 * np.linalg.norm(_camera_position(Tu) - _camera_position(Td)) * per
        assert trans > 0.05, trans  # the print's scale moves this extrinsic measurably
        assert abs(eff.extrinsic.translation_mm - trans) < 0.1 * trans, (eff, trans)
        assert abs(eff.extrinsic.rotation_deg - rot) < 0.1 * rot + 1e-5, (eff, rot)
        if lo is None:
            assert eff.beams_mm is None
            continue
        names = sol.assembly.layouts[0].names
        idx = [k for k, n in enumerate(names) if n.startswith("offset")]
        common = 1e3 * per * float(np.mean((up.values.atVector(L(0)) - down.values.atVector(L(0)))[idx]))
        assert abs(eff.beams_mm - common) < 0.1 * abs(common), (eff.beams_mm, common)
        # the beams' common level is measured against the print: ~0.1 % of the boards' range
        rng_mm = 1e3 * np.mean([np.linalg.norm(f.T_lidar_board[:3, 3]) for f in frames])
        assert 0.3 * 1e-3 * rng_mm < abs(eff.beams_mm) < 2.0 * 1e-3 * rng_mm, (eff.beams_mm, rng_mm)


def test_the_report_line_says_what_precision_the_square_size_needs() -> None:
    cal = Calibration(np.eye(4), np.eye(6), ())
    assert square_size_text(cal) == ""
    diag = {f"{SQUARE_SIZE_KEY}_rotation_deg": 0.02, f"{SQUARE_SIZE_KEY}_translation_mm": 2.76,
            f"{SQUARE_SIZE_KEY}_sigmas": 1.25, f"{SQUARE_SIZE_KEY}_beams_mm": -2.4}  # fmt: skip
    line = square_size_text(Calibration(np.eye(4), np.eye(6), (), diagnostics=diag))
    assert "2.76 mm (1.25 sigma)" in line and "-2.40 mm" in line and "0.08 %" in line, line
