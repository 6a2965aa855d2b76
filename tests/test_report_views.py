"""The report drawn on the views the image stage keeps (no second decode), and the page in a browser."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest
from test_report import BOARD, CAM, T_TRUE, frame_results, scene_image_and_scan

from ilcc_graph.image.previews import TIGHT, WHOLE_WIDTH, make_views, view_crop
from ilcc_graph.report import build_report
from ilcc_graph.types import Calibration


def _with_views(rng: np.random.Generator):
    frames, sources = [], []
    for f in frame_results(rng)[:3]:
        image, scan = scene_image_and_scan(rng, f.board.T_lidar_board)
        views = make_views(image, f.corners.uv, CAM)
        frames.append(dataclasses.replace(f, corners=dataclasses.replace(f.corners, views=views)))
        sources.append((f.name, scan, image))
    return frames, sources


def _decode(blob: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_COLOR)


def test_views_keep_the_windows_the_report_cuts() -> None:
    rng = np.random.default_rng(30)
    image = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    uv = np.array([[100.0, 80.0], [160.0, 80.0], [160.0, 130.0], [100.0, 130.0]])
    views = make_views(image, uv, CAM)
    assert [v.purpose for v in views] == ["tight", "wide", "whole"]
    tight = view_crop(views, "tight")
    assert tight is not None and max(tight.image.shape[:2]) <= TIGHT.max_size
    # a full-image pixel lands where the crop says: compare the content around a corner
    p = tight.to_crop(uv[:1])[0]
    z = tight.zoom
    y, x = int(round(p[1])), int(round(p[0]))
    patch = (
        tight.image[y - int(z) : y + int(z) + 1, x - int(z) : x + int(z) + 1].astype(float).mean(axis=(0, 1))
    )
    ref = image[79:82, 99:102].astype(float).mean(axis=(0, 1))
    assert np.abs(patch - ref).max() < 40  # JPEG at 95 and a 3x3 average
    whole = view_crop(views, "whole")
    assert whole is not None and whole.image.shape[1] == min(WHOLE_WIDTH, 320)


def test_report_from_views_needs_no_image_and_matches_the_one_from_the_image() -> None:
    frames, sources = _with_views(np.random.default_rng(31))
    cal = Calibration(T_TRUE, np.eye(6) * 1e-8, tuple(frames))
    from_image = build_report(cal, CAM, BOARD, iter(sources), show_valley=False)
    no_image = build_report(cal, CAM, BOARD, ((n, s, None) for n, s, _ in sources), show_valley=False)
    pictures = {k for k in from_image if k.endswith(".webp")}
    assert pictures == {k for k in no_image if k.endswith(".webp")} and len(pictures) == 15
    for k in pictures:
        a, b = _decode(from_image[k]).astype(float), _decode(no_image[k]).astype(float)
        assert a.shape == b.shape and np.abs(a - b).mean() < 4.0, k  # the views' JPEG, re-compressed


class _Page(HTMLParser):
    """Tags opened and closed, and every referenced file."""

    VOID = {"meta", "img", "br", "hr", "link", "input"}

    def __init__(self) -> None:
        super().__init__()
        self.stack: list[str] = []
        self.refs: list[str] = []
        self.errors: list[str] = []

    def handle_starttag(self, tag, attrs):  # noqa: ANN001, ANN201
        for k, v in attrs:
            if k in ("src", "href") and v and not v.startswith("#"):
                self.refs.append(v)
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):  # noqa: ANN001, ANN201
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:]}")
        else:
            self.stack.pop()


def _write(files: dict[str, bytes], out: Path) -> None:
    for rel, blob in files.items():
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        (out / rel).write_bytes(blob)


def test_report_page_is_well_formed_and_every_file_it_names_exists(tmp_path: Path) -> None:
    frames, sources = _with_views(np.random.default_rng(32))
    files = build_report(Calibration(T_TRUE, np.eye(6) * 1e-8, tuple(frames)), CAM, BOARD, iter(sources))
    _write(files, tmp_path)
    page = _Page()
    page.feed(files["index.html"].decode("utf-8"))
    assert not page.errors and page.stack == [], (page.errors, page.stack)
    assert page.refs and all((tmp_path / r).is_file() for r in page.refs)


def _browser() -> str | None:
    return next(
        (b for b in ("chromium-headless-shell", "chromium", "google-chrome") if shutil.which(b)), None
    )


def test_a_real_browser_decodes_every_picture(tmp_path: Path) -> None:
    """Headless Chromium loads the page's pictures (WebP, PNG) and reports their sizes."""
    browser = _browser()
    if browser is None:
        pytest.skip("no headless Chromium on this machine (apt-get install chromium-headless-shell)")
    frames, sources = _with_views(np.random.default_rng(33))
    files = build_report(Calibration(T_TRUE, np.eye(6) * 1e-8, tuple(frames)), CAM, BOARD, iter(sources))
    _write(files, tmp_path)
    page = _Page()
    page.feed(files["index.html"].decode("utf-8"))
    pictures = sorted({r for r in page.refs if r.endswith((".webp", ".png", ".jpg"))})
    probe = (
        "<!DOCTYPE html><html><body><pre id=out>waiting</pre><script>"
        f"const names = {pictures!r};"
        "Promise.all(names.map(n => new Promise(ok => { const i = new Image();"
        " i.onload = () => ok(n + ' ' + i.naturalWidth + 'x' + i.naturalHeight);"
        " i.onerror = () => ok(n + ' FAILED'); i.src = n; })))"
        ".then(r => { document.getElementById('out').textContent = 'done\\n' + r.join('\\n'); });"
        "</script></body></html>"
    )
    (tmp_path / "probe.html").write_text(probe)
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--allow-file-access-from-files",
           "--virtual-time-budget=10000", "--dump-dom", (tmp_path / "probe.html").as_uri()]  # fmt: skip
    dom = subprocess.run(cmd, capture_output=True, text=True, timeout=120).stdout
    lines = dom[dom.index("done") :].split("</pre>")[0].splitlines()[1:]
    assert len(lines) == len(pictures), dom[-2000:]
    for line in lines:
        name, size = line.rsplit(" ", 1)
        w, h = (int(v) for v in size.split("x"))
        assert w > 0 and h > 0, line
        assert (w, h) == _decode((tmp_path / name).read_bytes()).shape[1::-1] or name.endswith(".png")
