"""The rig's report and verdict (issue 24): a small simulated rig (the backpack: two LiDARs and a
panorama, 5 moments at 1200 px) calibrated with ``calibrate_rig``; its page parsed, its pictures on
disk, the LiDAR boards on the images checked by the share of their points on the detected board
(high for the solved poses, low for a pose turned by 5 degrees), the page in headless Chromium; the
verdict on hand-made calibrations (GOOD, FAIR, POOR) and on reasons the real start and gate give."""

from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ilcc_graph.app.report_writer import write_rig_report
from ilcc_graph.board import Board
from ilcc_graph.datasets.rig_source import RigSource
from ilcc_graph.evaluation.metric import transform_points
from ilcc_graph.io.rig_results import RigCalibration
from ilcc_graph.report.rig_pictures import board_share, share_of_points
from ilcc_graph.report.rig_report import pose_cells
from ilcc_graph.report.rig_verdict import (
    DISAGREE,
    NO_DATA,
    USED,
    fate_kind,
    rig_verdict,
    rig_verdict_lines,
    sensor_standings,
)
from ilcc_graph.run import rig_calibrate
from ilcc_graph.run.rig_calibrate import RigResult, calibrate_rig, solve_observed, to_calibration
from ilcc_graph.run.rig_observe import RigObservation
from ilcc_graph.simulate.rig_export import write_rig_set
from ilcc_graph.simulate.rig_spec import backpack_rig
from ilcc_graph.types import MomentResult

VOID = {"meta", "img", "br", "hr", "link", "input", "col", "area", "base", "wbr", "source"}


class Page(HTMLParser):
    """An HTML page read strictly: every element closed in order (void elements aside); its text,
    its pictures' sources and the verdict box's text."""

    def __init__(self, html: str) -> None:
        super().__init__()
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.text: list[str] = []
        self.images: list[str] = []
        self.verdict: list[str] = []
        self._in_verdict = 0
        self.feed(html)
        self.close()
        if self.stack:
            self.errors.append(f"not closed: {self.stack}")

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "img":
            self.images.append(a["src"] or "")
        if tag in VOID:
            return
        self.stack.append(tag)
        if tag == "div" and "verdict" in (a.get("class") or ""):
            self._in_verdict = len(self.stack)

    def handle_endtag(self, tag: str) -> None:
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:] or 'nothing'}")
            return
        if self._in_verdict == len(self.stack):
            self._in_verdict = 0
        self.stack.pop()

    def handle_data(self, data: str) -> None:
        self.text.append(data)
        if self._in_verdict:
            self.verdict.append(data)


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> tuple[RigSource, RigResult, RigCalibration]:
    """A backpack rig (vlp16 the reference, os1, pano) simulated, written and calibrated."""
    folder = write_rig_set(
        tmp_path_factory.mktemp("rig") / "set", backpack_rig(width=1200, n_moments=5, seed=1)
    )
    src = RigSource(folder)
    res = calibrate_rig(src)
    assert res.sensors == ("vlp16", "os1", "pano") and not res.unsolved
    return src, res, to_calibration(res)


def _shares(res: RigResult, cal: RigCalibration, turn_deg: float) -> list[float]:
    """The share of every LiDAR board on the panorama's detected board, each LiDAR's pose turned by
    ``turn_deg`` about its own z axis."""
    obs = res.observation
    assert obs is not None
    cam = obs.rig.sensor("pano").camera
    assert cam is not None
    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec([0.0, 0.0, np.radians(turn_deg)]).as_matrix()
    out = []
    for m in obs.moments:
        for lid, fit in m.boards.items():
            T = np.linalg.inv(cal.T_ref_sensor["pano"]) @ cal.T_ref_sensor[lid] @ D
            uv = cam.project(transform_points(T, fit.points_lidar))
            out.append(board_share(uv, m.corners["pano"].uv, obs.rig.board, cam.width))
    return out


def test_the_lidar_boards_land_on_the_detected_boards(rig) -> None:  # noqa: ANN001
    """Right poses put nearly every board point on the board the camera detected; a LiDAR turned by
    5 degrees puts a third or more of them off it (measured: 98-100 % against 55-65 %)."""
    _, res, cal = rig
    right, turned = _shares(res, cal, 0.0), _shares(res, cal, 5.0)
    assert len(right) == 10
    assert min(right) > 0.95, right
    assert max(turned) < 0.75, turned
    assert max(_shares(res, cal, -5.0)) < 0.75


def test_the_report_of_a_simulated_rig(rig, tmp_path: Path) -> None:  # noqa: ANN001
    src, res, cal = rig
    page_path = write_rig_report(tmp_path / "report", cal, res.observation, src, {"data": "simulated"})
    assert page_path == tmp_path / "report" / "index.html"
    html = page_path.read_text(encoding="utf-8")
    page = Page(html)
    assert page.errors == []
    text = " ".join(page.text)
    for s in ("vlp16", "os1", "pano"):
        assert s in text
    level, _ = rig_verdict(cal)
    assert level == "GOOD" and "".join(page.verdict).startswith("GOOD:")
    assert len(page.images) == 10  # 5 moments x 2 LiDARs on the one camera
    for src_path in page.images:
        assert src_path.startswith("figures/") and (page_path.parent / src_path).stat().st_size > 1000
    # the share printed per picture is board_share's
    shares = _shares(res, cal, 0.0)
    printed = re.findall(r"<td>(\d+)%</td></tr>", html)
    assert [int(p) for p in printed] == [round(100 * s) for s in shares]
    assert "Every pair" in text and "os1 in vlp16's frame" in text
    assert text.count("used") >= 15  # every sensor at every moment


def _without(cal: RigCalibration, gone: str, why: str) -> RigCalibration:
    """``cal`` as if sensor ``gone`` had got no pose (``why``)."""
    keep = [s for s in cal.sensors if s != gone]
    idx = np.concatenate([np.arange(6 * cal.sensors.index(s), 6 * cal.sensors.index(s) + 6) for s in keep])
    moments = {m: {**d, gone: why} for m, d in cal.extra["moments"].items()}
    extra = {**cal.extra, "unsolved": {gone: why}, "moments": moments, "used": {**cal.extra["used"], gone: 0}}
    pairs = {k: v for k, v in cal.pairs.items() if gone not in k}
    T = {s: cal.T_ref_sensor[s] for s in keep}
    return RigCalibration(
        tuple(keep), cal.reference, T, cal.covariance[np.ix_(idx, idx)], pairs, cal.rig, extra
    )


def test_a_report_without_the_data_and_a_sensor_without_pose(rig, tmp_path: Path) -> None:  # noqa: ANN001
    _, res, cal = rig
    cal = _without(cal, "os1", "no usable link to the placed sensors")
    page_path = write_rig_report(tmp_path / "r", cal, res.observation, None, {})
    page = Page(page_path.read_text(encoding="utf-8"))
    text = " ".join(page.text)
    assert page.errors == [] and page.images == [] and not (tmp_path / "r" / "figures").exists()
    assert "No pictures" in text and "no pose" in text and "os1" in text
    assert "".join(page.verdict).startswith("POOR: os1: no pose (no usable link to the placed sensors)")


CHROMIUM = next((c for c in ("chromium", "chromium-browser", "google-chrome") if shutil.which(c)), None)


def _chromium(url: str, profile: Path) -> subprocess.CompletedProcess:
    argv = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
            "--enable-logging=stderr", "--v=0", "--dump-dom", "--virtual-time-budget=8000", url]  # fmt: skip
    return subprocess.run(argv, capture_output=True, text=True, timeout=120, check=True)


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium is not installed (apt-get install chromium)")
def test_the_rig_report_in_a_browser(rig, tmp_path: Path) -> None:  # noqa: ANN001
    """The page in headless Chromium: no console message, the verdict rendered, and every picture
    loads and decodes (a page beside it loads each one and says so)."""
    src, res, cal = rig
    page_path = write_rig_report(tmp_path / "report", cal, res.observation, src, {})
    got = _chromium(page_path.as_uri(), tmp_path / "profile")
    assert "CONSOLE" not in got.stderr, got.stderr
    assert "GOOD:" in got.stdout and "LiDAR boards in the images" in got.stdout
    images = re.findall(r'<img src="([^"]+)"', page_path.read_text(encoding="utf-8"))
    check = page_path.parent / "_check.html"
    check.write_text(
        "<!DOCTYPE html><html><body>"
        + "".join(f'<img src="{i}">' for i in images)
        + '<pre id="r"></pre><script>'
        'addEventListener("load",()=>{document.getElementById("r").textContent=[...document.images].map('
        'i=>i.getAttribute("src")+" "+(i.complete&&i.naturalWidth>0?"ok":"broken")).join("\\n")})'
        "</script></body></html>"
    )  # fmt: skip
    dom = _chromium(check.as_uri(), tmp_path / "profile2").stdout
    shown = re.search(r'<pre id="r">(.*?)</pre>', dom, re.S)
    assert shown is not None
    lines = shown.group(1).splitlines()
    assert [line.rsplit(" ", 1)[0] for line in lines] == images and len(images) == 10
    assert [line for line in lines if not line.endswith(" ok")] == []


# ------------------------------------------------------------------------------ the share alone
def test_share_of_points_on_a_drawn_board() -> None:
    """A board seen square-on: inner corners every 50 px; its pattern is one square (50 px) beyond
    them on every side, so points there count and points beyond do not."""
    board = Board(3, 4, 0.1)  # 2 x 3 inner corners
    i, j = np.divmod(np.arange(6), 3)
    corners = np.column_stack([200.0 + 50 * j, 100.0 + 50 * i])  # u along the long side
    inside = np.array([[160.0, 60.0], [340.0, 190.0], [250.0, 125.0], [151.0, 149.0]])
    outside = np.array([[140.0, 125.0], [360.0, 125.0], [250.0, 40.0], [250.0, 210.0], [np.nan, 100.0]])
    assert board_share(inside, corners, board) == 1.0
    assert board_share(outside, corners, board) == 0.0
    assert board_share(np.vstack([inside, outside]), corners, board) == pytest.approx(4 / 9)
    # a margin of half a square on the long side's ends and a fifth on the short side's widens it
    margin = Board(3, 4, 0.1, margin_long=0.05, margin_short=0.02)
    assert board_share(np.array([[130.0, 125.0], [250.0, 45.0]]), corners, margin) == 1.0
    assert board_share(np.array([[120.0, 125.0], [250.0, 35.0]]), corners, margin) == 0.0
    # a panorama's board across its seam (width 1000): columns 980..1030 are 980..999, 0..30
    wrapped = corners.copy()
    wrapped[:, 0] = np.mod(corners[:, 0] + 780.0, 1000.0)  # 980, 1030, 1080 -> 980, 30, 80
    pts = np.array([[np.mod(250.0 + 780.0, 1000.0), 125.0], [945.0, 125.0], [120.0, 125.0]])
    assert board_share(pts, wrapped, board, period=1000.0) == 1.0
    far = np.array([[500.0, 125.0]])  # half a panorama away
    assert board_share(far, wrapped, board, period=1000.0) == 0.0
    assert board_share(far, wrapped, board) == 1.0  # without the period the hull spans the seam's width
    assert np.isnan(share_of_points(np.zeros((0, 2)), corners[:3]))


def test_pose_cells_sigmas_match_a_monte_carlo() -> None:
    """The table's position and roll/pitch/yaw 1-sigma against the spread of poses drawn from the
    covariance (``T_true = T Exp(xi)``), for a camera turned as a lens camera is (OpenCV axes)."""
    rng = np.random.default_rng(0)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [-95.0, 3.0, -80.0], degrees=True).as_matrix()
    T[:3, 3] = [0.12, -0.30, 0.45]
    A = rng.normal(size=(6, 6))
    C = A @ A.T * 1e-5
    cells = pose_cells(T, C)
    sigmas = np.array([float(c.split("±")[1]) for c in cells])
    xi = rng.multivariate_normal(np.zeros(6), C, size=20000)
    R = Rotation.from_matrix(T[:3, :3])
    rots = R * Rotation.from_rotvec(xi[:, :3])
    rpy = rots.as_euler("xyz", degrees=True)
    pos = 1e3 * (T[:3, 3] + R.apply(xi[:, 3:]))  # Exp(xi)'s translation to first order
    drawn = np.concatenate([pos.std(axis=0), rpy.std(axis=0)])
    assert np.allclose(sigmas, drawn, rtol=0.05, atol=0.0015), (sigmas, drawn)


# ------------------------------------------------------------------------------ the verdict
def _cal(sig: dict[str, tuple[float, float]], used: dict[str, int], disagree: dict[str, int] | None = None,
         unsolved: dict[str, str] | None = None, n: int = 8) -> RigCalibration:  # fmt: skip
    """A rig 'L' (the reference) + the sensors of ``sig`` ((deg, mm) 1-sigma on every axis), with
    ``used`` moments used per sensor, ``disagree`` dropped by the gate; ``unsolved`` sensors have no pose."""
    names = ("L", *sig)
    C = np.zeros((6 * len(names), 6 * len(names)))
    for k, s in enumerate(names[1:], 1):
        deg, mm = sig[s]
        C[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] = np.diag([np.radians(deg) ** 2] * 3 + [(mm / 1e3) ** 2] * 3)
    disagree = disagree or {}
    moments = {}
    for i in range(n):
        row = {"L": USED}
        for s in (*sig, *(unsolved or {})):
            u, d = used.get(s, 0), disagree.get(s, 0)
            row[s] = USED if i < u else "chi-square gate: residual 99 > 20" if i < u + d else NO_DATA
        moments[f"{i:04d}"] = row
    extra = {"used": {"L": n, **used}, "unsolved": dict(unsolved or {}), "moments": moments}
    T = {s: np.eye(4) for s in names}
    return RigCalibration(names, "L", T, C, {}, None, extra)


def test_the_verdict_good_fair_and_poor() -> None:
    good = _cal({"C1": (0.03, 1.0), "C2": (0.08, 4.0)}, {"C1": 6, "C2": 5})
    level, text = rig_verdict(good)
    assert level == "GOOD" and text.startswith("GOOD:") and "the least sure: C2" in text
    assert "Rests on:" in text

    fair = _cal({"C1": (0.03, 1.0), "C2": (0.2, 4.0)}, {"C1": 6, "C2": 5})  # C2 above need, within 3x
    level, text = rig_verdict(fair)
    assert level == "FAIR" and text.startswith("FAIR: C2: 1-sigma up to 0.2 deg")
    assert "C1" not in text.split("Rests on")[0] and "more board poses in view of C2" in text

    odd = _cal({"C1": (0.03, 1.0)}, {"C1": 5}, disagree={"C1": 2})  # 2 of 7 disagree: over a quarter
    level, text = rig_verdict(odd)
    assert level == "FAIR" and "2 of 7 moments with the board disagree" in text
    assert "a look at the moments dropped for C1" in text

    few = _cal({"C1": (0.03, 1.0), "C2": (0.03, 1.0)}, {"C1": 6, "C2": 2})
    level, text = rig_verdict(few)
    assert level == "POOR" and text.startswith("POOR: C2: only 2 moments used")

    lost = _cal(
        {"C1": (0.03, 1.0), "C2": (0.2, 1.0)}, {"C1": 6, "C2": 6}, unsolved={"C3": "no moment shared"}
    )
    level, text = rig_verdict(lost)
    assert level == "POOR" and text.startswith("POOR: C3: no pose (no moment shared)")
    assert "Also FAIR: C2." in text and "boards that C3 and a sensor with a pose see" in text

    # a stricter need turns the good rig's worse sensor
    level, text = rig_verdict(good, need=(0.05, 5.0))
    assert level == "FAIR" and text.startswith("FAIR: C2")
    assert rig_verdict(good, need=(0.02, 5.0))[0] == "POOR"  # 0.08 deg > 3 x 0.02


def test_the_verdict_lines_fit_the_terminal() -> None:
    why = "no usable link to the placed sensors (with L: one shared moment: which half turn it is unknown)"
    wide = "front_left_wide_camera"
    cal = _cal({"C1": (0.03, 1.0), wide: (0.2, 4.0)}, {"C1": 6, wide: 2}, unsolved={"C3": why})
    lines = rig_verdict_lines(cal)
    assert all(len(line) <= 80 for line in lines), lines
    rows = [line.split()[0] for line in lines[1:] if not line.startswith(" ")]
    assert rows == ["C1", wide, "C3"]  # not the reference
    assert lines[2].split()[1:4] == ["POOR", "2", "0"] and lines[3].strip().startswith("only 2 moments used")
    assert any("no usable link" in line for line in lines)


def test_fates_of_a_real_run_are_read_right(rig) -> None:  # noqa: ANN001
    """The reasons the run gives: ``used``, no file at a moment, and a camera's corners moved by
    25 px at one moment, which the start or the gate drops as disagreeing with the LiDARs."""
    _, res, _ = rig
    obs = res.observation
    assert obs is not None and rig_calibrate.USED == USED
    cam = obs.rig.sensor("pano").camera
    assert cam is not None
    m0, m2 = obs.moments[0], obs.moments[2]
    no_pano = MomentResult(m0.name, m0.boards, {}, {}, ())
    c = m2.corners["pano"]
    uv = c.uv + np.array([25.0, 0.0])
    moved = dataclasses.replace(c, uv=uv, bearings=cam.bearing(uv))
    moments = [no_pano, obs.moments[1], MomentResult(m2.name, m2.boards, {"pano": moved}), *obs.moments[3:]]
    cal = to_calibration(solve_observed(RigObservation(obs.rig, moments)))
    fates = cal.extra["moments"]
    assert fates[m0.name]["pano"] == NO_DATA and fate_kind(NO_DATA) == "no data"
    assert fates[m2.name]["pano"].startswith(DISAGREE), fates[m2.name]
    assert fate_kind(fates[m2.name]["pano"]) == "disagrees"
    pano = next(s for s in sensor_standings(cal) if s.name == "pano")
    assert (pano.used, pano.disagree) == (3, 1)
