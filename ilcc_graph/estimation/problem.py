"""What the estimation core solves: boards seen by the LiDAR, views of them by cameras, extrinsics.

Plain data only. One ``Problem`` describes every mode:

- batch: one extrinsic, per frame one board and one view;
- sessions: boards of several data sets (``group`` = session), one extrinsic (rigid) or one per
  session tied by ``Tie``s (drift), optionally a range offset per LiDAR;
- rig: one extrinsic per camera, a board seen by several cameras is one board with several views.

Variables (``keys.py``): ``X(e)`` extrinsic ``T_cam_lidar`` of index e, ``B(i)`` board i's
``T_lidar_board``, ``O(l)`` the range offset of LiDAR l.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ilcc_graph.cameras import CameraModel
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.types import BoardReturns, GraphFrame

__all__ = ["BoardPrior", "Problem", "Tie", "View", "frames_problem", "merge_problems"]


@dataclass(frozen=True)
class BoardPrior:
    """One board placement as the LiDAR stage saw it.

    name: unique label (frame name, ``session/frame`` when several sessions).
    T_lidar_board: (4, 4) the LiDAR stage's pose. covariance: (6, 6) its Pose3-tangent covariance, or
    None for a board the (base) LiDAR did not see (a rig's: ``T_lidar_board`` is then only its start).
    group: noise group (the session): its board priors share one variance component.
    lidar: index of the LiDAR unit (shares the range-offset variable ``O(lidar)``).
    samples_board: (M, 3) points of the board's face, board frame, for the range offset (None: a
        grid over the corners grown by one square).
    returns: its LiDAR returns, to calibrate the LiDAR's own errors (``Problem.lidar_errors``).
    """

    name: str
    T_lidar_board: np.ndarray
    covariance: np.ndarray | None
    group: str = ""
    lidar: int = 0
    samples_board: np.ndarray | None = None
    returns: BoardReturns | None = None


@dataclass(frozen=True)
class View:
    """One camera's view of one board: its corners' bearings and pixel covariances.

    board: index into ``Problem.boards``. extrinsic: index e of the ``T_cam_lidar`` variable X(e).
    points_board: (K, 3) the corners seen, board frame. bearings: (K, 3) camera frame.
    cov_px: (K, 2, 2) pixel covariances, px^2. camera: maps them to bearing covariances.
    group: noise group of the bearings (session or camera). uv: (K, 2) the measured pixels (for
    intrinsics refinement), or None. lens: the physical camera whose intrinsics the view shares (a
    rig's camera index: cameras stated alike are still two lenses); None: views whose camera models
    are equal share them (one camera over sessions).
    """

    board: int
    extrinsic: int
    points_board: np.ndarray
    bearings: np.ndarray
    cov_px: np.ndarray
    camera: CameraModel
    group: str = ""
    uv: np.ndarray | None = None
    lens: int | None = None

    def lens_key(self) -> object:
        """What identifies the view's intrinsics: its ``lens``, else its camera model."""
        return self.camera if self.lens is None else ("lens", self.lens)


@dataclass(frozen=True)
class Tie:
    """``BetweenFactorPose3(X(a), X(b), identity)`` with per-axis sigmas (rad, rad, rad, m, m, m)."""

    a: int
    b: int
    sigmas: tuple[float, ...]


@dataclass(frozen=True)
class Problem:
    """Boards, views, extrinsic starts and ties.

    T_init: per extrinsic index its (4, 4) start. range_offset_sigma_m: None for no range-offset
    variables; else the sigma of each LiDAR's weak zero-mean prior on its offset (metres).
    lidar_errors: which of the LiDAR's own errors to estimate from the boards' returns (None: none).
    intrinsics: whether the cameras' intrinsics are refined, or their stated sigmas propagated.
    evidence: the data of factor kinds that bring their own (``kinds/``), by kind name (e.g. a rig's
    other LiDARs, ``kinds.lidar_boards``).
    excluded: boards left out of every solve, by name, with the reason (``held_out.held_out_gate``).
    """

    boards: tuple[BoardPrior, ...]
    views: tuple[View, ...]
    T_init: Mapping[int, np.ndarray]
    ties: tuple[Tie, ...] = ()
    range_offset_sigma_m: float | None = None
    lidar_names: tuple[str, ...] = field(default=("lidar",))
    lidar_errors: LidarErrorOptions | None = None
    intrinsics: IntrinsicsOptions | None = None
    evidence: Mapping[str, Any] = field(default_factory=dict)
    excluded: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        names = [b.name for b in self.boards]
        if len(set(names)) != len(names):
            raise ValueError(
                f"board names must be unique, got {sorted(n for n in names if names.count(n) > 1)}"
            )
        for v in self.views:
            if not 0 <= v.board < len(self.boards):
                raise ValueError(f"a view refers to board {v.board}, but there are {len(self.boards)}")
            if v.extrinsic not in self.T_init:
                raise ValueError(f"a view refers to extrinsic {v.extrinsic}, which has no start in T_init")
        for t in self.ties:
            if t.a not in self.T_init or t.b not in self.T_init:
                raise ValueError(f"a tie refers to extrinsic {t.a} or {t.b}, which has no start in T_init")

    @property
    def extrinsics(self) -> list[int]:
        """Extrinsic indices that some view or tie uses, ascending."""
        used = {v.extrinsic for v in self.views} | {i for t in self.ties for i in (t.a, t.b)}
        return sorted(used)

    def index(self, name: str) -> int:
        """Index of the board called ``name``."""
        for i, b in enumerate(self.boards):
            if b.name == name:
                return i
        raise KeyError(name)

    def with_extrinsics(self, mapping: Mapping[int, int], T_init: Mapping[int, np.ndarray]) -> Problem:
        """The same boards with every view's extrinsic renamed by ``mapping`` (e.g. all onto one)."""
        views = tuple(replace(v, extrinsic=mapping.get(v.extrinsic, v.extrinsic)) for v in self.views)
        return replace(self, views=views, T_init=dict(T_init), ties=())

    def with_ties(self, ties: Iterable[Tie], T_init: Mapping[int, np.ndarray]) -> Problem:
        return replace(self, ties=tuple(ties), T_init=dict(T_init))


def frames_problem(
    frames: Sequence[GraphFrame],
    camera: CameraModel,
    T_init: np.ndarray,
    group: str = "",
    extrinsic: int = 0,
    lidar: int = 0,
    samples_board: np.ndarray | None = None,
    prefix: str = "",
    lidar_errors: LidarErrorOptions | None = None,
    intrinsics: IntrinsicsOptions | None = None,
) -> Problem:
    """The problem of one data set: per frame one board (named ``prefix + frame.name``) and one view."""
    boards = tuple(
        BoardPrior(prefix + f.name, f.T_lidar_board, f.board_cov, group, lidar, samples_board, f.returns)
        for f in frames
    )
    views = tuple(
        View(i, extrinsic, f.points_board, f.bearings, f.cov_px, camera, group, f.uv)
        for i, f in enumerate(frames)
    )
    T0 = {extrinsic: np.asarray(T_init, dtype=np.float64)}
    return Problem(boards, views, T0, lidar_errors=lidar_errors, intrinsics=intrinsics)


def merge_problems(parts: Sequence[Problem], **kw: object) -> Problem:
    """One problem holding the boards and views of ``parts`` (board indices shifted; T_init merged)."""
    boards: list[BoardPrior] = []
    views: list[View] = []
    T_init: dict[int, np.ndarray] = {}
    ties: list[Tie] = []
    for p in parts:
        if p.evidence:
            raise ValueError(
                f"merge_problems: a part carries evidence of {sorted(p.evidence)}, which it cannot shift"
            )
        off = len(boards)
        boards.extend(p.boards)
        views.extend(replace(v, board=v.board + off) for v in p.views)
        T_init.update(p.T_init)
        ties.extend(p.ties)
    return Problem(tuple(boards), tuple(views), T_init, tuple(ties), **kw)  # type: ignore[arg-type]
