"""One-line diagnoses of the common set-up mistakes, from both sensors' evidence.

A wrong ``board.square_size`` or ``board.squares`` does not make a frame fail in a way that names
it: the LiDAR stage reports a board-shaped object whose pattern it cannot fit, or the image stage
no chessboard, and the run ends with "no frame has the board" (or, worse, with a few frames that
passed by chance). These checks look for the evidence and say what is likely wrong, in one line:

- ``board.square_size``: the images say the board moved k times as far between two frames as the
  scans say (``board_scale``: the distance between two poses of the board is the same in both
  sensors' frames, no extrinsic needed; from the image it scales with the configured square size);
  when no frame has the board in both sensors, the LiDAR stage is tried with scaled square sizes,
  and the scale at which both sensors agree must show the board in the scans too.
- ``board.squares``: beyond the detected corners the image shows the checker pattern going on (a
  part of a bigger print was found); or, when the images show no board, the image stage finds one
  with a square fewer on both sides (squares counted as inner corners), and so does the LiDAR stage.
- the camera's intrinsics: most images' corners do not fit a board seen through them.

The LiDAR model is checked when the scans are read (``run.source.resolve_lidar`` warns when the
measured beam table contradicts ``lidar.model``); the image size in ``run.source.check_image_size``.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from collections.abc import Callable, Sequence

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.config import Config
from ilcc_graph.datasets import FrameSource
from ilcc_graph.errors import FrameError, InputError
from ilcc_graph.evaluation.causes import SCALE_TOL, board_scale
from ilcc_graph.evaluation.pattern_check import extra_squares, pattern_continues
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.stages import StageOptions, attempt, observe_image, observe_lidar
from ilcc_graph.types import Calibration, FrameResult

log = logging.getLogger(__name__)

__all__ = ["board_scale", "diagnose_failure", "diagnose_result", "pattern_continues"]

#: square-size factors tried when the configured board is found in no scan
SCALES = (0.8, 0.85, 0.9, 0.95, 1.05, 1.1, 1.15, 1.2, 1.25)
LOOK = 3  # frames looked at per check (each check runs a stage per frame)


def _square_size_line(board: Board, k: float, evidence: str) -> str:
    """k: the print's square = k x the configured one."""
    return (
        f"board.square_size {board.square_size:g} m looks wrong: {evidence}; a square of this print is "
        f"about {k * board.square_size:.4f} m (measure one and set board.square_size)"
    )


def _dims_line(board: Board, squares: tuple[int, int], evidence: str, at_least: bool = False) -> str:
    return (
        f"board.squares [{board.rows}, {board.cols}] looks wrong: {evidence}; the print has "
        f"{'at least ' if at_least else ''}[{squares[0]}, {squares[1]}] squares (count the squares, not "
        "the inner corners, along the short and the long side)"
    )


def diagnose_result(obs: Observation, cal: Calibration, images: int = 2) -> list[str]:
    """Set-up mistakes a finished calibration shows (module docstring); one line each. Reads
    ``images`` of the used frames' images again (the pattern check)."""
    lines = []
    board = obs.config.board
    used = {f.name for f in cal.frames if f.used}
    frames = [f for f in obs.frames if f.name in used]
    both = [(f.corners, f.board.T_lidar_board) for f in obs.frames if f.corners is not None and f.board]
    scale = board_scale(both, board)
    if (
        scale is not None
        and scale[2] >= 3
        and abs(scale[0] - 1) > SCALE_TOL
        and scale[1] < abs(scale[0] - 1) / 3
    ):
        k, _, n = scale
        ev = f"the images make the board's moves between frames {k:.3f} x what the scans give ({n} pairs)"
        lines.append(_square_size_line(board, 1 / k, ev))
    source = obs.pair_source  # a rig's, or frames without their source: no image to read again
    refs = functools.cache(lambda: {} if source is None else {r.name: r for r in source.frames()})
    found = (_squares_beyond(f, obs, source, refs) for f in frames[:images] if f.corners is not None)
    extra = [e for e in found if e is not None]
    if len(extra) >= 2:
        e_rows, e_cols = (int(np.median([e[i] for e in extra])) for i in range(2))
        if e_rows or e_cols:
            n = sum(1 for e in extra if e != (0, 0))
            ev = f"beyond the detected corners the checker pattern continues ({n} of {len(extra)} images)"
            lines.append(_dims_line(board, (board.rows + e_rows, board.cols + e_cols), ev, at_least=True))
    return lines


def _squares_beyond(
    f: FrameResult, obs: Observation, source: FrameSource | None, refs: Callable[[], dict]
) -> tuple[int, int] | None:
    """The (rows, cols) of squares the checker pattern continues beyond frame ``f``'s corners: as the
    image stage found it, else from its image read again (``pattern_continues``; ``refs()``: the
    source's {name: FrameRef}, listed only then); None without one."""
    if (kept := extra_squares(f.corners)) is not None:  # type: ignore[arg-type]
        return kept
    if source is None or f.name not in refs():
        return None
    try:
        image = source.read_image(refs()[f.name])
    except InputError:
        return None
    return pattern_continues(image, obs.pair_config.board, obs.pair_config.camera, f.corners)  # type: ignore[arg-type]


def _found(results: Sequence[object]) -> int:
    return sum(1 for r in results if not isinstance(r, FrameError))


def _with_board(config: Config, board: Board) -> Config:
    return dataclasses.replace(config, board=board)


def _scaled(config: Config, k: float) -> Config:
    b = config.board
    return _with_board(
        config,
        dataclasses.replace(
            b, square_size=b.square_size * k, margin_long=b.margin_long * k, margin_short=b.margin_short * k
        ),
    )


def _square_size_search(
    obs: Observation, source: FrameSource, stages: StageOptions, refs: dict
) -> str | None:
    """When the scans show no board: the LiDAR stage with scaled square sizes, checked by the images
    (the frames read again from ``source``, the pair's, by ``refs``: {name: FrameRef}).

    A scale at which the scans show the board gives its distances; the images' distances with the
    configured board against them say the square size the print has (k_img); the scans must show
    the board at that size too.
    """
    cfg = obs.pair_config
    board = cfg.board
    frames = [
        f
        for f in obs.frames
        if f.corners is not None and f.board is None and not f.damaged and f.name in refs
    ][:LOOK]
    need = min(2, len(frames))
    if not frames:
        return None

    def lidar(k: float) -> list:
        return [attempt(observe_lidar, source, refs[f.name], _scaled(cfg, k), stages) for f in frames]

    found = next(
        ((k, fits) for k in sorted(SCALES, key=lambda x: abs(x - 1)) if _found(fits := lidar(k)) >= need),
        None,
    )
    if found is None:
        return None
    k, fits = found
    pairs = [
        (f.corners, fit.T_lidar_board)
        for f, fit in zip(frames, fits, strict=True)
        if not isinstance(fit, FrameError)
    ]
    scale = board_scale(pairs, _scaled(cfg, k).board)  # type: ignore[arg-type]
    if scale is None:
        return None
    k_img = k / scale[0]  # with square size s k, the images' moves are scale[0] x the scans'
    if abs(k_img - 1) <= SCALE_TOL or (n := _found(lidar(k_img))) < need:
        return None
    ev = (
        f"the scans show the board in none of {len(frames)} frames with it, and in {n} with the square size "
        "at which the images and the scans agree on how far the board moved between frames"
    )
    return _square_size_line(board, k_img, ev)


def _board_dims_search(obs: Observation, source: FrameSource, stages: StageOptions, refs: dict) -> str | None:
    """Other board dimensions (a square more or fewer on both sides) that both sensors prefer (the
    frames read again from ``source``, the pair's, by ``refs``: {name: FrameRef}).

    Image evidence: the image stage finds the other board where the configured one is not found,
    or the checker pattern continues beyond the corners found (``pattern_continues``). LiDAR
    evidence: the LiDAR stage finds the other board in more of the same frames.
    """
    cfg = obs.pair_config
    board = cfg.board
    usable = [f for f in obs.frames if not f.damaged and f.name in refs]
    with_corners = [f for f in usable if f.corners is not None][:LOOK]
    without = [f for f in usable if f.corners is None][:LOOK]
    beyond = (_squares_beyond(f, obs, source, lambda: refs) for f in with_corners)
    continues = [e != (0, 0) for e in beyond if e is not None]
    for rows, cols in ((board.rows + 1, board.cols + 1), (board.rows - 1, board.cols - 1)):
        if rows < 3:
            continue
        alt = _with_board(cfg, dataclasses.replace(board, rows=rows, cols=cols))
        img = _found([attempt(observe_image, source, refs[f.name], alt, stages) for f in without])
        tried = len(without)
        if rows > board.rows:
            img, tried = img + sum(continues), tried + len(continues)
        if img == 0 or img < min(2, tried):
            continue
        frames = (without + with_corners)[:LOOK]
        given = sum(f.board is not None for f in frames)
        lid = _found([attempt(observe_lidar, source, refs[f.name], alt, stages) for f in frames])
        if lid <= given:
            continue
        ev = (
            f"the images show a [{rows}, {cols}]-square chessboard in {img} of {tried} frames looked at, "
            f"the scans a board of that size in {lid} of {len(frames)} ({given} with the value given)"
        )
        return _dims_line(board, (rows, cols), ev)
    return None


def diagnose_failure(observations: Sequence[Observation], stages: StageOptions = StageOptions()) -> list[str]:
    """Set-up mistakes that explain a calibration the data cannot give; one line each (runs the
    stages again on a few frames with other board settings: seconds). The board's settings are
    searched on a pair's frames only (``Observation.pair_source``): a rig's observation, or one
    without its source, is judged on its frames' reasons alone."""
    lines: list[str] = []
    for obs in observations:
        if (source := obs.pair_source) is not None:
            refs = {r.name: r for r in source.frames()}
            found = (check(obs, source, stages, refs) for check in (_board_dims_search, _square_size_search))
            if line := next((x for x in found if x), None):
                lines.append(line)
                continue
        images = [f for f in obs.frames if f.reason and not f.damaged]
        bad_fit = [f for f in images if "seen by a pinhole" in (f.reason or "")]
        if len(bad_fit) >= max(2, len(images) // 2):
            lines.append(
                f"the camera's intrinsics look wrong: in {len(bad_fit)} of {len(images)} images the "
                "corners do not fit a flat board seen through them (check camera.K, camera.dist, the "
                "model and the image size)"
            )
    return lines
