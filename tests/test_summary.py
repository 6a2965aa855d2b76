"""The closing summary of ``calibrate``: its numbers, its verdict rule, and how it looks in a real
80-column terminal (tmux)."""

from __future__ import annotations

import dataclasses
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from ilcc_graph.cameras import R_FLU_OPENCV
from ilcc_graph.report.summary import NEED_DEG_MM, camera_in_lidar, lidar_in_camera, verdict
from ilcc_graph.types import BoardFit, Calibration, FrameResult, ImageCorners


def _rig(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A lens camera 25 cm above the LiDAR looking roughly along its x axis, and a covariance."""
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(np.radians(rng.normal(0, 5, 3))).as_matrix() @ R_FLU_OPENCV.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, -R @ np.array([0.08, -0.02, 0.25])
    A = rng.normal(size=(6, 6)) * np.r_[np.full(3, 1e-3), np.full(3, 3e-3)]
    return T, A @ A.T


def test_poses_and_their_sigmas_match_a_monte_carlo():
    """The camera's position and viewing direction in the LiDAR frame and the LiDAR's position in
    the camera frame, computed here from sampled extrinsics ``T Exp(xi)``, ``xi ~ N(0, C)``: means
    and spreads as the summary states them."""
    T, C = _rig(0)
    p, ps, ang, angs = camera_in_lidar(T, C, R_FLU_OPENCV)
    q, qs, _, _, rs = lidar_in_camera(T, C)
    rng = np.random.default_rng(1)
    xis = rng.multivariate_normal(np.zeros(6), C, 8000)
    # T Exp(xi) with SE(3)'s exponential written out: rotation Exp(w), translation V(w) v
    w, v = xis[:, :3], xis[:, 3:]
    th = np.linalg.norm(w, axis=1)[:, None, None]
    W = np.cross(w[:, None, :], -np.eye(3)[None])  # [w]x, one per sample
    V = np.eye(3) + (1 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * W @ W
    R0, t0 = T[:3, :3], T[:3, 3]
    R = R0 @ Rotation.from_rotvec(w).as_matrix()
    t = t0 + np.einsum("ij,nj->ni", R0, np.einsum("nij,nj->ni", V, v))
    pos = -np.einsum("nji,nj->ni", R, t)
    forward = R[:, 2, :]  # optical z in LiDAR axes (a row of R)
    left = -R[:, 0, :]
    az, el = np.arctan2(forward[:, 1], forward[:, 0]), np.arcsin(forward[:, 2])
    level = np.cross([0.0, 0.0, 1.0], forward)  # the left axis of a camera with no roll
    level /= np.linalg.norm(level, axis=1, keepdims=True)
    roll = np.arctan2(np.sum(np.cross(level, left) * forward, axis=1), np.sum(level * left, axis=1))
    view = np.degrees(np.c_[az, el, roll])
    lid = t
    rot = Rotation.from_matrix(R @ R0.T).as_rotvec()  # the turn on the camera side
    np.testing.assert_allclose(p, 1e3 * pos.mean(axis=0), atol=0.05)
    np.testing.assert_allclose(ps, 1e3 * pos.std(axis=0), rtol=0.05)
    np.testing.assert_allclose(ang, view.mean(axis=0), atol=0.01)
    np.testing.assert_allclose(angs, view.std(axis=0), rtol=0.05)
    np.testing.assert_allclose(qs, 1e3 * lid.std(axis=0), rtol=0.05)
    np.testing.assert_allclose(rs, np.degrees(rot.std(axis=0)), rtol=0.05)
    np.testing.assert_allclose(q, 1e3 * T[:3, 3])


def _calibration(
    sigma_deg: float, sigma_mm: float, used: int, disagree: int, missing: int = 0
) -> Calibration:
    C = np.diag([math.radians(sigma_deg)] * 3 + [1e-3 * sigma_mm] * 3) ** 2
    board = BoardFit(np.eye(4), np.eye(6), np.zeros((35, 3)), np.zeros((0, 3)), np.zeros(0), False)
    corners = ImageCorners(np.zeros((35, 2)), np.zeros((35, 3)), np.zeros((35, 2, 2)), False)
    frames = [FrameResult(f"u{i}", True, None, board, corners) for i in range(used)]
    frames += [FrameResult(f"d{i}", False, "chi-square gate", board, corners) for i in range(disagree)]
    frames += [FrameResult(f"m{i}", False, "no board in the scan") for i in range(missing)]
    return Calibration(np.eye(4), C, tuple(frames))


def test_the_verdict_rule():
    deg, mm = NEED_DEG_MM
    level = lambda *a, **k: verdict(_calibration(*a), **k)[0]  # noqa: E731
    assert level(0.9 * deg, 0.9 * mm, 19, 1) == "GOOD"
    assert level(0.9 * deg, 0.9 * mm, 12, 0, 8) == "GOOD"  # frames without a board say nothing against it
    assert level(1.5 * deg, 0.9 * mm, 19, 1) == "FAIR"  # sigma above the need
    assert level(0.9 * deg, 0.9 * mm, 3, 0) == "FAIR"  # too few frames
    assert level(0.9 * deg, 0.9 * mm, 12, 5) == "FAIR"  # more than a quarter disagree
    assert level(0.9 * deg, 3.5 * mm, 19, 1) == "POOR"
    assert level(0.9 * deg, 0.9 * mm, 5, 6) == "POOR"
    assert level(0.9 * deg, 0.9 * mm, 2, 0) == "POOR"
    assert level(0.04, 0.9, 19, 1, need=(0.05, 1.0)) == "GOOD"  # the run's own target
    assert level(0.06, 0.9, 19, 1, need=(0.05, 1.0)) == "FAIR"
    text = verdict(_calibration(0.9 * deg, 0.9 * mm, 19, 1))[1]
    assert text.startswith("GOOD: 19 of 20 frames agree with the result within their noise")
    assert "Rests on: each frame's residuals pass a chi-square test (99.9 %)" in text
    paper = _calibration(0.05, 1.0, 5, 0)
    paper = Calibration(paper.T_cam_lidar, np.full((6, 6), np.nan), paper.frames, "paper")
    assert verdict(paper)[0] == "NO UNCERTAINTY"


def test_the_verdict_names_the_cause_of_residuals_far_above_the_stated_noise():
    """Image corners 3 x their stated sigma (component 9) with 1-sigma above the need: the verdict says
    more poses will not mend it and names the cause the run found, or what to check when none showed,
    instead of asking for more poses; at the recorded sets' 1.6 it asks for more poses as before."""
    cal = _calibration(0.15, 0.9, 19, 1)
    diag = {"variance_component_board": 2.0, "variance_component_bearing": 9.0}
    cause = "synchronisation: the images of 0003, 0004 fit a flat board as their stated noise says"
    named = dataclasses.replace(cal, diagnostics=diag, causes=(cause,))
    level, text = verdict(named)
    assert level == "FAIR" and "More board poses would help" not in text, text
    assert "far above the detectors' stated noise (image corners 3.0 x their stated sigma)" in text, text
    assert f"more poses will not mend that. Likely: {cause}." in text, text
    unnamed = verdict(dataclasses.replace(named, causes=()))[1]
    assert "no cause shows in the frames: check the camera's intrinsics" in unnamed, unnamed
    lidar = dataclasses.replace(cal, diagnostics={"variance_component_board": 25.0}, causes=(cause,))
    assert "(LiDAR board poses 5.0 x their stated sigma)" in verdict(lidar)[1]
    usual = verdict(dataclasses.replace(cal, diagnostics={"variance_component_bearing": 1.6}))[1]
    assert "More board poses would help" in usual and "far above" not in usual, usual


# ------------------------------------------------------------------ a real terminal, a real browser
def _tmux(cwd: Path, command: str, timeout: float = 300.0) -> list[str]:
    """Run ``command`` in a detached tmux session 80 columns wide; every line it showed (wrapped
    rows joined back, so a line longer than the window shows as such)."""
    name = f"ilcc-summary-{os.getpid()}"
    log = cwd / "exit_code"
    shell = f"cd {shlex.quote(str(cwd))} && {command}; echo $? > {shlex.quote(str(log))}; sleep 600"
    subprocess.run(["tmux", "new-session", "-d", "-s", name, "-x", "80", "-y", "50", shell], check=True)
    try:
        t0 = time.monotonic()
        while not log.exists() or not log.read_text().strip():
            assert time.monotonic() - t0 < timeout, "the command did not finish in the terminal"
            time.sleep(0.5)
        width = subprocess.run(["tmux", "display", "-p", "-t", name, "#{window_width}"], capture_output=True,
                               text=True, check=True).stdout.strip()  # fmt: skip
        capture = ["tmux", "capture-pane", "-p", "-J", "-S", "-", "-t", name]
        pane = subprocess.run(capture, capture_output=True, text=True, check=True).stdout
    finally:
        subprocess.run(["tmux", "kill-session", "-t", name], check=False)
    assert width == "80" and log.read_text().strip() == "0", pane
    return pane.rstrip("\n").splitlines()


@pytest.fixture(scope="module")
def run(simulated, tmp_path_factory) -> tuple[Path, list[str] | None]:
    """``ilcc-graph calibrate data --out out --jobs 2 --studies`` on a small pinhole set whose frame 0003
    has a blank image, in tmux at 80 columns: (the folder holding ``out``, the lines shown; None without
    tmux, then run without a terminal). The studies' solves run on the two processes."""
    cwd = tmp_path_factory.mktemp("terminal")
    shutil.copytree(simulated("pinhole", frames=6), cwd / "data")
    blank = np.full_like(cv2.imread(str(cwd / "data/img/0003.png")), 128)
    cv2.imwrite(str(cwd / "data/img/0003.png"), blank)
    argv = ["calibrate", "data", "--out", "out", "--jobs", "2", "--studies"]
    if shutil.which("tmux") is None:
        subprocess.run(
            [sys.executable, "-m", "ilcc_graph.app", *argv], cwd=cwd, check=True, capture_output=True
        )
        return cwd, None
    return cwd, _tmux(cwd, " ".join(shlex.quote(a) for a in [sys.executable, "-m", "ilcc_graph.app", *argv]))


def test_the_summary_in_an_80_column_terminal(run):
    """The verdict first, the poses, the report's path, the frame not used on one line, nothing
    wider than the window, no warning or log line from the run's inside."""
    cwd, lines = run
    if lines is None:
        pytest.skip("tmux is not installed (apt-get install tmux): the terminal is not checked")
    text = "\n".join(lines)
    assert all(len(line) <= 80 for line in lines), max(lines, key=len)
    first = next(line for line in lines if line.strip())
    assert first.startswith("GOOD: 5 of 6 frames agree with the result within their noise"), text
    assert sum("0003" in line for line in lines) == 1 and any(
        line.startswith("not used 0003") for line in lines
    )
    for needed in ("camera in the LiDAR frame", "LiDAR in the camera frame", "position mm", "optical axis"):
        assert needed in text
    assert "report:  out/report/index.html" in lines and (cwd / "out/report/index.html").is_file()
    assert any(line.startswith("time:    calibrated in ") for line in lines)
    for unwanted in ("Warning", "Traceback", "INFO", "DEBUG"):
        assert unwanted not in text
    # the numbers printed are the file's
    T = np.array(yaml.safe_load((cwd / "out/calibration.yaml").read_text())["T_cam_lidar"])
    x = float(next(line for line in lines if line.startswith("  position mm")).split()[3])
    assert x == pytest.approx(1e3 * (-T[:3, :3].T @ T[:3, 3])[0], abs=0.06)


def test_the_studies_on_two_processes_draw_what_one_process_draws(run):
    """The report's studies (frames against accuracy, cross-validation), solved on two processes in
    the terminal's run, are the same to the byte as when solved one after another in one process."""
    cwd, _ = run
    one = cwd / "out-one-process"
    argv = ["calibrate", "data", "--out", one.name, "--jobs", "1", "--studies"]
    subprocess.run([sys.executable, "-m", "ilcc_graph.app", *argv], cwd=cwd, check=True, capture_output=True)
    studies = ("frames_vs_error.png", "frames_vs_parameters.png", "cross_validation.png")
    for name in studies:
        two = (cwd / "out/report/figures" / name).read_bytes()
        assert two == (one / "report/figures" / name).read_bytes(), name
    page = (cwd / "out/report/index.html").read_text()
    same = page.replace("--out out --jobs 2", f"--out {one.name} --jobs 1")
    assert same == (one / "report/index.html").read_text()


CHROMIUM = next((c for c in ("chromium", "chromium-browser", "google-chrome") if shutil.which(c)), None)


def _chromium(url: str, profile: Path, *flags: str) -> subprocess.CompletedProcess:
    argv = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
            "--enable-logging=stderr", "--v=0", *flags, url]  # fmt: skip
    return subprocess.run(argv, capture_output=True, text=True, timeout=120, check=True)


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium is not installed (apt-get install chromium)")
def test_the_report_in_a_browser(run, tmp_path):
    """The report of that run in headless Chromium: no console message, and every picture it shows
    loads and decodes (a page beside it loads each one and says so)."""
    report = run[0] / "out" / "report"
    page = (report / "index.html").read_text()
    got = _chromium(
        (report / "index.html").as_uri(), tmp_path / "profile", "--dump-dom", "--virtual-time-budget=5000"
    )
    assert "CONSOLE" not in got.stderr, got.stderr
    assert "Where to hold the board next" in got.stdout and "Stability" in got.stdout
    assert "CalibrationImpossible" not in got.stdout and "3 sigma</th>" not in got.stdout
    images = re.findall(r'<img src="([^"]+)"', page)
    assert len(images) >= 20 and "figures/next_pose.png" in images
    assert any(i.endswith("_range.webp") for i in images) and any(i.endswith("_edges.webp") for i in images)
    check = report / "_check.html"
    check.write_text(
        "<!DOCTYPE html><html><body>"
        + "".join(f'<img src="{i}">' for i in images)
        + '<pre id="r"></pre><script>'
        'addEventListener("load",()=>{document.getElementById("r").textContent=[...document.images].map('
        'i=>i.getAttribute("src")+" "+(i.complete&&i.naturalWidth>0?"ok":"broken")).join("\\n")})'
        "</script></body></html>"
    )  # fmt: skip
    try:
        dom = _chromium(
            check.as_uri(), tmp_path / "profile2", "--dump-dom", "--virtual-time-budget=10000"
        ).stdout
    finally:
        check.unlink()
    shown = re.search(r'<pre id="r">(.*?)</pre>', dom, re.S).group(1).splitlines()
    assert [line.rsplit(" ", 1)[0] for line in shown] == images
    assert [line for line in shown if not line.endswith(" ok")] == []


def test_a_stage_table_of_long_reasons_fits_80_columns() -> None:
    """``lidar-corners`` / ``image-corners`` tables: a reason of hundreds of characters (the LiDAR
    stage's, on a real scan) wraps under its column; no line and no rule is wider than 80 columns."""
    from ilcc_graph.report.text import STAGE_HEADERS, format_table

    reason = "no segment passed the chessboard tests (43 board-sized candidates); " * 12
    text = format_table([("pose01", "no", 12, reason), ("pose02", "yes", 4000, "")], STAGE_HEADERS["lidar"])
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 80, text
    assert " ".join(" ".join(line[23:].split()) for line in lines[2:-1]) == " ".join(reason.split())
    assert lines[-1].split() == ["pose02", "yes", "4000"]
