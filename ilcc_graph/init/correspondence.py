"""Corner order across frames: resolve each board's half turn from the data, drop what does not fit.

A chessboard whose pattern looks the same after a half turn about its normal gives, per frame,
image corners that match the LiDAR corners either as listed or after the permutation ``perm``
(``Board.half_turn_permutation()``). From one frame alone both orders fit equally well: the wrong
one just gives a pose turned 180 degrees about that board's normal. Across frames they differ: the
true extrinsic is the same for every frame, while the wrong order turns it about a different axis
in each frame. So:

1. per frame and per candidate order, the frame's own pose ``T_cam_lidar`` by UPnP (positive
   depths preferred: a planar board has an exact mirror minimum behind the camera);
2. each of those poses is a hypothesis; a frame supports it when, under one of its orders, the
   bearing error of its corners is below a gate tied to the board's angular size in the image
   (the wrong order moves the corners by about twice that size);
3. the hypothesis with the most support wins; the extrinsic is re-estimated by UPnP on all its
   frames together, the orders and the support are re-evaluated against it (a few rounds);
4. each frame keeps the order that agrees with the consensus; frames that agree under neither
   order are dropped with the reason. Two different extrinsics with equal support (e.g. two
   frames whose boards sit in the same place) make the result ambiguous, which is said.

Frames: LiDAR corners (K, 3) in the LiDAR frame, bearings (K, 3) unit vectors in the camera frame.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ilcc_graph.init.upnp import upnp

__all__ = ["OrderOptions", "OrderResult", "resolve_half_turns", "bearing_errors"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OrderOptions:
    """Gates of the cross-frame consistency check.

    gate_rel: a frame agrees with an extrinsic when its RMS bearing error is below
        ``gate_rel`` x the board's angular radius (RMS angle of its corners from their mean
        direction). The wrong half turn gives about twice that radius.
    robust_factor, min_gate_mrad: after the consensus is refined, a frame is also dropped when its
        error exceeds ``max(min_gate_mrad, robust_factor * median error of the agreeing frames)``.
    rot_gate_deg: hypotheses from single frames: a frame supports another's pose when their
        rotations differ by less than this (the wrong half turn differs by twice the angle between
        the two boards' normals).
    rounds: re-estimation rounds of the consensus.
    max_hypotheses_frames: frames whose own poses are tried as hypotheses (evenly spread).
    """

    gate_rel: float = 0.5
    rot_gate_deg: float = 10.0
    robust_factor: float = 6.0
    min_gate_mrad: float = 3.0
    rounds: int = 5
    max_hypotheses_frames: int = 60


@dataclass(frozen=True)
class OrderResult:
    """The corner order of every frame, the frames dropped and why.

    flip: name -> True when the image corners must be permuted by ``perm``
        (``bearings[perm]``, i.e. image corner perm[k] matches LiDAR corner k); kept frames only.
    dropped: (name, reason) of frames that cannot be ordered consistently.
    per_frame_T: name -> (4, 4) T_cam_lidar from that frame alone in its chosen order (kept frames).
    T_cam_lidar: (4, 4) consensus extrinsic from the kept frames together, or None.
    ambiguous: None, or why the data cannot decide (a single frame; two equally supported extrinsics).
    errors_mrad: name -> (RMS bearing error as listed, after the flip) under the consensus, mrad
        (NaN when there is no consensus or no flip).
    """

    flip: dict[str, bool]
    dropped: list[tuple[str, str]]
    per_frame_T: dict[str, np.ndarray]
    T_cam_lidar: np.ndarray | None = None
    ambiguous: str | None = None
    errors_mrad: dict[str, tuple[float, float]] = field(default_factory=dict)


def bearing_errors(T_cam_lidar: np.ndarray, lidar_corners: np.ndarray, bearings: np.ndarray) -> np.ndarray:
    """Angles (rad) between bearings (..., K, 3) and the directions of T @ corners (..., K, 3)."""
    X = lidar_corners @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]
    cr = np.linalg.norm(np.cross(X, bearings), axis=-1)
    return np.arctan2(cr, np.sum(X * bearings, axis=-1))


def _rms(a: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.sqrt(np.mean(a * a, axis=axis))


def _angular_radius(F: np.ndarray) -> float:
    m = F.mean(axis=0)
    m /= max(np.linalg.norm(m), 1e-300)
    return float(_rms(np.arctan2(np.linalg.norm(np.cross(F, m), axis=1), F @ m)))


def _check_inputs(lidar_corners, bearings, perm, names, flippable):
    n = len(names)
    if len(lidar_corners) != n or len(bearings) != n:
        raise ValueError(
            f"need one entry per name: {n} names, {len(lidar_corners)} corner sets, "
            f"{len(bearings)} bearing sets"
        )
    if len(set(names)) != n:
        raise ValueError("frame names must be unique")
    L = [np.asarray(x, dtype=np.float64) for x in lidar_corners]
    F = []
    for name, x, b in zip(names, L, bearings, strict=True):
        b = np.asarray(b, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3 or b.shape != x.shape:
            raise ValueError(f"frame {name}: corners {x.shape} and bearings {b.shape} must both be (K, 3)")
        F.append(b / np.linalg.norm(b, axis=1, keepdims=True))
    if perm is not None:
        perm = np.asarray(perm, dtype=np.int64)
        for name, x in zip(names, L, strict=True):
            if perm.shape != (len(x),):
                raise ValueError(f"frame {name}: perm has shape {perm.shape}, the frame has {len(x)} corners")
        if not np.array_equal(np.sort(perm), np.arange(len(perm))):
            raise ValueError("perm is not a permutation")
    if flippable is None:
        flippable = [perm is not None] * n
    elif len(flippable) != n:
        raise ValueError(f"flippable has {len(flippable)} entries for {n} frames")
    flippable = [bool(f) and perm is not None for f in flippable]
    return L, F, perm, flippable


def resolve_half_turns(
    lidar_corners: Sequence[np.ndarray],
    bearings: Sequence[np.ndarray],
    perm: np.ndarray | None,
    names: Sequence[str],
    *,
    flippable: Sequence[bool] | None = None,
    options: OrderOptions = OrderOptions(),
) -> OrderResult:
    """Choose per frame the image corner order that agrees with one extrinsic; drop the rest.

    Parameters
    ----------
    lidar_corners : per frame (K, 3) corners in the LiDAR frame, metres, the board's canonical order.
    bearings : per frame (K, 3) unit bearings of the image corners in the camera frame, same order
        up to the half turn.
    perm : (K,) corner permutation of the board's half turn, or None when the board has no such
        symmetry (then the frames are only checked for consistency).
    names : frame names, unique.
    flippable : per frame, whether its order is known only up to the half turn (default: all,
        when ``perm`` is given).
    """
    names = list(names)
    L, F, perm, flip_ok = _check_inputs(lidar_corners, bearings, perm, names, flippable)
    n = len(names)
    dropped: list[tuple[str, str]] = []

    def oriented(j: int, o: int) -> np.ndarray:
        return F[j][perm] if o else F[j]

    # 1. each frame's own pose in each candidate order
    own: dict[tuple[int, int], np.ndarray] = {}
    alive = []
    for j in range(n):
        try:
            for o in (0, 1) if flip_ok[j] else (0,):
                sols = upnp(L[j], oriented(j, o), prefer_front=True, tie_rtol=np.inf)
                if not sols:
                    raise ValueError("no pose found")
                own[(j, o)] = sols[0].T_cam_points
            alive.append(j)
        except ValueError as e:
            dropped.append(
                (names[j], f"corner order inconsistent with the other frames: no pose from its corners ({e})")
            )
    if not alive:
        return OrderResult({}, dropped, {})
    gate = {j: options.gate_rel * _angular_radius(F[j]) for j in alive}

    if len(alive) == 1:
        j = alive[0]
        amb = (
            f"frame {names[j]} is the only one: its half turn cannot be resolved from the data"
            if flip_ok[j]
            else None
        )
        if amb:
            log.warning(amb)
        return OrderResult({names[j]: False}, dropped, {names[j]: own[(j, 0)]}, own[(j, 0)], amb)

    def errors(T: np.ndarray) -> np.ndarray:
        """(n_alive, 2) RMS bearing error (rad) of each alive frame per order; inf where no flip."""
        E = np.full((len(alive), 2), np.inf)
        for a, j in enumerate(alive):
            for o in (0, 1) if flip_ok[j] else (0,):
                E[a, o] = _rms(bearing_errors(T, L[j], oriented(j, o)))
        return E

    def fit(idx: np.ndarray, orders: np.ndarray) -> np.ndarray:
        P = np.vstack([L[alive[a]] for a in idx])
        B = np.vstack([oriented(alive[a], int(orders[a])) for a in idx])
        return upnp(P, B, prefer_front=True, tie_rtol=np.inf)[0].T_cam_points

    g = np.array([gate[j] for j in alive])
    rot_gate = np.radians(options.rot_gate_deg)

    # 2. hypotheses: every frame's own pose in each order; a frame supports one when its own
    # rotation under one of its orders is within rot_gate (cheap, and blind to the big lever-arm
    # errors of one-board translations)
    Rown = np.full((len(alive), 2, 3, 3), np.nan)
    for a, j in enumerate(alive):
        for o in (0, 1):
            if (j, o) in own:
                Rown[a, o] = own[(j, o)][:3, :3]
    step = max(1, int(np.ceil(len(alive) / options.max_hypotheses_frames)))
    scored = []
    for a in range(0, len(alive), step):
        for o in (0, 1):
            if (alive[a], o) not in own:
                continue
            tr = np.einsum("ij,koij->ko", Rown[a, o], Rown)
            d = np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))
            d = np.where(np.isnan(d), np.inf, d)
            d[a, 1 - o] = np.inf  # the anchor's order is the hypothesis
            orders = np.argmin(d, axis=1)
            dmin = d[np.arange(len(d)), orders]
            sup = dmin < rot_gate
            undecided = sup & np.all(d < rot_gate, axis=1)
            score = (int(sup.sum()), -float(np.sum(np.where(sup, dmin / rot_gate, 1.0))))
            scored.append((score, a, sup, undecided, orders))
    scored.sort(key=lambda s: s[0], reverse=True)

    def consensus(a0: int, sup: np.ndarray, undecided: np.ndarray, orders: np.ndarray):
        """Extrinsic from the supporting frames, then a few robust rounds on bearing errors."""
        orders = orders.copy()
        decided = sup & ~undecided
        if decided.sum() < 2:  # only the anchor is sure: pick each undecided frame's order jointly with it
            for u in np.flatnonzero(undecided):
                rms = []
                for o in (0, 1):
                    orders[u] = o
                    E2 = errors(fit(np.array([a0, u]), orders))
                    rms.append(max(E2[a0, orders[a0]] / g[a0], E2[u, o] / g[u]))
                orders[u] = int(np.argmin(rms))
            decided = sup
        T = fit(np.flatnonzero(decided), orders)
        inl = decided
        E = errors(T)
        for _ in range(options.rounds):
            best_o = np.argmin(E, axis=1)
            best_e = E[np.arange(len(E)), best_o]
            new_inl = best_e < g
            if new_inl.sum() >= 2:
                med = float(np.median(best_e[new_inl]))
                new_inl &= best_e < max(options.min_gate_mrad * 1e-3, options.robust_factor * med)
            if new_inl.sum() < 2 or (np.array_equal(new_inl, inl) and np.array_equal(best_o, orders)):
                break
            inl, orders = new_inl, best_o
            T = fit(np.flatnonzero(inl), orders)
            E = errors(T)
        best_o = np.argmin(E, axis=1)
        best_e = E[np.arange(len(E)), best_o]
        inl = best_e < g
        if inl.sum() >= 2:
            inl &= best_e < max(
                options.min_gate_mrad * 1e-3, options.robust_factor * float(np.median(best_e[inl]))
            )
        score = (int(inl.sum()), -float(np.sum(np.where(inl, best_e / g, 1.0))))
        return T, E, inl, best_o, score

    # 3. consensus from the best hypothesis
    best_score, a0, sup, undecided, orders = scored[0]
    T, E, inl, best_o, final_score = consensus(a0, sup, undecided, orders)
    if final_score[0] < 2:
        why = "no two frames agree on one extrinsic under either corner order"
        if len(alive) == 2:
            why = "the two frames disagree under either corner order; cannot tell which one is wrong"
        dropped += [(names[j], f"corner order inconsistent with the other frames: {why}") for j in alive]
        return OrderResult({}, dropped, {}, None, why)

    # rivals with as much support but another order assignment: refine them too; if one still ties
    # with a different assignment, the data cannot decide
    ambiguous = None
    key = np.where(inl, best_o, -1)
    tried: list[np.ndarray] = [key]
    for score, a1, sup1, und1, ord1 in scored[1:]:
        if score[0] < best_score[0] or len(tried) > 5:
            break
        k1 = np.where(sup1 & ~und1, ord1, -1)
        if any(np.array_equal(k1, np.where(sup1 & ~und1, t, -1)) for t in tried):
            continue
        T2, E2, inl2, bo2, score2 = consensus(a1, sup1, und1, ord1)
        k2 = np.where(inl2, bo2, -1)
        tried.append(k2)
        if np.array_equal(k2, key) or score2[0] < final_score[0]:
            continue
        ambiguous = (
            f"two extrinsics fit {final_score[0]} frames each with different corner orders "
            f"(frames {', '.join(names[alive[a]] for a in np.flatnonzero(inl | inl2))}); "
            "the one with the smaller error is used"
        )
        log.warning(ambiguous)
        if score2 > final_score:
            T, E, inl, best_o, final_score = T2, E2, inl2, bo2, score2
        break

    # 4. decisions
    flip: dict[str, bool] = {}
    per_frame: dict[str, np.ndarray] = {}
    errs: dict[str, tuple[float, float]] = {}
    best_e = E[np.arange(len(E)), best_o]
    robust = max(options.min_gate_mrad * 1e-3, options.robust_factor * float(np.median(best_e[inl])))
    for a, j in enumerate(alive):
        e0, e1 = 1e3 * E[a, 0], (1e3 * E[a, 1] if np.isfinite(E[a, 1]) else float("nan"))
        errs[names[j]] = (float(e0), float(e1))
        o = int(best_o[a])
        e_list = f"RMS bearing error {e0:.1f} mrad as listed" + (
            f", {e1:.1f} mrad half-turned" if flip_ok[j] else ""
        )
        limit = 1e3 * min(g[a], robust)
        if not inl[a]:
            dropped.append(
                (
                    names[j],
                    f"corner order inconsistent with the other frames: {e_list} "
                    f"under the extrinsic of {int(inl.sum())} frames (gate {limit:.1f} mrad)",
                )
            )
            continue
        other = E[a, 1 - o]
        if np.isfinite(other) and other < g[a]:
            dropped.append(
                (
                    names[j],
                    f"corner order ambiguous: both orders fit the other frames ({e_list}, "
                    f"gate {1e3 * g[a]:.1f} mrad)",
                )
            )
            continue
        flip[names[j]] = bool(o)
        per_frame[names[j]] = own[(j, o)]
    return OrderResult(flip, dropped, per_frame, T, ambiguous, errs)
