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

from ilcc_graph.errors import ORDER_AMBIGUOUS, ORDER_INCONSISTENT
from ilcc_graph.init.consensus import (
    Consensus,
    Frames,
    Hypothesis,
    bearing_errors,
    half_turn_size,
    rms,
    rot_angle,
    rotation_hypotheses,
)
from ilcc_graph.init.upnp import upnp

__all__ = ["OrderOptions", "OrderResult", "resolve_half_turns", "bearing_errors"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OrderOptions:
    """Gates of the cross-frame consistency check.

    gate_rel: a frame agrees with an extrinsic when its RMS bearing error is below ``gate_rel`` x
        the RMS angle by which the half turn moves its corners in the image (what the wrong order
        costs under the right extrinsic; twice the board's angular radius when there is no half turn).
    robust_factor, min_gate_mrad: a frame agrees only when its error is also below
        ``max(min_gate_mrad, robust_factor * noise)``, noise being the median over frames of each
        frame's RMS bearing error under its own pose (an outlier fits itself, so it cannot inflate it).
    rot_gate_deg: hypotheses from single frames: a frame supports another's pose when their
        rotations differ by less than this (the wrong half turn differs by twice the angle between
        the two boards' normals).
    cand_cost_ratio, max_candidates: per frame and order, the UPnP minima with the corners in front
        and a cost within this ratio of the best are all hypotheses (planar PnP's tilt ambiguity).
    rounds: re-estimation rounds of the consensus.
    max_hypotheses_frames: frames whose own poses are tried as hypotheses (evenly spread).
    max_pair_fits, partners_per_hypothesis: joint fits of a frame with frames whose rotation agrees.
    consensus_tries: distinct pair fits grown to a full consensus.
    exhaustive_frames: with at most this many frames and no two rotations agreeing, every pair of
        frames in every order is fitted jointly instead.
    ambiguity_ratio: a rival consensus with as many frames and a bearing-error sum within this ratio
        of the best makes the result ambiguous.
    """

    gate_rel: float = 0.5
    rot_gate_deg: float = 10.0
    cand_cost_ratio: float = 4.0
    max_candidates: int = 3
    robust_factor: float = 8.0
    min_gate_mrad: float = 5.0
    rounds: int = 5
    max_pair_fits: int = 24
    partners_per_hypothesis: int = 4
    consensus_tries: int = 6
    ambiguity_ratio: float = 2.0
    exhaustive_frames: int = 6
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


def _check_inputs(
    lidar_corners: Sequence[np.ndarray],
    bearings: Sequence[np.ndarray],
    perm: np.ndarray | None,
    names: list[str],
    flippable: Sequence[bool] | None,
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray | None, list[bool]]:
    """The inputs checked (ValueError saying what is wrong): corners and unit bearings per frame as
    float64, ``perm`` as int64, and per frame whether its order may be flipped."""
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
    # 1. each frame's own pose in each candidate order
    own, own_rms, alive, dropped = _own_poses(L, F, perm, flip_ok, names, options)
    if not alive:
        return OrderResult({}, dropped, {})

    if len(alive) == 1:
        j = alive[0]
        amb = (
            f"frame {names[j]} is the only one: its half turn cannot be resolved from the data"
            if flip_ok[j]
            else None
        )
        if amb:
            log.warning(amb)
        return OrderResult({names[j]: False}, dropped, {names[j]: own[(j, 0)][0]}, own[(j, 0)][0], amb)

    # 2. hypotheses: every frame's own pose in each order, best supported first
    rot_gate = np.radians(options.rot_gate_deg)
    hyps = rotation_hypotheses(own, alive, rot_gate, options.max_hypotheses_frames)

    # noise scale: each frame's RMS bearing error under its own pose (an outlier frame fits itself)
    noise = max(float(np.median([own_rms[j] for j in alive])), 1e-6)
    gate = np.array([options.gate_rel * half_turn_size(F[j], perm) for j in alive])
    strict = np.minimum(gate, max(options.min_gate_mrad * 1e-3, options.robust_factor * noise))
    fr = Frames(
        [L[j] for j in alive], [F[j] for j in alive], perm, [flip_ok[j] for j in alive], gate, strict, noise,
        options.rounds,
    )  # fmt: skip

    # 3. pair hypotheses: the best-supported single-frame poses, each with the frames whose rotation
    # agrees best, fitted jointly (a pair fixes the extrinsic far better than one board); each grown
    # to a consensus; the most frames win, then the smaller bearing errors
    finals = _consensuses(fr, _pairs(hyps, fr, len(alive), options), options)
    if not finals or finals[0].score[0] < 2:
        why = "no two frames agree on one extrinsic under either corner order"
        if len(alive) == 2:
            why = "the two frames disagree under either corner order; cannot tell which one is wrong"
        dropped += [(names[j], f"{ORDER_INCONSISTENT} with the other frames: {why}") for j in alive]
        return OrderResult({}, dropped, {}, None, why)
    best = finals[0]
    ambiguous = _rival(best, finals, [names[j] for j in alive], options)

    # 4. decisions
    flip: dict[str, bool] = {}
    per_frame: dict[str, np.ndarray] = {}
    errs: dict[str, tuple[float, float]] = {}
    for a, j in enumerate(alive):
        errs[names[j]], o, reason = _decide(best, fr, a)
        if reason is not None:
            dropped.append((names[j], reason))
            continue
        flip[names[j]] = bool(o)
        cands = own[(j, o)]
        per_frame[names[j]] = min(cands, key=lambda Tc: rot_angle(Tc[:3, :3].T @ best.T[:3, :3]))
    return OrderResult(flip, dropped, per_frame, best.T, ambiguous, errs)


def _own_poses(
    L: list[np.ndarray],
    F: list[np.ndarray],
    perm: np.ndarray | None,
    flip_ok: list[bool],
    names: list[str],
    options: OrderOptions,
) -> tuple[dict[tuple[int, int], list[np.ndarray]], dict[int, float], list[int], list[tuple[str, str]]]:
    """Each frame's own poses (``T_cam_lidar`` candidates) by (frame, order: 0 as listed, 1
    half-turned), its RMS bearing error under its best pose as listed, the frames that have poses
    and those dropped (name, reason)."""
    own: dict[tuple[int, int], list[np.ndarray]] = {}
    own_rms: dict[int, float] = {}
    alive: list[int] = []
    dropped: list[tuple[str, str]] = []
    for j in range(len(names)):
        try:
            for o in (0, 1) if flip_ok[j] else (0,):
                sols = upnp(L[j], _oriented(F[j], perm, o), prefer_front=True, tie_rtol=np.inf)
                front = [s for s in sols if s.front_fraction > 0.5]
                if not front:
                    raise ValueError("no pose puts its corners in front of the camera")
                # a planar board's pose has a second, tilted minimum of similar cost (the planar PnP
                # ambiguity): keep every front minimum within cand_cost_ratio of the best
                own[(j, o)] = [
                    s.T_cam_points
                    for s in front[: options.max_candidates]
                    if s.cost <= options.cand_cost_ratio * front[0].cost + 1e-15
                ]
            own_rms[j] = float(rms(bearing_errors(own[(j, 0)][0], L[j], _oriented(F[j], perm, 0))))
            alive.append(j)
        except ValueError as e:
            dropped.append(
                (names[j], f"{ORDER_INCONSISTENT} with the other frames: no pose from its corners ({e})")
            )
    return own, own_rms, alive, dropped


def _oriented(bearings: np.ndarray, perm: np.ndarray | None, o: int) -> np.ndarray:
    """A frame's bearings in order ``o`` (1: re-indexed by the half turn ``perm``)."""
    return bearings[perm] if o else bearings


def _pairs(
    hyps: Sequence[Hypothesis], fr: Frames, n: int, options: OrderOptions
) -> list[tuple[int, int, int, int]]:
    """(frame a, its order, frame b, its order) of the pairs to fit: each hypothesis's anchor with
    the frames whose rotation agrees best; with none and few frames, every pair in every order."""
    pairs: list[tuple[int, int, int, int]] = []
    for h in hyps:
        if len(pairs) >= options.max_pair_fits:
            break
        partners = [int(b) for b in np.flatnonzero(h.support) if b != h.anchor]
        partners.sort(key=lambda b: h.distance[b])
        for b in partners[: options.partners_per_hypothesis]:
            for ob in (0, 1) if h.undecided[b] else (int(h.orders[b]),):
                key = (h.anchor, int(h.orders[h.anchor]), b, ob)
                if key not in pairs and (key[2], key[3], key[0], key[1]) not in pairs:
                    pairs.append(key)
    pairs = pairs[: options.max_pair_fits]
    if not pairs and n <= options.exhaustive_frames:
        # no two single-frame rotations agree (far boards: a single board's tilt can be off by
        # more than the gate): with few frames, try every pair in every order
        pairs = [
            (a, oa, b, ob)
            for a in range(n)
            for b in range(a + 1, n)
            for oa in ((0, 1) if fr.flip_ok[a] else (0,))
            for ob in ((0, 1) if fr.flip_ok[b] else (0,))
        ]
    return pairs


def _consensuses(
    fr: Frames, pairs: Sequence[tuple[int, int, int, int]], options: OrderOptions
) -> list[Consensus]:
    """Each pair fitted jointly, the best-scoring ones grown to distinct consensuses, best first."""
    starts = []
    for a, oa, b, ob in pairs:
        orders = np.zeros(len(fr.L), dtype=int)
        orders[a], orders[b] = oa, ob
        starts.append(fr.evaluate(fr.fit(np.array([a, b]), orders)))
    starts.sort(key=lambda c: c.score, reverse=True)
    finals: list[Consensus] = []
    for c0 in starts:
        if len(finals) >= options.consensus_tries:
            break
        c = fr.consensus(c0.T)
        if not any(np.array_equal(c.key, f.key) for f in finals):
            finals.append(c)
    finals.sort(key=lambda c: c.score, reverse=True)
    return finals


def _rival(
    best: Consensus, finals: Sequence[Consensus], names: list[str], options: OrderOptions
) -> str | None:
    """Why the data cannot decide, when a rival consensus has as many frames, other orders or
    frames, and errors of the same size (``names``: of the frames in the consensuses); else None."""
    for rival in finals[1:]:
        if rival.score[0] == best.score[0] and -rival.score[1] <= options.ambiguity_ratio * max(
            -best.score[1], 1e-9
        ):
            both = ", ".join(names[a] for a in np.flatnonzero(best.inliers | rival.inliers))
            ambiguous = (
                f"two extrinsics fit {best.score[0]} frames each, with different corner orders or frames "
                f"(frames {both}): the data do not tell which is right"
            )
            log.warning(ambiguous)
            return ambiguous
    return None


def _decide(best: Consensus, fr: Frames, a: int) -> tuple[tuple[float, float], int, str | None]:
    """Frame ``a``'s RMS bearing errors (mrad: as listed, half-turned) under the consensus, its order
    there and, when it is dropped, why."""
    E = best.E
    e0, e1 = 1e3 * E[a, 0], (1e3 * E[a, 1] if np.isfinite(E[a, 1]) else float("nan"))
    o = int(best.orders[a])
    e_list = f"RMS bearing error {e0:.1f} mrad as listed" + (
        f", {e1:.1f} mrad half-turned" if fr.flip_ok[a] else ""
    )
    limit = 1e3 * fr.gk[a]
    why = None
    if not best.inliers[a]:
        why = (
            f"{ORDER_INCONSISTENT} with the other frames: {e_list} "
            f"under the extrinsic of {int(best.inliers.sum())} frames (gate {limit:.1f} mrad)"
        )
    elif np.isfinite(E[a, 1 - o]) and E[a, 1 - o] < fr.g[a]:
        why = f"{ORDER_AMBIGUOUS}: both orders fit the other frames ({e_list}, gate {1e3 * fr.g[a]:.1f} mrad)"
    return (float(e0), float(e1)), o, why
