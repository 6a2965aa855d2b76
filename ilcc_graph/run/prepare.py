"""Observed frames into the estimation core's input (``run.finish`` turns the answer back).

``prepare``: repeated board poses out, the corner order made consistent across frames (half
turns), ``GraphFrame``s and the start (UPnP on that consensus); what the frames not used lacked.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ilcc_graph.config import Config
from ilcc_graph.errors import BLANK_IMAGE, CalibrationImpossible
from ilcc_graph.estimation.geometry import board_geometry
from ilcc_graph.evaluation.causes import causes_without_extrinsic
from ilcc_graph.init import resolve_half_turns, upnp
from ilcc_graph.types import FrameResult, GraphFrame, ImageCorners

log = logging.getLogger(__name__)

__all__ = [
    "Prepared",
    "drop",
    "frame_issues",
    "graph_frame",
    "permute_corners",
    "prepare",
]


@dataclass(frozen=True)
class Prepared:
    """Frames in a consistent corner order with the start from their consensus."""

    frames: list[GraphFrame]
    T_init: np.ndarray
    results: dict[str, FrameResult]  # every frame, with the ordering's drops and re-indexed corners


def permute_corners(corners: ImageCorners, perm: np.ndarray) -> ImageCorners:
    """The same corners re-indexed: new corner k is old corner perm[k]."""
    return dataclasses.replace(
        corners, uv=corners.uv[perm], bearings=corners.bearings[perm], cov_px=corners.cov_px[perm]
    )


def drop(results: dict[str, FrameResult], name: str, reason: str) -> None:
    """Mark frame ``name`` unused with ``reason`` (in place)."""
    results[name] = dataclasses.replace(results[name], used=False, reason=reason)


def graph_frame(r: FrameResult, config: Config) -> GraphFrame:
    """The estimation core's input of one frame with both stages' results."""
    b, c = r.board, r.corners
    assert b is not None and c is not None
    corners = config.board.corners_board()
    return GraphFrame(r.name, b.T_lidar_board, b.covariance, corners, c.bearings, c.cov_px, b.returns, c.uv)


def prepare(observed: Sequence[FrameResult], config: Config) -> Prepared:
    """Repeated board poses out, corners ordered across frames (half turns), the start from the consensus.

    Raises CalibrationImpossible when no frame has the board in both sensors, the distinct board
    poses cannot calibrate (``estimation.geometry``), or the corner order is ambiguous.
    """
    results = {r.name: r for r in observed}
    usable = [r for r in observed if r.used and r.board is not None and r.corners is not None]
    if not usable:
        issues = frame_issues(observed)
        raise CalibrationImpossible(
            f"no frame has the board in both the scan and the image ({_counts(observed, issues)})",
            issues,
            _stage_advice(issues),
        )
    geometry = board_geometry([graph_frame(r, config) for r in usable])
    for name, first in geometry.repeats.items():
        drop(results, name, f"same board pose as {first}: one observation, not an independent one")
    if not geometry.ok:
        reason = re.sub(r" \([^)]*show one pose\)", "", geometry.reason or "too few distinct board poses")
        issues = frame_issues([r for r in observed if not r.used or r.board is None or r.corners is None])
        n = len(geometry.groups)
        issues += tuple(
            (r.name, "geometry", f"same board pose as {geometry.repeats[r.name]}")
            if r.name in geometry.repeats
            else (r.name, "geometry", f"usable: one of only {n} distinct board pose{'s' if n != 1 else ''}")
            for r in usable
        )
        raise CalibrationImpossible(reason, issues, f"capture next: {geometry.advice}")
    if geometry.parallel:
        log.warning("%s: %s", config.source, geometry.parallel)
    usable = [r for r in usable if r.name not in geometry.repeats]
    board = config.board
    # a board whose print looks the same half-turned, or whose LiDAR fit could not see the print
    # (its outline alone: the half turn unknown), is matched to the image in either order
    flippable = [board.half_turn_symmetric or r.board.half_turn_ambiguous for r in usable]  # type: ignore[union-attr]
    perm = board.half_turn_permutation() if any(flippable) else None
    order = resolve_half_turns(
        [r.board.corners_lidar for r in usable],  # type: ignore[union-attr]
        [r.corners.bearings for r in usable],  # type: ignore[union-attr]
        perm,
        [r.name for r in usable],
        flippable=flippable,
    )
    if order.ambiguous:
        # a board size or a camera the frames contradict makes no order fit: name it before more poses
        # (not the outline's margin: boards placed by their outline alone leave the order open anyway)
        found = causes_without_extrinsic(usable, config.board, config.camera, margin=False)
        raise CalibrationImpossible(
            "the corner order between image and scan cannot be decided",
            tuple((r.name, "order", order.ambiguous) for r in usable[:1]),
            f"likely: {found[0]}"
            if found
            else "add frames with the board turned differently in its plane (not only half turns apart)",
        )
    for name, reason in order.dropped:
        drop(results, name, reason)
    kept: list[FrameResult] = []
    for r in usable:
        if not results[r.name].used:
            continue
        if perm is not None and order.flip.get(r.name, False):
            r = dataclasses.replace(r, corners=permute_corners(r.corners, perm))  # type: ignore[arg-type]
            results[r.name] = r
        kept.append(r)
    if not kept:
        raise CalibrationImpossible(
            "no frame left after ordering the corners",
            tuple((n, "order", why) for n, why in order.dropped),
            "check board.squares and board.lower_left in config.yaml against the print",
        )
    frames = [graph_frame(r, config) for r in kept]
    T_init = order.T_cam_lidar
    if T_init is None:
        P = np.vstack([r.board.corners_lidar for r in kept])  # type: ignore[union-attr]
        F = np.vstack([r.corners.bearings for r in kept])  # type: ignore[union-attr]
        T_init = upnp(P, F, prefer_front=True)[0].T_cam_points  # corners lie ahead along their rays
    return Prepared(frames, np.asarray(T_init, dtype=np.float64), results)


#: frame reasons as ``stages.observe_frame`` writes them: "LiDAR: ...; image: ..."
_STAGE_PREFIXES = (("LiDAR: ", "lidar"), ("image: ", "image"))


def frame_issues(frames: Sequence[FrameResult]) -> tuple[tuple[str, str, str], ...]:
    """``(frame, stage, reason)`` of every frame not used: stage ``lidar`` or ``image`` (both when
    both failed), ``pairing`` for a scan or image without its partner, ``frame`` otherwise."""
    out: list[tuple[str, str, str]] = []
    for f in frames:
        if f.used:
            continue
        why = f.reason or "not used"
        if why.startswith("LiDAR: ") or why.startswith("image: "):
            head, sep, tail = why.partition("; image: ")
            parts = [head] + ([f"image: {tail}"] if sep else [])
            for part in parts:
                for prefix, stage in _STAGE_PREFIXES:
                    if part.startswith(prefix):
                        out.append((f.name, stage, part[len(prefix) :]))
        elif f.board is None and f.corners is None and ("has no scan" in why or "has no image" in why):
            out.append((f.name, "pairing", why))
        else:
            out.append((f.name, "frame", why))
    return tuple(out)


def _counts(frames: Sequence[FrameResult], issues: Sequence[tuple[str, str, str]]) -> str:
    n = len(frames)
    by = {s: len({f for f, st, _ in issues if st == s}) for s in ("lidar", "image", "pairing")}
    parts = [f"{n} frame{'s' if n != 1 else ''}"]
    if by["lidar"]:
        parts.append(f"no board in {by['lidar']} scan{'s' if by['lidar'] != 1 else ''}")
    if by["image"]:
        parts.append(f"no corners in {by['image']} image{'s' if by['image'] != 1 else ''}")
    if by["pairing"]:
        parts.append(f"{by['pairing']} without a partner")
    return ", ".join(parts)


def _stage_advice(issues: Sequence[tuple[str, str, str]]) -> str:
    """One line on what to check, from which stage failed most."""
    lidar = sum(1 for _, s, _ in issues if s == "lidar")
    image = sum(1 for _, s, _ in issues if s == "image")
    if not issues:
        return "no frames: put scans in DATA/pcd and images with the same names in DATA/img"
    blank = sum(1 for _, s, why in issues if s == "image" and why.startswith(BLANK_IMAGE))
    if image >= lidar and 2 * blank > image:
        return (
            "most images are blank (one grey level): check the camera (lens cap, exposure, the driver's "
            "first frames) and that DATA/img holds the pictures taken with the scans"
        )
    if image >= lidar:
        return (
            "the image stage found no chessboard: check board.squares (squares, not inner corners) and the "
            "camera section of config.yaml, and that the whole board is in the pictures"
        )
    return (
        "the LiDAR stage found no board: check board.squares, board.square_size and lidar.model in "
        "config.yaml; if the board is in view, narrow the search with board.roi"
    )
