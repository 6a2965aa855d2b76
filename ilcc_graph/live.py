"""Calibrate while capturing: a verdict per frame as it arrives (``ilcc-graph check``).

Per frame: is the board found in the scan and in the image, is its pose new (not a repeat of an
earlier frame's, ``estimation.geometry``), and, once three or more distinct frames calibrate, the
running sigmas (``estimation.incremental``, iSAM2, from the stated noise of the two stages) and
their gap to a target. :class:`LiveCheck` does one frame at a time; :func:`run_check` feeds it a
source's frames, or a folder being filled (``datasets.watch.GrowingFolder``), until the frames run
out, ``until`` frames were seen, the target is reached or the user interrupts (Ctrl-C).

Each frame's verdict is ready once both stages ran on it (a fraction of a second to a few seconds,
docs/bench_live.md). The print's colour (``board.lower_left``) is checked on the way: when the first
image that shows the board contradicts the config and the other colour works, the other colour is
used from then on (with a warning), as ``observe.check_board_colour`` does for a whole data set.
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
from ilcc_graph.estimation.geometry import board_geometry
from ilcc_graph.estimation.incremental import FrameUpdate, IncrementalCalibrator
from ilcc_graph.observe import StageOptions, observe_image, observe_lidar, resolve_lidar
from ilcc_graph.types import FrameResult, GraphFrame, sigmas_deg_mm

log = logging.getLogger(__name__)

__all__ = ["CheckOptions", "CheckResult", "LiveCheck", "Verdict", "run_check"]


@dataclass(frozen=True)
class Verdict:
    """What one frame gave.

    lidar / image: None when the stage found the board, else its reason. repeat_of: the earlier
    frame whose board pose this one repeats (then it is not offered to the calibrator). accepted:
    the calibrator took it. note: why not (its gate), or what it waits for. n_frames: frames in the
    calibrator's graph; n_distinct: distinct board poses so far. sigmas: (6,) deg, deg, deg, mm, mm,
    mm after this frame (None before the first estimate). reached: every sigma within the target.
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
    watch mode, stop after this long without a new frame (None: wait for Ctrl-C).
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


@dataclass
class CheckResult:
    """The verdicts in arrival order, the batch answer over the frames offered (None when fewer
    than three distinct poses calibrate), why the check ended, and the state for advice."""

    verdicts: list[Verdict]
    final: FrameUpdate | None
    stopped: str
    config: Config | None
    frames: list[GraphFrame] = field(default_factory=list)
    error: str | None = None


class LiveCheck:
    """One frame at a time: both stages, the repeat test, the incremental calibrator."""

    def __init__(
        self,
        config: Config,
        target_sigma: tuple[float, float] | None = None,
        stages: StageOptions = StageOptions(),
        noise: NoiseOptions = NoiseOptions(),
    ) -> None:
        self.config = config
        self.target_sigma = target_sigma
        self.stages = stages
        self.noise = noise
        self._lidar_resolved = False
        self._colour_checked = not config.board.half_turn_symmetric
        self._distinct: list[GraphFrame] = []
        self._calibrator = self._new_calibrator()
        self._last: FrameUpdate | None = None
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="image-stage")

    def _new_calibrator(self) -> IncrementalCalibrator:
        return IncrementalCalibrator(
            self.config.camera, self.config.board, target_sigma=self.target_sigma, noise=self.noise
        )

    @property
    def distinct(self) -> list[GraphFrame]:
        """One frame per distinct board pose (the first of each), in arrival order."""
        return list(self._distinct)

    @property
    def calibrator(self) -> IncrementalCalibrator:
        return self._calibrator

    @property
    def last(self) -> FrameUpdate | None:
        """The calibrator's last update with an estimate."""
        return self._last

    def _image(self, source: FrameSource, ref: FrameRef) -> object:
        try:
            return observe_image(source, ref, self.config, self.stages.image, views=False)
        except BoardColourMismatch as err:
            if self._colour_checked:
                return err
            board = self.config.board
            other = "white" if board.lower_left == "black" else "black"
            flipped = dataclasses.replace(self.config, board=dataclasses.replace(board, lower_left=other))
            try:
                res = observe_image(source, ref, flipped, self.stages.image, views=False)
            except FrameError:
                return err
            log.warning(
                "%s: board.lower_left is %s, but the print's lower-left square is %s in frame %s; using %s",
                self.config.source,
                board.lower_left,
                other,
                ref.name,
                other,
            )
            self.config = flipped
            self._colour_checked = True
            self._calibrator = self._new_calibrator()  # nothing was offered yet: no image agreed before
            return res
        except FrameError as err:
            return err

    def add(self, source: FrameSource, ref: FrameRef, arrived: float | None = None) -> Verdict:
        """Both stages on ``ref``, then the repeat test and the calibrator; ``arrived``: the frame's
        arrival (``time.time()``) for the latency."""
        t0 = time.perf_counter()
        if not self._lidar_resolved:
            self.config = resolve_lidar(source, [ref], self.config, look=1)
            self._lidar_resolved = True
            self._calibrator = self._new_calibrator()
        image = self._pool.submit(self._image, source, ref)  # decoding and detection release the GIL
        stated = self.config.board
        try:
            board = observe_lidar(source, ref, self.config, self.stages.lidar)
        except FrameError as err:
            board = err
        corners = image.result()
        if self.config.board != stated:  # the image turned the print's colour: the pattern is another
            try:
                board = observe_lidar(source, ref, self.config, self.stages.lidar)
            except FrameError as err:
                board = err
        if not isinstance(corners, FrameError):
            self._colour_checked = True
        lidar_why = str(board) if isinstance(board, FrameError) else None
        image_why = str(corners) if isinstance(corners, FrameError) else None
        v = Verdict(
            ref.name,
            lidar_why,
            image_why,
            n_frames=len(self._calibrator.frames),
            n_distinct=len(self._distinct),
            sigmas=self._sigmas(self._last),
        )
        if v.found:
            fr = FrameResult(ref.name, True, None, board, corners)  # type: ignore[arg-type]
            v = self._offer(v, fr)
        return self._done(v, t0, arrived)

    def _done(self, v: Verdict, t0: float, arrived: float | None) -> Verdict:
        latency = None if arrived is None else time.time() - arrived
        return dataclasses.replace(v, seconds=time.perf_counter() - t0, latency=latency)

    def _sigmas(self, u: FrameUpdate | None) -> np.ndarray | None:
        return None if u is None or u.T_cam_lidar is None else sigmas_deg_mm(u.covariance)

    def _offer(self, v: Verdict, fr: FrameResult) -> Verdict:
        assert fr.board is not None and fr.corners is not None
        gf = GraphFrame(
            fr.name,
            fr.board.T_lidar_board,
            fr.board.covariance,
            self.config.board.corners_board(),
            fr.corners.bearings,
            fr.corners.cov_px,
            fr.board.returns,
            fr.corners.uv,
        )
        geo = board_geometry([*self._distinct, gf])
        if gf.name in geo.repeats:
            return dataclasses.replace(v, repeat_of=geo.repeats[gf.name])
        self._distinct.append(gf)
        try:
            u = self._calibrator.add_frame(fr)
        except CalibrationError as err:  # e.g. no frame left to initialise
            return dataclasses.replace(v, n_distinct=len(self._distinct), note=str(err))
        if u.T_cam_lidar is not None and u.accepted:
            self._last = u
        note = u.reason
        if geo.parallel and len(self._distinct) >= 3:
            note = "the distinct boards all face one way: tilt the board"
        return dataclasses.replace(
            v,
            accepted=u.accepted,
            note=note,
            n_frames=u.n_frames,
            n_distinct=len(self._distinct),
            sigmas=self._sigmas(self._last),
            reached=bool(self._last is not None and self._last.reached_target),
        )

    def finish(self) -> FrameUpdate | None:
        """The batch answer (the core's noise policy) on every frame offered; None when they cannot
        calibrate (fewer than three distinct poses, or the solver refuses)."""
        if len(self._distinct) < 3:
            return None
        try:
            return self._calibrator.finish()
        except CalibrationError as err:
            log.warning("the frames so far do not calibrate: %s", err)
            return None


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
        checker = LiveCheck(source.config(), options.target_sigma, options.stages, options.noise)
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
    frames = checker.calibrator.offered if final is not None else checker.distinct
    return CheckResult(verdicts, final, stopped, checker.config, frames)
