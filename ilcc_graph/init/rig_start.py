"""A rig's start: every sensor's pose in the base LiDAR's frame, and one corner order per moment.

Input: per moment what the stages found (``types.MomentResult``: LiDAR board fits, image corners),
each observation in its own stage's corner order, known only up to the board's half turn when the
pattern looks the same turned (``Board.half_turn_symmetric``). No rule about how the board is held.

1. **Links**: for every pair of sensors that saw the board at the same moments, their relative pose
   and each shared moment's relative order, by the single pair's consensus
   (``correspondence.resolve_half_turns``: per moment and order a pose, the pose most moments agree
   with, refitted by UPnP on them) on one sensor's 3-D corners and the other's bearings: camera-LiDAR
   the LiDAR's corners and the camera's bearings; LiDAR-LiDAR one LiDAR's corners and the other's
   corner directions; camera-camera one camera's corners placed by its own PnP board pose
   (``upnp``) and the other's bearings. A link that one moment alone decides with either order
   (a half-turn symmetric board) is ambiguous and not used.
2. **Tree**: from the base (the rig's first LiDAR) a spanning tree over the sensors, the link with
   the most agreeing moments first (LiDAR links before camera-camera ones on ties); each sensor's
   ``T_base_sensor`` is the chain of its links. A sensor no usable link reaches is not placed.
3. **Boards**: per moment every observation's candidate board poses (a LiDAR's fit; a camera's PnP
   minima with the corners in front) are tried as the board's place; each other observation takes
   the order (as listed or half-turned) that agrees with it: a LiDAR's corners within ``gate_rel`` of
   the distance the half turn moves them, a camera's bearings within ``gate_rel`` of the angle it
   moves them (``consensus.half_turn_size``). The place most observations agree with wins; an
   observation that agrees with neither order, or with both, is dropped with the reason. The board's
   frame is the base LiDAR's fit where the base saw it (its order never turns).

Frames: ``T_base_sensor`` maps a sensor's points into the base LiDAR's frame; ``T_base_board`` the
board's. Units metres.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.errors import ORDER_AMBIGUOUS, ORDER_INCONSISTENT
from ilcc_graph.init.consensus import bearing_errors, half_turn_size, rms
from ilcc_graph.init.correspondence import OrderOptions, resolve_half_turns
from ilcc_graph.init.upnp import upnp
from ilcc_graph.types import BoardFit, ImageCorners, MomentResult

log = logging.getLogger(__name__)

__all__ = ["Link", "RigStart", "StartOptions", "adjoint", "orient_moment", "place_boards", "rig_start"]


@dataclass(frozen=True)
class StartOptions:
    """gate_rel: an observation agrees with a board place when its error is below ``gate_rel`` x what
    the half turn moves it (LiDAR: RMS corner distance; camera: RMS bearing angle).
    max_link_moments: a link is judged on at most this many of its shared moments (evenly spread;
    enough for a start, and the consensus's cost grows with them). link_order: the links' consensus
    (``correspondence.OrderOptions``; fewer tries than a single pair's own, for a start)."""

    gate_rel: float = 0.5
    max_link_moments: int = 8
    link_order: OrderOptions = OrderOptions(max_pair_fits=8, consensus_tries=3)


@dataclass(frozen=True)
class Link:
    """What two sensors' shared moments say: ``T_a_b`` (``p_a = T_a_b @ p_b``) or None; ``shared``
    moments both saw the board; ``agreeing``: those that agree on ``T_a_b`` under one order; kind
    ``lidar-lidar``, ``camera-lidar``, ``camera-camera``; ``ambiguous``: why the link is not used."""

    a: str
    b: str
    T_a_b: np.ndarray | None
    shared: int
    agreeing: int
    kind: str
    ambiguous: str | None = None

    @property
    def usable(self) -> bool:
        return self.T_a_b is not None and self.ambiguous is None and self.agreeing > 0


@dataclass(frozen=True)
class RigStart:
    """The start of a rig.

    base: the base LiDAR. T_base_sensor: {sensor: (4, 4)} of the sensors placed. T_base_board:
    {moment: (4, 4)} of the moments placed. flips: {moment: {sensor: True when that observation's
    order is the half-turned one}} for the observations kept. dropped: ``(moment, sensor, reason)`` of
    observations left out. links: every pair's link; tree: ``(parent, child)`` in the order placed.
    unplaced: {sensor: reason} of the sensors no usable link reaches.
    """

    base: str
    T_base_sensor: dict[str, np.ndarray]
    T_base_board: dict[str, np.ndarray]
    flips: dict[str, dict[str, bool]]
    dropped: list[tuple[str, str, str]] = field(default_factory=list)
    links: list[Link] = field(default_factory=list)
    tree: list[tuple[str, str]] = field(default_factory=list)
    unplaced: dict[str, str] = field(default_factory=dict)


# ------------------------------------------------------------------------------- helpers
def adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint of a (4, 4) pose in GTSAM's tangent order (rotation, translation)."""
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    A = np.zeros((6, 6))
    A[:3, :3], A[3:, 3:], A[3:, :3] = R, R, tx @ R
    return A


def _unit(F: np.ndarray) -> np.ndarray:
    return F / np.linalg.norm(F, axis=1, keepdims=True)


def _obs(m: MomentResult, s: str) -> BoardFit | ImageCorners:
    return m.boards[s] if s in m.boards else m.corners[s]


def _flippable(board: Board, *obs: BoardFit | ImageCorners) -> bool:
    return board.half_turn_symmetric and any(o.half_turn_ambiguous for o in obs)


def _pnp_poses(board: Board, corners: ImageCorners) -> list[np.ndarray]:
    """The camera's candidate ``T_cam_board`` (corners in front, best first; planar PnP's twins)."""
    sols = upnp(board.corners_board(), _unit(corners.bearings), prefer_front=True, tie_rtol=np.inf)
    front = [s for s in sols if s.front_fraction > 0.5]
    return [s.T_cam_points for s in front[:2] if s.cost <= 4.0 * front[0].cost + 1e-15]


def _points(board: Board, m: MomentResult, s: str) -> np.ndarray:
    """(K, 3) sensor ``s``'s corners in its own frame: a LiDAR's fit; a camera's PnP placement."""
    if s in m.boards:
        return m.boards[s].corners_lidar
    T = _pnp_poses(board, m.corners[s])[0]
    return board.corners_board() @ T[:3, :3].T + T[:3, 3]


def _directions(m: MomentResult, s: str) -> np.ndarray:
    """(K, 3) unit directions of sensor ``s``'s corners (a camera's bearings, a LiDAR's corners)."""
    return _unit(m.corners[s].bearings if s in m.corners else m.boards[s].corners_lidar)


# ------------------------------------------------------------------------------- 1. links
def _kind(a: str, b: str, lidars: set[str]) -> str:
    return "-".join(sorted(("lidar" if s in lidars else "camera") for s in (a, b)))


def _link(
    a: str, b: str, shared: Sequence[MomentResult], board: Board, lidars: set[str], opts: StartOptions
) -> Link:
    """The link of sensors a and b (``T_a_b``) from their ``shared`` moments (at most ``most``)."""
    kind = _kind(a, b, lidars)
    if not shared:
        return Link(a, b, None, 0, 0, kind, "no shared moment")
    n = len(shared)
    if n > opts.max_link_moments:
        pick = np.unique(np.linspace(0, n - 1, opts.max_link_moments).round().astype(int))
        shared = [shared[k] for k in pick]
    obs = [(_obs(m, a), _obs(m, b)) for m in shared]
    flippable = [_flippable(board, *o) for o in obs]
    if len(shared) == 1 and flippable[0]:
        return Link(a, b, None, n, 0, kind, "one shared moment: which half turn it is cannot be decided")
    perm = board.half_turn_permutation() if board.half_turn_symmetric else None
    try:
        points = [_points(board, m, b) for m in shared]
    except (ValueError, IndexError) as err:
        return Link(a, b, None, n, 0, kind, f"no PnP board pose: {err}")
    order = resolve_half_turns(
        points,
        [_directions(m, a) for m in shared],
        perm,
        [m.name for m in shared],
        flippable=flippable,
        options=opts.link_order,
    )
    return Link(a, b, order.T_cam_lidar, n, len(order.flip), kind, order.ambiguous)


def _pairs(
    moments: Sequence[MomentResult], lidars: Sequence[str], cameras: Sequence[str]
) -> dict[tuple[str, str], list[MomentResult]]:
    """Every sensor pair (a camera before a LiDAR: its link is ``T_cam_lidar``, as the single pair's)
    with their shared moments."""
    sensors = [*lidars, *cameras]
    out: dict[tuple[str, str], list[MomentResult]] = {}
    for i, s in enumerate(sensors):
        for t in sensors[i + 1 :]:
            a, b = (t, s) if (s in lidars and t in cameras) else (s, t)
            out[(a, b)] = [m for m in moments if a in m.sensors and b in m.sensors]
    return out


# ------------------------------------------------------------------------------- 2. tree
_PRIORITY = {"lidar-lidar": 2, "camera-lidar": 1, "camera-camera": 0}


def _tree(
    base: str,
    sensors: Sequence[str],
    pairs: Mapping[tuple[str, str], list[MomentResult]],
    lidars: set[str],
    link: Callable[[str, str, list[MomentResult]], Link],
) -> tuple[dict[str, np.ndarray], list[tuple[str, str]], dict[str, str], list[Link]]:
    """Prim's maximum spanning tree from ``base`` (links by agreeing moments, then kind), the links
    evaluated lazily: one whose shared moments cannot beat an evaluated link's agreeing ones is not
    computed. Returns (poses, tree edges, unplaced with reasons, the links evaluated)."""
    T = {base: np.eye(4)}
    tree: list[tuple[str, str]] = []
    done: dict[tuple[str, str], Link] = {}
    kinds = {ab: _PRIORITY[_kind(*ab, lidars)] for ab in pairs}
    while True:
        frontier = sorted(
            (ab for ab, ms in pairs.items() if ms and (ab[0] in T) != (ab[1] in T)),
            key=lambda ab: (len(pairs[ab]), kinds[ab]),
            reverse=True,
        )
        best, key = None, None
        for ab in frontier:
            if key is not None and (len(pairs[ab]), kinds[ab]) <= key:
                break  # no later pair can beat the best evaluated
            lk = done.get(ab) or done.setdefault(ab, link(*ab, pairs[ab]))
            if lk.usable and (key is None or (lk.agreeing, kinds[ab]) > key):
                best, key = lk, (lk.agreeing, kinds[ab])
        if best is None:
            break
        if best.a in T:  # T_base_b = T_base_a T_a_b
            T[best.b] = T[best.a] @ best.T_a_b  # type: ignore[operator]
            tree.append((best.a, best.b))
        else:
            T[best.a] = T[best.b] @ np.linalg.inv(best.T_a_b)  # type: ignore[arg-type]
            tree.append((best.b, best.a))
    unplaced = {}
    for s in sensors:
        if s in T:
            continue
        mine = [lk for ab, lk in done.items() if s in ab]
        why = "; ".join(
            f"with {lk.b if lk.a == s else lk.a}: {lk.ambiguous or 'no agreeing moment'}" for lk in mine
        )
        shared = any(ms for ab, ms in pairs.items() if s in ab)
        unplaced[s] = (
            "no usable link to the placed sensors" + (f" ({why})" if why else "")
            if shared
            else "no moment shared with another sensor"
        )
    return T, tree, unplaced, list(done.values())


# ------------------------------------------------------------------------------- 3. boards
def _errors(
    T_base_board: np.ndarray, m: MomentResult, s: str, T_base_s: np.ndarray, board: Board
) -> tuple[float, float, float]:
    """(error as listed, error half-turned, gate) of sensor ``s``'s observation against a board
    placed at ``T_base_board``: metres (LiDAR corners) or radians (camera bearings)."""
    perm = board.half_turn_permutation() if board.half_turn_symmetric else None
    T = np.linalg.solve(T_base_s, T_base_board)
    P = board.corners_board() @ T[:3, :3].T + T[:3, 3]
    if s in m.boards:
        C = m.boards[s].corners_lidar
        size = 2.0 * float(rms(np.linalg.norm(C - C.mean(axis=0), axis=1)))  # the half turn's move
        e0 = float(rms(np.linalg.norm(P - C, axis=1)))
        e1 = float(rms(np.linalg.norm(P - C[perm], axis=1))) if perm is not None else np.inf
    else:
        F = _unit(m.corners[s].bearings)
        size = half_turn_size(F, perm)
        e0 = float(rms(bearing_errors(np.eye(4), P, F)))
        e1 = float(rms(bearing_errors(np.eye(4), P, F[perm]))) if perm is not None else np.inf
    return e0, e1, size


def _candidates(m: MomentResult, s: str, T_base_s: np.ndarray, board: Board) -> list[np.ndarray]:
    if s in m.boards:
        return [T_base_s @ m.boards[s].T_lidar_board]
    try:
        return [T_base_s @ T for T in _pnp_poses(board, m.corners[s])]
    except ValueError:
        return []


def _place(
    m: MomentResult, T_base: Mapping[str, np.ndarray], board: Board, base: str, opts: StartOptions
) -> tuple[np.ndarray, dict[str, bool], list[tuple[str, str]]] | None:
    """(T_base_board, {sensor: flip}, [(sensor, reason)]) of one moment, or None with no observation."""
    obs = [s for s in m.sensors if s in T_base]
    if not obs:
        return None
    best = None
    for s in obs:
        for T in _candidates(m, s, T_base[s], board):
            flips, errs, bad = {}, 0.0, []
            for o in obs:
                e0, e1, size = _errors(T, m, o, T_base[o], board)
                gate = opts.gate_rel * size
                turns = _flippable(board, _obs(m, o))  # else its order is as listed
                ok0, ok1 = e0 < gate, turns and e1 < gate
                unit, scale = ("mm", 1e3) if o in m.boards else ("mrad", 1e3)
                listed = f"{scale * e0:.1f} {unit} as listed" + (
                    f", {scale * e1:.1f} {unit} half-turned" if np.isfinite(e1) else ""
                )
                if ok0 and ok1:
                    bad.append((o, f"{ORDER_AMBIGUOUS}: both orders fit the board's place ({listed}, "
                                   f"gate {scale * gate:.1f} {unit})"))  # fmt: skip
                elif ok0 or ok1:
                    flips[o] = bool(ok1)
                    errs += (e1 if ok1 else e0) / max(size, 1e-12)
                else:
                    bad.append((o, f"{ORDER_INCONSISTENT} with the other sensors: {listed} from where "
                                   f"they put the board (gate {scale * gate:.1f} {unit})"))  # fmt: skip
            score = (len(flips), -errs)
            if best is None or score > best[0]:
                best = (score, T, flips, bad)
    if best is None:
        return None
    _, T, flips, bad = best
    if flips.get(base):  # the board's frame is the base LiDAR's fit: turn every order with it
        T = T @ board.T_half_turn()
        flips = {s: not f for s, f in flips.items()}
    return T, flips, bad


def place_boards(
    moments: Sequence[MomentResult],
    T_base_sensor: Mapping[str, np.ndarray],
    board: Board,
    base: str,
    options: StartOptions = StartOptions(),
) -> tuple[dict[str, np.ndarray], dict[str, dict[str, bool]], list[tuple[str, str, str]]]:
    """Step 3 with known sensor poses (e.g. a stored calibration's, for ``verify``): per moment the
    board's place and each observation's order; observations of sensors not in ``T_base_sensor``
    and those that agree with neither order are dropped. Returns (T_base_board, flips, dropped)."""
    T_board: dict[str, np.ndarray] = {}
    flips: dict[str, dict[str, bool]] = {}
    dropped: list[tuple[str, str, str]] = []
    for m in moments:
        dropped += [(m.name, s, "sensor not placed") for s in m.sensors if s not in T_base_sensor]
        res = _place(m, T_base_sensor, board, base, options)
        if res is None:
            continue
        T_board[m.name], flips[m.name], bad = res
        dropped += [(m.name, s, why) for s, why in bad]
    return T_board, flips, dropped


def rig_start(
    moments: Sequence[MomentResult],
    board: Board,
    lidars: Sequence[str],
    cameras: Sequence[str],
    options: StartOptions = StartOptions(),
) -> RigStart:
    """Every sensor's pose in the base LiDAR's frame (``lidars[0]``) and each moment's board place and
    corner orders, from the stages' answers alone (module docstring)."""
    if not lidars:
        raise ValueError("rig_start: a rig needs a LiDAR (the base frame)")
    base = lidars[0]
    pairs = _pairs(moments, lidars, cameras)
    kinds = set(lidars)

    def link(a: str, b: str, shared: list[MomentResult]) -> Link:
        return _link(a, b, shared, board, kinds, options)

    T, tree, unplaced, links = _tree(base, [*lidars, *cameras], pairs, kinds, link)
    for s, why in unplaced.items():
        log.warning("sensor %s: %s", s, why)
    T_board, flips, dropped = place_boards(moments, T, board, base, options)
    dropped = [(m, s, unplaced.get(s, why)) for m, s, why in dropped]
    return RigStart(base, T, T_board, flips, dropped, links, tree, unplaced)


# ------------------------------------------------------------------------------- oriented data
def orient_fit(fit: BoardFit, board: Board) -> BoardFit:
    """A LiDAR fit half-turned: ``T_lidar_board @ H``, its covariance in the new tangent
    (``Ad(H^-1) C Ad(H^-1)^T``), corners re-indexed; its returns left out (a rig's other LiDARs
    enter the graph by their board poses alone)."""
    H = board.T_half_turn()
    A = adjoint(np.linalg.inv(H))
    perm = board.half_turn_permutation()
    return dataclasses.replace(
        fit,
        T_lidar_board=fit.T_lidar_board @ H,
        covariance=A @ fit.covariance @ A.T,
        corners_lidar=fit.corners_lidar[perm],
        returns=None,
    )


def orient_corners(corners: ImageCorners, board: Board) -> ImageCorners:
    """Image corners half-turned: corner k is the old corner ``perm[k]``."""
    perm = board.half_turn_permutation()
    return dataclasses.replace(
        corners, uv=corners.uv[perm], bearings=corners.bearings[perm], cov_px=corners.cov_px[perm]
    )


def orient_moment(m: MomentResult, flips: Mapping[str, bool], board: Board) -> MomentResult:
    """The moment with only the observations in ``flips``, each in the moment's board order."""
    boards = {s: orient_fit(f, board) if flips[s] else f for s, f in m.boards.items() if s in flips}
    corners = {s: orient_corners(c, board) if flips[s] else c for s, c in m.corners.items() if s in flips}
    return dataclasses.replace(m, boards=boards, corners=corners)
