"""Calibrate while capturing: a verdict per frame as it arrives (``ilcc-graph check``).

Per frame: is the board found in the scan and in the image, is its pose new (not a repeat of an
earlier frame's, ``estimation.geometry``), and, once three or more distinct frames calibrate, the
running sigmas and their gap to a target. The frames so far are solved as ``calibrate`` solves
them (``prepare`` and the batch strategy: the same gate, variance components and choice of the
sensor model, ``estimation.selection``): a frame is accepted when that solve keeps it, and the
sigmas are that solve's. With few boards the noise levels rest on few residuals: their own
uncertainty widens the sigmas (``estimation.components``, the held-out factor of ``selection``),
and the verdict says so. :class:`LiveCheck` does one frame at a time; :func:`run_check` feeds it a
source's frames, or a folder being filled (``datasets.watch.GrowingFolder``), until the frames run
out, ``until`` frames were seen, the target is reached or the user interrupts (Ctrl-C).

Each frame's verdict is ready once both stages ran on it (a fraction of a second to a few seconds,
docs/bench_live.md). The print's colour (``board.lower_left``) is checked on the way: when the first
image that shows the board contradicts the config and the other colour works, the other colour is
used from then on (with a warning), as ``run.colour.check_board_colour`` does for a whole data set.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ilcc_graph.config import Config
from ilcc_graph.datasets import FrameRef, FrameSource
from ilcc_graph.errors import BoardColourMismatch, CalibrationError, FrameError
from ilcc_graph.estimation import NoiseOptions
from ilcc_graph.estimation.batch import BatchSolution
from ilcc_graph.estimation.geometry import board_geometry
from ilcc_graph.estimation.incremental import FrameUpdate
from ilcc_graph.run.colour import colour_warning, other_colour
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.pipeline import solve_observations
from ilcc_graph.run.prepare import graph_frame
from ilcc_graph.run.result import SENSOR_MODELS, Result, RunOptions
from ilcc_graph.run.source import open_run
from ilcc_graph.run.stages import StageOptions, frame_result, observe_image, observe_lidar
from ilcc_graph.run.strategies.solve_incremental import update_of
from ilcc_graph.types import Calibration, FrameResult, GraphFrame, sigmas_deg_mm, worst_sigmas

log = logging.getLogger(__name__)

__all__ = ["FEW_BOARDS", "CheckOptions", "CheckResult", "LiveCheck", "Verdict", "run_check"]

#: below this many boards in the solve, the verdict says that the noise rests on few boards
FEW_BOARDS = 6


@dataclass(frozen=True)
class Verdict:
    """What one frame gave.

    lidar / image: None when the stage found the board, else its reason. repeat_of: the earlier
    frame whose board pose this one repeats (then it is not offered to the solve). accepted: the
    solve of the frames so far keeps it. note: why not (its gate), what it waits for, or that the
    noise rests on few boards. n_frames: frames the solve uses; n_distinct: distinct board poses so
    far. sigmas: (6,) deg, deg, deg, mm, mm, mm after this frame (None before the first estimate);
    worst: the largest 1-sigma in any direction, (deg, mm) (``types.worst_sigmas``, as the verdict
    judges it). model: the sensor model the solve chose. reached: ``worst`` within the target.
    seconds: time spent on the frame; latency: from its arrival (its files complete) to the verdict.
    """

    name: str
    lidar: str | None
    image: str | None
    repeat_of: str | None = None
    accepted: bool = False
    note: str | None = None
    n_frames: int = 0
    n_distinct: int = 0
    sigmas: np.ndarray | None = None
    worst: tuple[float, float] | None = None
    model: str | None = None
    reached: bool = False
    seconds: float = 0.0
    latency: float | None = None

    @property
    def found(self) -> bool:
        """The board was found in both the scan and the image."""
        return self.lidar is None and self.image is None


@dataclass(frozen=True)
class CheckOptions:
    """How ``run_check`` runs.

    target_sigma: (deg, mm) every sigma must reach; None: no target. until: stop after this many
    frames; stop_at_target: stop when the target is reached. watch: follow a folder being filled
    (poll every ``poll_s``; a file is complete once unchanged for ``settle_s``); idle_timeout_s: in
    watch mode, stop after this long without a new frame (None: wait for Ctrl-C). sensor_model:
    ``calibrate``'s ``--sensor-model`` (``RunOptions.sensor_model``: ``auto`` chooses).
    """

    target_sigma: tuple[float, float] | None = None
    until: int | None = None
    stop_at_target: bool = True
    watch: bool = False
    poll_s: float = 0.1
    settle_s: float = 0.3
    idle_timeout_s: float | None = None
    stages: StageOptions = StageOptions()
    noise: NoiseOptions = NoiseOptions()
    sensor_model: str = "auto"

    def __post_init__(self) -> None:
        if self.sensor_model not in SENSOR_MODELS:
            raise ValueError(f"CheckOptions.sensor_model must be one of {SENSOR_MODELS}")

    def run_options(self) -> RunOptions:
        """The options ``calibrate`` would run with: its solve is the check's."""
        return RunOptions(noise=self.noise, stages=self.stages, sensor_model=self.sensor_model)


@dataclass
class CheckResult:
    """The verdicts in arrival order, the batch answer over the frames offered (None when fewer
    than three distinct poses calibrate), why the check ended, the state for advice, the frames
    whose board the final second look found (``LiveCheck.finish``) and the final answer's
    ``Calibration`` (None with ``final``)."""

    verdicts: list[Verdict]
    final: FrameUpdate | None
    stopped: str
    config: Config | None
    frames: list[GraphFrame] = field(default_factory=list)
    error: str | None = None
    second_look: list[str] = field(default_factory=list)
    calibration: Calibration | None = None


class LiveCheck:
    """One frame at a time: both stages, the repeat test, the frames so far solved as ``calibrate``
    solves them (``pipeline.solve_observations``: the same strategy, gate and model choice; its boards
    on corrected ranges and its second look once, at ``finish``)."""

    def __init__(
        self,
        config: Config,
        target_sigma: tuple[float, float] | None = None,
        options: RunOptions = RunOptions(),
    ) -> None:
        self.config = config
        self.target_sigma = target_sigma
        self.options = options
        self.stages = options.stages
        self._lidar_resolved = False
        self._colour_checked = not config.board.half_turn_symmetric
        self._distinct: list[GraphFrame] = []
        self._found: list[FrameResult] = []  # the distinct frames as the stages gave them
        self._observed: list[FrameResult] = []  # every frame as the stages gave it, in arrival order
        self._last: FrameUpdate | None = None
        self._result: Result | None = None  # the last solve's
        self._source: FrameSource | None = None
        self.second_look: list[str] = []  # frames whose board the second look found (``finish``)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="image-stage")

    @property
    def distinct(self) -> list[GraphFrame]:
        """One frame per distinct board pose (the first of each), in arrival order."""
        return list(self._distinct)

    @property
    def used(self) -> list[GraphFrame]:
        """The frames the last solve used, in the corner order it chose."""
        return [] if self._result is None else list(self._result.used_frames)

    @property
    def last(self) -> FrameUpdate | None:
        """The last solve with an estimate (``FrameUpdate.solution`` the batch answer)."""
        return self._last

    def _image(self, source: FrameSource, ref: FrameRef) -> object:
        try:
            return observe_image(source, ref, self.config, self.stages, views=False)
        except BoardColourMismatch as err:
            if self._colour_checked:
                return err
            try:
                res = observe_image(source, ref, other_colour(self.config), self.stages, views=False)
            except FrameError:
                return err
            self.config = colour_warning(self.config, f"image of frame {ref.name}")
            self._colour_checked = True
            return res
        except FrameError as err:
            return err

    def _lidar(self, source: FrameSource, ref: FrameRef) -> object:
        try:
            return observe_lidar(source, ref, self.config, self.stages)
        except FrameError as err:
            return err

    def add(self, source: FrameSource, ref: FrameRef, arrived: float | None = None) -> Verdict:
        """Both stages on ``ref``, then the repeat test and the solve of the frames so far;
        ``arrived``: the frame's arrival (``time.time()``) for the latency."""
        t0 = time.perf_counter()
        if not self._lidar_resolved:  # the run's start on the first frame (its colour checked below)
            self.config = open_run(source, self.stages, refs=[ref], config=self.config, sizes=False).config
            self._lidar_resolved = True
        image = self._pool.submit(self._image, source, ref)  # decoding and detection release the GIL
        stated = self.config.board
        board = self._lidar(source, ref)
        corners = image.result()
        if self.config.board != stated:  # the image turned the print's colour: the pattern is another
            board = self._lidar(source, ref)
        if not isinstance(corners, FrameError):
            self._colour_checked = True
        self._source = source
        fr = frame_result(ref.name, board, corners)
        self._observed.append(fr)
        last = self._last
        v = Verdict(
            ref.name,
            str(board) if isinstance(board, FrameError) else None,
            str(corners) if isinstance(corners, FrameError) else None,
            n_frames=0 if last is None else last.n_frames,
            n_distinct=len(self._distinct),
            sigmas=self._sigmas(last),
            worst=self._worst(last),
            model=None if last is None or last.solution is None else _model(last.solution),
        )
        if v.found:
            v = self._offer(v, fr)
        return self._done(v, t0, arrived)

    def _done(self, v: Verdict, t0: float, arrived: float | None) -> Verdict:
        latency = None if arrived is None else time.time() - arrived
        return dataclasses.replace(v, seconds=time.perf_counter() - t0, latency=latency)

    def _sigmas(self, u: FrameUpdate | None) -> np.ndarray | None:
        return None if u is None or u.T_cam_lidar is None else sigmas_deg_mm(u.covariance)

    def _worst(self, u: FrameUpdate | None) -> tuple[float, float] | None:
        return None if u is None or u.T_cam_lidar is None else worst_sigmas(u.covariance)

    def _offer(self, v: Verdict, fr: FrameResult) -> Verdict:
        gf = graph_frame(fr, self.config)
        geo = board_geometry([*self._distinct, gf])
        if gf.name in geo.repeats:
            return dataclasses.replace(v, repeat_of=geo.repeats[gf.name])
        self._distinct.append(gf)
        self._found.append(fr)
        n = len(self._distinct)
        got = self._solve(self._found, again=False)
        if isinstance(got, str):
            wait = n < 3
            note: str | None = f"{3 - n} more pose{'s' if 3 - n > 1 else ''} to calibrate" if wait else got
            return dataclasses.replace(v, n_distinct=n, note=note)
        update, why = got
        accepted = gf.name in update.solution.per_frame  # type: ignore[union-attr]
        note = why.get(gf.name)
        model = _model(update.solution)  # type: ignore[arg-type]
        if accepted and update.n_frames < FEW_BOARDS:
            note = f"{update.n_frames} boards: their noise levels rest on few boards (sigmas widened)"
        elif accepted and v.model is not None and model != v.model:
            note = f"sensor model now {model}"
        if geo.parallel and n >= 3:
            note = "the distinct boards all face one way: tilt the board"
        return dataclasses.replace(
            v,
            accepted=accepted,
            note=note,
            n_frames=update.n_frames,
            n_distinct=n,
            sigmas=self._sigmas(update),
            worst=self._worst(update),
            model=model,
            reached=update.reached_target,
        )

    def _solve(self, frames: list[FrameResult], again: bool) -> tuple[FrameUpdate, dict[str, str]] | str:
        """``frames`` solved as ``calibrate`` solves them (``pipeline.solve_observations``; ``again``:
        with its boards on corrected ranges and its second look): the update and why each frame not
        used was left out; or why they do not calibrate."""
        t0 = time.perf_counter()
        options = self.options
        if not again:
            options = dataclasses.replace(options, second_pass=False, range_refit=False)
        obs = Observation(self._source, self.config, list(frames), "check")
        try:
            result = solve_observations([obs], dataclasses.replace(options, mode="graph"))
        except CalibrationError as err:
            return str(err)
        cal, sol = result.calibration, result.batch
        assert sol is not None  # the batch strategy gives its solution
        update = update_of(cal, self.target_sigma, seconds=time.perf_counter() - t0, solution=sol)
        self._last, self._result = update, result
        return update, {f.name: f.reason or "" for f in cal.frames if not f.used}

    @property
    def calibration(self) -> Calibration | None:
        """The last solve's ``Calibration`` (after ``finish``: calibrate's answer on every frame seen)."""
        return None if self._result is None else self._result.calibration

    def finish(self) -> FrameUpdate | None:
        """``calibrate``'s answer on every frame seen (``pipeline.solve_observations`` on them in
        arrival order: its boards on corrected ranges and its second look included); None when they
        cannot calibrate (fewer than three distinct poses, or the solver refuses)."""
        if len(self._distinct) < 3 or self._last is None or self._source is None:
            return None
        got = self._solve(self._observed, again=True)
        if isinstance(got, str):
            log.warning("the frames seen do not calibrate together (%s)", got)
            return None
        seen = {f.name for f in self._observed if f.board is not None}
        assert self._result is not None
        final = self._result.sessions[0].observation.frames
        self.second_look = [f.name for f in final if f.board is not None and f.name not in seen]
        return self._last


def _model(sol: BatchSolution) -> str | None:
    return None if sol.selection is None else sol.selection.chosen


# ------------------------------------------------------------------------------- the loop
def _frames(
    source: FrameSource, options: CheckOptions, stop: Callable[[], str | None], idle: Callable[[float], None]
) -> Iterable[tuple[FrameRef, float | None]]:
    """(ref, arrival time) of each frame: all at once, or as a growing folder completes them."""
    if not options.watch:
        for ref in source.frames():
            if stop() is not None:
                return
            yield ref, None
        return
    last = time.monotonic()
    while stop() is None:
        got = source.poll()  # type: ignore[attr-defined]
        for a in got:
            yield a.ref, a.arrived
            last = time.monotonic()
            if stop() is not None:
                return
        if not got:
            waited = time.monotonic() - last
            if options.idle_timeout_s is not None and waited > options.idle_timeout_s:
                return
            idle(waited)
            time.sleep(options.poll_s)


def run_check(
    source: FrameSource,
    options: CheckOptions = CheckOptions(),
    on_verdict: Callable[[Verdict, LiveCheck], None] | None = None,
    on_idle: Callable[[float, LiveCheck | None], None] | None = None,
) -> CheckResult:
    """Check ``source``'s frames one by one (module docstring); ``on_verdict`` after each frame,
    ``on_idle(seconds waiting)`` while a watched folder has nothing new. Ctrl-C ends it cleanly.

    In watch mode ``source`` must have ``poll()`` (``GrowingFolder``) and its ``config.yaml`` is
    waited for. Raises InputError for a bad config.
    """
    verdicts: list[Verdict] = []
    checker: LiveCheck | None = None
    stopped = "no more frames"

    def stop() -> str | None:
        if options.until is not None and len(verdicts) >= options.until:
            return f"{options.until} frames checked"
        if options.stop_at_target and verdicts and verdicts[-1].reached:
            return "target reached"
        return None

    try:
        if options.watch:
            while not source.has_config():  # type: ignore[attr-defined]
                if on_idle is not None:
                    on_idle(0.0, None)
                time.sleep(options.poll_s)
        checker = LiveCheck(source.config(), options.target_sigma, options.run_options())
        for ref, arrived in _frames(source, options, stop, lambda w: on_idle and on_idle(w, checker)):
            v = checker.add(source, ref, arrived)
            verdicts.append(v)
            if on_verdict is not None:
                on_verdict(v, checker)
        stopped = stop() or ("idle" if options.watch else "no more frames")
    except KeyboardInterrupt:
        stopped = "interrupted"
    if checker is None:
        return CheckResult(verdicts, None, stopped, None)
    try:
        final = checker.finish()
    except KeyboardInterrupt:
        final, stopped = None, "interrupted"
    frames = checker.used if final is not None else checker.distinct
    cal = checker.calibration if final is not None else None
    looked = list(checker.second_look)
    return CheckResult(verdicts, final, stopped, checker.config, frames, second_look=looked, calibration=cal)
