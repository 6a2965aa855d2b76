"""One exception tree for the whole toolkit.

``InputError`` means the user's files or arguments are wrong (command line exit 2; ``OutputError``:
the output location). ``FrameError`` and its subclasses mean one frame cannot be used; the
pipeline records the reason and skips the frame (``DamagedFile``: one of its files cannot be
read). ``CalibrationImpossible`` means no result can come from the data given (exit 3).
"""

from __future__ import annotations

#: how the reasons of frames dropped for disagreeing with the others begin (the corner-order checks
#: of ``init``, the graph's chi-square gate): reports and ``verify`` tell such frames apart by them
ORDER_INCONSISTENT = "corner order inconsistent"
ORDER_AMBIGUOUS = "corner order ambiguous"
GATE_DROPPED = "chi-square gate"
DISAGREEING = (ORDER_INCONSISTENT, ORDER_AMBIGUOUS, GATE_DROPPED)
#: how the reason of a frame a run left unread begins (the incremental mode once at its target)
NOT_READ = "not read"
#: how the reason of an image of one grey level begins (the image stage; the failure's advice)
BLANK_IMAGE = "the image is blank"


class CalibrationError(Exception):
    """Base of every error the toolkit raises on purpose."""


class InputError(CalibrationError):
    """A file, a configuration key or an argument is wrong; the message names it."""


class OutputError(InputError):
    """The output location cannot be written (a file in the way, no permission, disk full)."""


class FrameError(CalibrationError):
    """One frame cannot be used; the message is the reason recorded for it."""


class DamagedFile(FrameError):
    """A frame's scan or image cannot be read (truncated, undecodable, not the camera's size).

    The frame is skipped with this reason (the file and the problem); with ``--strict`` the run
    stops on it instead (an ``InputError``).
    """


class BoardNotFound(FrameError):
    """No segment of the scan passes the chessboard tests."""


class CornersNotFound(FrameError):
    """The chessboard's inner corners were not found in the image."""


class BoardColourMismatch(CornersNotFound):
    """The print's origin square (z towards the viewer) has the other colour than ``lower_left``.

    Only possible for a board that looks the same after a half turn, where that colour is a
    property of the print, not of how the board is held.
    """


class PartialPattern(CornersNotFound):
    """The detected corner grid is not provably the whole printed pattern (``image/whole.py``).

    Part of a larger checker pattern (a print with more squares than configured) or a board whose
    outer squares leave the picture: its corners' indices cannot be told, so the image is not used.
    """


class CorrespondenceError(FrameError):
    """Image and LiDAR corners of a frame cannot be ordered consistently."""


class CalibrationImpossible(CalibrationError):
    """Too little usable data for any estimate (exit code 3).

    The message is short; ``frames`` holds ``(frame, stage, reason)`` per frame that could not be
    used (the command line prints them as a table and writes them in full), ``advice`` one line on
    what to change or capture.
    """

    def __init__(
        self, message: str, frames: tuple[tuple[str, str, str], ...] = (), advice: str | None = None
    ):
        super().__init__(message)
        self.frames = tuple(frames)
        self.advice = advice


class IndeterminateSystem(CalibrationError):
    """The factor graph's information matrix is singular: the data do not fix the extrinsic."""


EXIT_OK = 0
EXIT_BUG = 1
EXIT_INPUT = 2
EXIT_IMPOSSIBLE = 3


def quote(value: object, limit: int = 120) -> str:
    """At most ``limit`` characters of ``repr(value)`` (``...`` at the end when cut), computed without
    formatting the whole value: a list or mapping is walked only as far as the prefix needs, so a
    YAML alias bomb (a list of lists of ... that expands to billions of values) costs no more than a
    short one (issue 36)."""
    out: list[str] = []
    room = [limit + 1]  # one more than shown: whether anything was cut is known without a full repr

    def put(s: str) -> bool:
        out.append(s[: room[0]])
        room[0] -= min(len(s), room[0])
        return room[0] > 0

    def walk(v: object, depth: int) -> bool:
        if isinstance(v, (list, tuple, dict)):
            if depth > 50:
                return put("...")
            opened, closed = "{}" if isinstance(v, dict) else "()" if isinstance(v, tuple) else "[]"
            items = v.items() if isinstance(v, dict) else v
            if not put(opened):
                return False
            for k, item in enumerate(items):
                if k and not put(", "):
                    return False
                if isinstance(v, dict):
                    if not (walk(item[0], depth + 1) and put(": ") and walk(item[1], depth + 1)):
                        return False
                elif not walk(item, depth + 1):
                    return False
            return put(closed)
        if isinstance(v, str) and len(v) > room[0]:
            return put(repr(v[: room[0]]))
        return put(repr(v))

    walk(value, 0)
    text = "".join(out)
    return text if len(text) <= limit else text[: limit - 3] + "..."
