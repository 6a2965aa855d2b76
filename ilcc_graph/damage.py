"""Frame files that cannot be read: a damaged frame costs that frame, loudly, not the run.

A scan or image whose source read raises ``InputError`` (truncated PCD, undecodable PNG, a .bin of
the wrong length, ...) or an image of another size than the camera's becomes a ``DamagedFile`` for
its frame: the frame is skipped with the file and the problem as its reason, a warning says so,
and calibration.yaml, the report's frame table and the printed summary count it. With ``strict``
the ``InputError`` stops the run instead (the behaviour before issue 14). Every image of another
size than the camera's is the config's mistake, not damage: ``check_image_size`` says so once.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ilcc_graph.config import Config
from ilcc_graph.datasets import FrameRef, FrameSource
from ilcc_graph.errors import DamagedFile, InputError
from ilcc_graph.types import FrameResult

log = logging.getLogger(__name__)

__all__ = ["check_image_size", "damage_summary", "read_frame_file", "size_problem", "warn_damaged"]


def read_frame_file(fn: Callable[..., Any], *args: object, strict: bool = False) -> Any:
    """``fn(*args)``, a source's read; its InputError (the file and the problem) becomes a DamagedFile
    that costs the frame, or stays an InputError that stops the run with ``strict``."""
    try:
        return fn(*args)
    except InputError as err:
        if strict:
            raise
        raise DamagedFile(f"damaged file: {err}") from None


def size_problem(size: tuple[int, int], config: Config, where: str) -> str | None:
    """Why an image of ``size`` (width, height) px cannot be of the config's camera, or None."""
    w, h = size
    cam = config.camera
    if (w, h) == (cam.width, cam.height):
        return None
    hint = ""
    if w * cam.height == h * cam.width and cam.intrinsic_names:
        hint = (
            f"; the images look scaled by {w / cam.width:g} from the size the intrinsics are for: "
            "scale fx, fy, cx, cy with width and height"
        )
    return (
        f"{where}: image is {w}x{h} px, but the camera in {config.source} is {cam.width}x{cam.height} "
        f"(camera.width x camera.height; ILCC's image_res){hint}"
    )


def check_image(
    image: np.ndarray | tuple[int, int], config: Config, where: str, strict: bool = False
) -> None:
    """DamagedFile (InputError with ``strict``) when the image, or an image of size (width, height)
    read from its header, has not the camera's size."""
    size = image if isinstance(image, tuple) else (image.shape[1], image.shape[0])
    problem = size_problem(size, config, where)
    if problem is None:
        return
    if strict:
        raise InputError(problem)
    raise DamagedFile(f"damaged file: {problem}")


def check_image_size(source: FrameSource, refs: Sequence[FrameRef], config: Config, look: int = 3) -> None:
    """Raise InputError when the first readable images (up to ``look``) all differ from the camera's size.

    One odd image is a damaged frame (skipped); every image of another size is the config's mistake
    (or the images were scaled), said once, naming an image and the config keys.
    """
    problems = []
    for ref in [r for r in refs if r.image is not None][:look]:
        try:
            w, h = source.image_size(ref)
        except InputError:
            continue  # a damaged image: the stage says so for its frame
        problem = size_problem((w, h), config, str(ref.image))
        if problem is None:
            return
        problems.append(problem)
    if problems:
        more = f" (so are the other {len(problems) - 1} image(s) looked at)" if len(problems) > 1 else ""
        raise InputError(problems[0] + more)


def damage_summary(frames: Sequence[FrameResult]) -> str | None:
    """'N frame(s) skipped for damaged files: a, b' or None."""
    names = [f.name for f in frames if f.damaged]
    if not names:
        return None
    return f"{len(names)} frame(s) skipped for damaged files: {', '.join(names)}"


def warn_damaged(frames: Sequence[FrameResult]) -> None:
    """A warning per damaged frame; InputError when no frame's files can be read at all."""
    for f in frames:
        if f.damaged:
            log.warning("%s: skipped, %s", f.name, f.reason)
    if frames and all(f.damaged for f in frames):
        raise InputError(
            f"no frame's files can be read ({len(frames)} damaged): "
            + "; ".join(f"{f.name}: {f.reason}" for f in frames[:3])
        )
