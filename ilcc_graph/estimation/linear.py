"""Linear algebra of the arrow-shaped systems: each factor touches at most one board ``B(i)``.

Every other variable (extrinsics, range offsets, the LiDAR's errors, the cameras' intrinsics) is
global. Eliminating the boards first (6x6 blocks) leaves a dense system over the globals, so the
redundancies of Foerstner's variance components and the information of the globals cost O(boards)
plus one dense inverse over the globals.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from ilcc_graph.errors import IndeterminateSystem
from ilcc_graph.estimation.assembly import Term
from ilcc_graph.estimation.keys import POSE3_DOF, is_board, key_dim

__all__ = ["redundancies"]


def _linear_blocks(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, terms: Sequence[Term], dim):
    """Per factor and row kind: (kind, group, board key or None, A_board, global keys, A_globals, b)
    of its whitened linearisation."""
    out = []
    for k, t in enumerate(terms):
        A, b = graph.at(k).linearize(values).jacobian()
        keys = list(graph.at(k).keys())
        col, board_key, A_b, g_keys, g_cols = 0, None, None, [], []
        for key in keys:
            d = dim(key)
            if is_board(key):
                board_key, A_b = key, A[:, col : col + d]
            else:
                g_keys.append(key)
                g_cols.append(A[:, col : col + d])
            col += d
        A_g = np.hstack(g_cols) if g_cols else np.zeros((A.shape[0], 0))
        for kind, r0, r1 in t.parts or ((t.kind, 0, len(b)),):
            rows = slice(r0, r1)
            out.append(
                (kind, t.group, board_key, None if A_b is None else A_b[rows], g_keys, A_g[rows], b[rows])
            )
    return out


def redundancies(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, terms: Sequence[Term], dim=key_dim
) -> dict[tuple[str, str], tuple[float, float]]:
    """Per (kind, group): (whitened chi-square, redundancy ``m_g - trace(N^-1 N_g)``) at ``values``.

    N is the information matrix of the whitened linear system. Boards are eliminated first (each
    factor touches at most one), so the cost is O(boards) plus a dense inverse over the globals.
    ``dim(key)``: the tangent dimension of a variable (``Assembly.dim``).
    """
    blocks = _linear_blocks(graph, values, terms, dim)
    g_index: dict[int, int] = {}
    G = 0
    for *_, g_keys, _, _ in blocks:
        for key in g_keys:
            if key not in g_index:
                g_index[key] = G
                G += dim(key)

    def cols(g_keys: Sequence[int]) -> np.ndarray:
        if not g_keys:
            return np.zeros(0, int)
        return np.concatenate([np.arange(g_index[k], g_index[k] + dim(k)) for k in g_keys])

    D: dict[int, np.ndarray] = {}
    C: dict[int, np.ndarray] = {}
    E = np.zeros((G, G))
    for _, _, board_key, A_b, g_keys, A_g, _ in blocks:
        c = cols(g_keys)
        if board_key is not None:
            D[board_key] = D.get(board_key, np.zeros((POSE3_DOF, POSE3_DOF))) + A_b.T @ A_b
            Ci = C.setdefault(board_key, np.zeros((POSE3_DOF, G)))
            Ci[:, c] += A_b.T @ A_g
        E[np.ix_(c, c)] += A_g.T @ A_g
    Dinv = {k: np.linalg.inv(d) for k, d in D.items()}
    S = E - sum((C[k].T @ Dinv[k] @ C[k] for k in D), np.zeros((G, G)))
    try:
        S_inv = np.linalg.inv(S) if G else S
    except np.linalg.LinAlgError:
        raise IndeterminateSystem("the graph does not determine its global variables") from None
    out: dict[tuple[str, str], list[float]] = {}
    for kind, group, board_key, A_b, g_keys, A_g, b in blocks:
        c = cols(g_keys)
        if board_key is not None:
            di, ci = Dinv[board_key], C[board_key]
            S_bg = -di @ ci @ S_inv  # (6, G)
            S_bb = di - S_bg @ ci.T @ di
            A = np.hstack([A_b, A_g])
            Sig = np.block([[S_bb, S_bg[:, c]], [S_bg[:, c].T, S_inv[np.ix_(c, c)]]])
        else:
            A, Sig = A_g, S_inv[np.ix_(c, c)]
        acc = out.setdefault((kind, group), [0.0, 0.0])
        acc[0] += float(b @ b)
        acc[1] += len(b) - float(np.sum(Sig * (A.T @ A)))
    return {k: (v[0], v[1]) for k, v in out.items()}
