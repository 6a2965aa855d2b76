"""What several benchmark scripts share: processes from /proc (the package's), a block of a doc
between markers, today's code extracted beside this tree, and a sink of results (one JSON object a
line, appended as each finishes, so a run can be stopped and resumed)."""

from __future__ import annotations

import json
import subprocess
import tempfile
from pathlib import Path

from ilcc_graph.workers import processes_where

__all__ = ["append_sink", "baseline_tree", "load_sink", "observe_frame", "processes_where", "write_between"]


def load_sink(path: Path) -> list[dict]:
    """The results in a sink (one JSON object a line); none when it does not exist."""
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def append_sink(path: Path, row: dict) -> None:
    """Append one result to a sink."""
    with path.open("a", encoding="utf-8") as fh:
        fh.write(json.dumps(row) + "\n")


def write_between(doc: Path, begin: str, end: str, text: str) -> None:
    """Put ``text`` between the ``begin`` and ``end`` markers of ``doc`` (appended with them if absent)."""
    body = doc.read_text() if doc.is_file() else ""
    block = f"{begin}\n{text}\n{end}"
    if begin in body and end in body:
        head, rest = body.split(begin, 1)
        body = head + block + rest.split(end, 1)[1]
    else:
        body = body.rstrip() + "\n\n" + block + "\n"
    doc.write_text(body)


def baseline_tree(root: Path, baseline: str | None, prefix: str) -> tuple[str, str, Path, Path]:
    """(today's revision, this tree's short HEAD, a new work folder, today's code extracted in it):
    ``baseline`` (a git revision; None: the merge-base with main) from the repository at ``root``,
    with ``git archive``, into ``<work>/baseline``."""
    git = ["git", "-C", str(root)]
    rev = baseline or subprocess.run(
        git + ["merge-base", "HEAD", "main"], capture_output=True, text=True, check=True
    ).stdout.strip()
    head = subprocess.run(
        git + ["rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    work = Path(tempfile.mkdtemp(prefix=prefix))
    base = work / "baseline"
    base.mkdir()
    arch = subprocess.run(git + ["archive", rev], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(base)], input=arch, check=True)
    return rev, head, work, base


def observe_frame(spec, renderer, biases, i: int, T_lidar_board):  # noqa: ANN001, ANN201 - simulate's types
    """Frame ``i`` of a simulated set (board at ``T_lidar_board``) through the pipeline's per-frame
    stages: its image's corners and its scan's board fit, a ``FrameError`` of either recorded as the
    frame's reason (a ``types.FrameResult`` named ``0001`` for i = 0)."""
    from ilcc_graph.errors import FrameError
    from ilcc_graph.image import detect_corners
    from ilcc_graph.lidar import estimate_board
    from ilcc_graph.simulate import frame_scene, simulate_scan
    from ilcc_graph.types import FrameResult

    scene = frame_scene(spec, T_lidar_board, i)
    reasons, fit, corners = [], None, None
    try:
        corners = detect_corners(renderer.render(scene, i), spec.camera, spec.board)
    except FrameError as err:
        reasons.append(f"image: {err}")
    try:
        fit = estimate_board(simulate_scan(spec, scene, i, biases), spec.board, spec.lidar_model)
    except FrameError as err:
        reasons.append(f"LiDAR: {err}")
    return FrameResult(f"{i + 1:04d}", not reasons, "; ".join(reasons) or None, board=fit, corners=corners)
