"""``ilcc-graph demo`` says what it stores, where and how big, and stores the images as JPEG (a sixth
of the PNG's bytes, the same corners: docs/bench_demo.md); its data set is an output folder of ours.
"""

from __future__ import annotations

import re

import yaml

from ilcc_graph.app import main
from ilcc_graph.io.output_folders import MARKER


def test_the_demo_says_what_it_stores(tmp_path, capsys):
    cache, out = tmp_path / "cache", tmp_path / "out"
    argv = ["demo", "--width", "1200", "--cache", str(cache), "--out", str(out), "--no-report", "--jobs", "1"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    data = cache / "demo-hdl32-equirect1200-seed0"
    stored = [ln for ln in printed.splitlines() if ln.startswith("kept in ")]
    assert len(stored) == 1 and str(data) in stored[0] and "deletable" in stored[0], printed
    size = sum(p.stat().st_size for p in data.rglob("*") if p.is_file()) / 1e6
    assert re.search(r"\((\d+) MB", stored[0]).group(1) == f"{size:.0f}"
    images = sorted(p.name for p in (data / "img").iterdir())
    assert len(images) == 20 and all(n.endswith(".jpg") for n in images)
    assert yaml.safe_load((data / MARKER).read_text())["kind"] == "data set"
    assert (out / "calibration.yaml").is_file()
    assert "truth" in printed  # the result beside the simulated truth
