"""The consensus machinery of the corner order across frames (``correspondence.resolve_half_turns``).

Frames: LiDAR corners (K, 3) in the LiDAR frame, unit bearings (K, 3) in the camera frame, each in
one of two candidate orders (as listed, or half-turned by ``perm``). A hypothesis is one frame's own
pose; a consensus is the extrinsic refitted by UPnP on the frames that agree with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcc_graph.init.upnp import upnp

__all__ = [
    "Consensus",
    "Frames",
    "Hypothesis",
    "bearing_errors",
    "half_turn_size",
    "rms",
    "rot_angle",
    "rotation_hypotheses",
]


def bearing_errors(T_cam_lidar: np.ndarray, lidar_corners: np.ndarray, bearings: np.ndarray) -> np.ndarray:
    """Angles (rad) between bearings (..., K, 3) and the directions of T @ corners (..., K, 3)."""
    X = lidar_corners @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]
    cr = np.linalg.norm(np.cross(X, bearings), axis=-1)
    return np.arctan2(cr, np.sum(X * bearings, axis=-1))


def rms(a: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.sqrt(np.mean(a * a, axis=axis))


def _angular_radius(F: np.ndarray) -> float:
    m = F.mean(axis=0)
    m /= max(np.linalg.norm(m), 1e-300)
    return float(rms(np.arctan2(np.linalg.norm(np.cross(F, m), axis=1), F @ m)))


def half_turn_size(F: np.ndarray, perm: np.ndarray | None) -> float:
    """RMS angle (rad) by which the half turn moves the frame's corners in the image (2x the
    board's angular radius when there is no half turn)."""
    if perm is None:
        return 2.0 * _angular_radius(F)
    G = F[perm]
    return float(rms(np.arctan2(np.linalg.norm(np.cross(F, G), axis=1), np.sum(F * G, axis=1))))


def rot_angle(R: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


@dataclass(frozen=True)
class Hypothesis:
    """A single-frame pose as seen by every frame: which frames support it and in which order."""

    score: tuple[int, float]
    anchor: int
    support: np.ndarray  # (n,) bool: rotation within the gate under some order
    undecided: np.ndarray  # (n,) bool: within the gate under both orders
    orders: np.ndarray  # (n,) int: the order closest in rotation
    distance: np.ndarray  # (n,) rad: that rotation distance


def _score_hypothesis(a: int, d: np.ndarray, rot_gate: float) -> Hypothesis:
    """d (n, 2): rotation distance of each frame's orders to the hypothesis from frame a."""
    orders = np.argmin(d, axis=1)
    dmin = d[np.arange(len(d)), orders]
    sup = dmin < rot_gate
    undecided = sup & np.all(d < rot_gate, axis=1)
    score = (int(sup.sum()), -float(np.sum(np.where(sup, dmin / rot_gate, 1.0))))
    return Hypothesis(score, a, sup, undecided, orders, dmin)


@dataclass(frozen=True)
class Consensus:
    T: np.ndarray  # (4, 4) T_cam_lidar
    E: np.ndarray  # (n, 2) RMS bearing error per frame and order, rad
    inliers: np.ndarray  # (n,) bool
    orders: np.ndarray  # (n,) int
    score: tuple[int, float]  # (frames agreeing, -sum of their errors / noise)

    @property
    def key(self) -> np.ndarray:
        return np.where(self.inliers, self.orders, -1)


class Frames:
    """The frames that have a pose of their own, and the consensus machinery over them."""

    def __init__(
        self,
        L: list[np.ndarray],
        F: list[np.ndarray],
        perm: np.ndarray | None,
        flip_ok: list[bool],
        gate: np.ndarray,
        strict_gate: np.ndarray,
        noise: float,
        rounds: int,
    ) -> None:
        """L, F: per frame corners and bearings; perm: the half turn's permutation or None; flip_ok:
        per frame, may its order flip; gate: (n,) rad, gate_rel x the half turn's size in the image;
        strict_gate: (n,) rad, the agreement gate (also bounded by the noise); noise: rad, the median
        own-pose RMS error; rounds: refits of a consensus."""
        self.L, self.F, self.perm, self.flip_ok = L, F, perm, flip_ok
        self.g = gate
        self.noise = noise
        self.gk = strict_gate
        self.rounds = rounds
        # every frame with as many corners: all frames' errors at once (the same numbers)
        same = len({x.shape for x in L}) == 1 and len({x.shape for x in F}) == 1
        self._stacked = (np.stack(L), np.stack(F), np.stack([self.oriented(a, 1) for a in range(len(F))])
                         if perm is not None else None) if same and L else None  # fmt: skip

    def oriented(self, a: int, o: int) -> np.ndarray:
        return self.F[a][self.perm] if o else self.F[a]

    def errors(self, T: np.ndarray) -> np.ndarray:
        """(n, 2) RMS bearing error (rad) of each frame per order; inf where it cannot flip."""
        E = np.full((len(self.L), 2), np.inf)
        if self._stacked is not None:
            Ls, F0, F1 = self._stacked
            E[:, 0] = rms(bearing_errors(T, Ls, F0))
            if F1 is not None:
                flip = np.asarray(self.flip_ok, dtype=bool)
                E[flip, 1] = rms(bearing_errors(T, Ls[flip], F1[flip]))
            return E
        for a in range(len(self.L)):
            for o in (0, 1) if self.flip_ok[a] else (0,):
                E[a, o] = rms(bearing_errors(T, self.L[a], self.oriented(a, o)))
        return E

    def fit(self, idx: np.ndarray, orders: np.ndarray) -> np.ndarray:
        """T_cam_lidar by UPnP on the frames idx in the given orders."""
        P = np.vstack([self.L[a] for a in idx])
        B = np.vstack([self.oriented(a, int(orders[a])) for a in idx])
        return upnp(P, B, prefer_front=True, tie_rtol=np.inf)[0].T_cam_points

    def evaluate(self, T: np.ndarray) -> Consensus:
        E = self.errors(T)
        orders = np.argmin(E, axis=1)
        best = E[np.arange(len(E)), orders]
        inl = best < self.gk
        return Consensus(T, E, inl, orders, (int(inl.sum()), -float(np.sum(best[inl])) / self.noise))

    def consensus(self, T: np.ndarray) -> Consensus:
        """Refit on the frames that agree with T, re-assign their orders, until stable."""
        c = self.evaluate(T)
        for _ in range(self.rounds):
            if c.inliers.sum() < 2:
                break
            c2 = self.evaluate(self.fit(np.flatnonzero(c.inliers), c.orders))
            if c2.score < c.score:
                break
            stable = np.array_equal(c2.key, c.key)
            c = c2
            if stable:
                break
        return c


def rotation_hypotheses(
    own: dict[tuple[int, int], list[np.ndarray]], alive: list[int], rot_gate: float, max_frames: int
) -> list[Hypothesis]:
    """Every frame's own pose in each order as a hypothesis, best supported first; a frame supports one
    when its own rotation under one of its orders is within ``rot_gate`` rad (cheap, and blind to the
    big lever-arm errors of one-board translations).

    own: (frame j, order o) -> candidate (4, 4) poses of frame j alone; alive: the frames that have
    one; max_frames: at most this many frames (evenly spread) anchor hypotheses.
    """
    n_c = max(len(v) for v in own.values())
    Rown = np.full((len(alive), 2, n_c, 3, 3), np.nan)
    for a, j in enumerate(alive):
        for o in (0, 1):
            for c, Tc in enumerate(own.get((j, o), [])):
                Rown[a, o, c] = Tc[:3, :3]
    step = max(1, int(np.ceil(len(alive) / max_frames)))
    hyps: list[Hypothesis] = []
    for a in range(0, len(alive), step):
        for o in (0, 1):
            for c in range(len(own.get((alive[a], o), []))):
                tr = np.einsum("ij,kocij->koc", Rown[a, o, c], Rown)
                d = np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))
                d = np.where(np.isnan(d), np.inf, d).min(axis=2)
                d[a, 1 - o] = np.inf  # the anchor's order is the hypothesis
                hyps.append(_score_hypothesis(a, d, rot_gate))
    hyps.sort(key=lambda h: h.score, reverse=True)
    return hyps
