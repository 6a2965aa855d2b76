"""``ilcc-graph check``: the live table, the progress line, the advice, what is written.

The check itself is ``live``; this module prints it (the table on standard output, the progress
line on standard error, redrawn in place on a terminal) and writes ``check.yaml`` and
``next_pose.png`` through ``write``. ``cmd_check`` is the command (its flags, its folder).
Every line printed fits ``WIDTH`` columns: a frame's note goes on indented lines below its row,
longer text is wrapped (the full notes are in check.yaml).
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

from ilcc_graph.app.console import WIDTH, stdout_closed, wrapped
from ilcc_graph.config import Config
from ilcc_graph.errors import InputError
from ilcc_graph.estimation.incremental import FrameUpdate
from ilcc_graph.report.text import lidar_view_lines
from ilcc_graph.run.live import CheckOptions, LiveCheck, Verdict, run_check
from ilcc_graph.types import GraphFrame, sigmas_deg_mm, target_gap

if TYPE_CHECKING:  # next_pose is imported when advice is asked for
    from ilcc_graph.next_pose import Advisor, Proposal

__all__ = [
    "VERDICT_HEADER",
    "WIDTH",
    "LiveAdvice",
    "StatusLine",
    "check_command",
    "format_progress",
    "format_verdict",
]


# ----------------------------------------------------------------------------- printing
#: the columns of :func:`format_verdict` (a row's note follows on lines indented by ``_NOTE_INDENT``)
VERDICT_HEADER = (
    f"{'frame':<10s} {'scan':<4s} {'image':<5s} {'pose':<10s} {'n':>3s} "
    f"{'rot deg':>8s} {'trans mm':>8s} {'target':>13s} {'latency':>7s}"
)
_NOTE_INDENT = " " * 11  # under the scan column
_NOTE_LINES = 3  # a longer note ends with " [...]"; check.yaml has it whole


def _more(n_distinct: int) -> str:
    k = max(0, 3 - n_distinct)
    return "" if k == 0 else f"{k} more pose" + ("s" if k > 1 else "")


def _short(text: str, n: int = WIDTH - 1) -> str:
    text = " ".join(text.split())
    return text if len(text) <= n else text[: n - 3] + "..."


def _note_lines(note: str) -> list[str]:
    """A row's note on at most ``_NOTE_LINES`` lines of ``WIDTH`` columns, indented."""
    return textwrap.wrap(
        " ".join(note.split()),
        WIDTH,
        initial_indent=_NOTE_INDENT,
        subsequent_indent=_NOTE_INDENT,
        max_lines=_NOTE_LINES,
        placeholder=" [...]",
    )


def format_verdict(v: Verdict, target: tuple[float, float] | None = None) -> str:
    """One table row (``VERDICT_HEADER``): found in scan / image, pose new or a repeat, frames in
    the graph, worst rotation and translation sigma, gap to the target (sigma / target), latency;
    then its note (the scan's and the image's reason, the solve's note) on indented lines. Every
    line fits ``WIDTH`` columns (a frame name too long for its row stands on a line of its own)."""
    pose = "-" if not v.found else (f"= {v.repeat_of}" if v.repeat_of else "new")
    pose = pose if len(pose) <= 10 else "repeat"  # the note names the frame
    rot = trans = gap = ""
    if v.sigmas is not None:  # the largest per axis (the advice's figures); the gap in any direction
        rot, trans = f"{np.max(v.sigmas[:3]):.4f}", f"{np.max(v.sigmas[3:]):.3f}"
        gap = target_gap(v.worst, target) if v.worst is not None else ""
    elif v.found:
        gap = _more(v.n_distinct)
    notes = [f"scan: {v.lidar}" if v.lidar else "", f"image: {v.image}" if v.image else "", v.note or ""]
    if v.repeat_of:
        notes.append(f"same board pose as {v.repeat_of}: move or turn the board")
    lat = "" if v.latency is None else f"{v.latency:.2f}s"
    cells = (
        f"{'ok' if v.lidar is None else 'no':<4s} {'ok' if v.image is None else 'no':<5s} "
        f"{pose:<10s} {v.n_frames:>3d} {rot:>8s} {trans:>8s} {gap:>13s} {lat:>7s}"
    )
    row = f"{v.name:<10s} {cells}".rstrip()
    lines = [row] if len(row) <= WIDTH else [v.name, f"{'':<10s} {cells}".rstrip()]
    return "\n".join(lines + _note_lines("; ".join(n for n in notes if n)))


def format_progress(
    verdicts: list[Verdict], target: tuple[float, float] | None = None, waiting: float | None = None
) -> str:
    """One status line: frames seen, with the board in both, distinct, in the graph; the sigmas."""
    n = len(verdicts)
    both = sum(v.found for v in verdicts)
    last = verdicts[-1] if verdicts else None
    head = f"{n} frame(s): {both} with the board in both, {last.n_distinct if last else 0} distinct poses"
    if last is not None and last.sigmas is not None and last.worst is not None:
        s = last.sigmas
        head += f"; sigma {np.max(s[:3]):.4f} deg, {np.max(s[3:]):.3f} mm"
        if target is not None:
            g = target_gap(last.worst, target)
            head += (
                "; target reached" if g == "reached" else f"; target {target[0]:g} deg, {target[1]:g} mm: {g}"
            )
    elif last is not None:
        head += f"; {_more(last.n_distinct)} to calibrate"
    if waiting is not None:
        head += f"; waiting for frames ({waiting:.0f} s)"
    return head


class StatusLine:
    """The progress line on a terminal, redrawn in place (elsewhere only ``final`` lines are written)."""

    def __init__(self, stream: TextIO = sys.stderr) -> None:
        self.stream = stream
        self.tty = bool(getattr(stream, "isatty", lambda: False)())
        self._shown = False

    def clear(self) -> None:
        if self.tty and self._shown:
            self.stream.write("\r\033[K")
            self.stream.flush()
            self._shown = False

    def show(self, text: str, final: bool = False) -> None:
        if self.tty:
            self.stream.write("\r\033[K" + text + ("\n" if final else ""))
            self._shown = not final
            self.stream.flush()
        elif final:
            self.stream.write(text + "\n")
            self.stream.flush()


# ------------------------------------------------------------------------------ advice
class LiveAdvice:
    """The next-board-pose advice of a check (``next_pose.Advisor``), refitted when the boards it
    was fitted on are fewer than half of those now, the extrinsic moved (0.5 deg / 2 cm) or the
    noise the solve found changed by more than a fifth."""

    def __init__(self, target_sigma: tuple[float, float] | None = None) -> None:
        self.target_sigma = target_sigma
        self._advisor: Advisor | None = None
        self._fitted_on = 0
        self._noise = np.ones(3)

    def propose(
        self, config: Config | None, frames: list[GraphFrame], update: FrameUpdate
    ) -> Proposal | None:
        """The proposal after a solve of the frames (``update.solution``): a new frame predicted with
        the noise that solve found, as after ``calibrate`` (``next_pose.from_calibration``); None
        without a config (no frame read yet)."""
        from ilcc_graph import next_pose

        sol = update.solution
        if config is None or config.lidar is None or len(frames) < 3 or sol is None:
            return None
        T_cam_lidar, covariance = update.T_cam_lidar, update.covariance
        factor = 1.0 if sol.selection is None else sol.selection.factor
        noise = np.array([*sol.variance_components, max(sol.variance_factor, factor, 1.0)])
        frames = next_pose.noise_scaled(frames, noise[0], noise[1])
        adv, moved = self._advisor, False
        if adv is not None:
            d = np.linalg.inv(adv.rig.T_cam_lidar) @ T_cam_lidar
            moved = bool(np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1))) > 0.5)
            moved = moved or bool(np.linalg.norm(d[:3, 3]) > 0.02)
            moved = moved or bool(np.any(np.abs(np.log(noise / self._noise)) > np.log(1.2)))
            moved = moved or (adv.solved is None) != (sol.solved is None)  # the sensor model's terms
            moved = moved or (
                sol.solved is not None and adv.solved is not None and adv.solved.dim != sol.solved.dim
            )
        if adv is None or moved or len(frames) >= 2 * self._fitted_on:
            rig = next_pose.Rig(config.camera, np.asarray(T_cam_lidar), config.lidar, config.board)
            adv = self._advisor = next_pose.Advisor(
                rig, frames, information_scale=noise[2], solved=sol.solved
            )
            self._fitted_on, self._noise = len(frames), noise
        adv.solved = sol.solved  # the gain through the shared terms from this solve's covariance
        return adv.propose(covariance, self.target_sigma, frames)


def _stop_when_unread(watch: bool) -> None:
    """End a ``check --watch`` nobody reads any more (its stdout's pipe closed: a pager quit):
    ``BrokenPipeError``, which the command line turns into a quiet exit 141 (issue 36: it would follow
    the folder until Ctrl-C, printing into nothing). A check of the frames there goes on to its end."""
    if watch and stdout_closed():
        raise BrokenPipeError("standard output closed")


def check_command(
    data: str, options: CheckOptions, out: Path | str | None = None, advise_live: bool = False,
    command: str = "",
) -> int:
    """``ilcc-graph check``: the live table on standard output, the progress line on standard error,
    then the batch answer and the next board pose; ``out`` (a folder): check.yaml and next_pose.png
    there (``command``: the command line, for the folder's marker). Returns the exit code (0; bad
    input raises InputError)."""
    from ilcc_graph.datasets import open_source
    from ilcc_graph.datasets.watch import GrowingFolder

    if options.watch and not Path(data).is_dir():
        raise InputError(f"{data}: --watch follows a data-set folder (config.yaml, pcd/, img/) being filled")
    source = GrowingFolder(data, options.settle_s) if options.watch else open_source(data)
    target = options.target_sigma
    status = StatusLine()
    advice = LiveAdvice(target)
    shown = {"advised": -1}
    seen: list[Verdict] = []
    print(VERDICT_HEADER, flush=True)

    def on_verdict(v: Verdict, checker: LiveCheck) -> None:
        _stop_when_unread(options.watch)
        seen.append(v)
        status.clear()
        print(format_verdict(v, target), flush=True)
        status.show(_short(format_progress(seen, target)))

    def on_idle(waited: float, checker: LiveCheck | None) -> None:
        _stop_when_unread(options.watch)
        if checker is None:
            if status.tty:
                status.show(_short(f"waiting for {Path(data) / 'config.yaml'}"))
            return
        last = checker.last
        if advise_live and last is not None and waited > 0.3 and shown["advised"] != last.n_frames:
            shown["advised"] = last.n_frames
            p = advice.propose(checker.config, checker.used, last)
            if p is not None:
                status.clear()
                print(wrapped(p.describe(), "  ", "    "), flush=True)
        if status.tty:
            status.show(_short(format_progress(seen, target, waiting=waited)))

    result = run_check(source, options, on_verdict, on_idle)
    status.clear()
    line = format_progress(result.verdicts, target)
    print("\n" + wrapped(line if result.stopped in line else f"{line} ({result.stopped})"))
    proposal = None
    if result.final is not None:
        s = sigmas_deg_mm(result.final.covariance)
        print(f"all {result.final.n_frames} frames solved together (as calibrate solves them):")
        print(f"  sigma rot {s[0]:.4f} {s[1]:.4f} {s[2]:.4f} deg, trans {s[3]:.3f} {s[4]:.3f} {s[5]:.3f} mm")
        if result.second_look:
            print(
                wrapped(f"second look, as calibrate's: the board found in {', '.join(result.second_look)}")
            )
        sol = result.final.solution
        if sol is not None and sol.selection is not None:
            print(wrapped(sol.selection.summary()))
        for said in lidar_view_lines(result.calibration) if result.calibration is not None else []:
            print(wrapped(said))  # how the LiDAR saw the boards, as calibrate's summary says it
        proposal = advice.propose(result.config, result.frames, result.final)
    elif result.verdicts:
        print("not calibrated yet: at least 3 distinct board poses with the board in both sensors")
        print("  are needed")
    if proposal is not None:
        print(wrapped(proposal.describe()))
    if out is not None:
        from ilcc_graph.app.write import write_check

        write_check(Path(out), result, proposal, command)
        print(wrapped(f"wrote check.yaml{' and next_pose.png' if proposal is not None else ''} to {out}"))
    return 0
