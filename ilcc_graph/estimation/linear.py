"""Linear algebra of the arrow-shaped systems: each factor touches at most one board ``B(i)``.

Every other variable (extrinsics, range offsets, the LiDAR's errors, the cameras' intrinsics) is
global. Eliminating the boards first (6x6 blocks) leaves a dense system over the globals, so the
redundancies of Foerstner's variance components and the information of the globals cost O(boards)
plus one dense inverse over the globals.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import gtsam
import numpy as np

from ilcc_graph.errors import IndeterminateSystem
from ilcc_graph.estimation.assembly import Term
from ilcc_graph.estimation.keys import POSE3_DOF, I, X, is_board, key_dim

if TYPE_CHECKING:
    from ilcc_graph.estimation.noise import Solution

__all__ = ["Reduced", "consider_covariance", "reduce", "redundancies"]


#: ``extra(k, term)``: virtual rows of factor k as [(kind, first row, end row, Z (rows, n))]: the rows
#: ``Z^T`` of its rows first..end (e.g. a random effect marginalised in their whitening,
#: ``BoardPointsFactor.plane_rows``); they enter no information, only the chi-squares and redundancies
Extra = Callable[[int, Term], Sequence[tuple[str, int, int, np.ndarray]]]
#: a variable's dimension by key (``keys.key_dim``, or an assembly's ``dim``)
Dim = Callable[[int], int]
#: rows of one factor and kind: (kind, group, board key or None, A_board or None, global keys,
#: A_globals, b, count: None for its own rows, ``Z^T Z`` for virtual ones)
Block = tuple[
    str, str, "int | None", "np.ndarray | None", list[int], np.ndarray, np.ndarray, "np.ndarray | None"
]


def _linear_blocks(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, terms: Sequence[Term], dim: Dim,
    extra: Extra | None = None,
) -> list[Block]:  # fmt: skip
    """Per factor and row kind: (kind, group, board key or None, A_board, global keys, A_globals, b,
    count) of its whitened linearisation; count is None for its own rows, ``Z^T Z`` for the virtual
    rows ``Z^T`` of ``extra``."""
    out: list[Block] = []
    for k, t in enumerate(terms):
        A, b = graph.at(k).linearize(values).jacobian()
        keys = list(graph.at(k).keys())
        col, board_key, A_b = 0, None, None
        g_keys: list[int] = []
        g_cols: list[np.ndarray] = []
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
                (
                    kind,
                    t.group,
                    board_key,
                    None if A_b is None else A_b[rows],
                    g_keys,
                    A_g[rows],
                    b[rows],
                    None,
                )
            )
        for kind, r0, r1, Z in extra(k, t) if extra is not None else ():
            rows = slice(r0, r1)
            out.append(
                (kind, t.group, board_key, None if A_b is None else Z.T @ A_b[rows], g_keys, Z.T @ A_g[rows],
                 Z.T @ b[rows], Z.T @ Z)
            )  # fmt: skip
    return out


@dataclass
class Reduced:
    """The boards eliminated from a whitened linear system: per board its information ``D`` (inverted,
    ``Dinv``) and coupling ``C`` to the globals, and the globals' information ``S`` (Schur complement)
    with each global key's first column in ``index``."""

    blocks: list[Block]
    index: dict[int, int]
    dims: dict[int, int]
    Dinv: dict[int, np.ndarray]
    C: dict[int, np.ndarray]
    S: np.ndarray
    _cols: dict[tuple[int, ...], np.ndarray] = field(default_factory=dict)

    def cols(self, keys: Sequence[int]) -> np.ndarray:
        """The columns of the global ``keys`` in ``S``, in that order (kept per key tuple)."""
        got = self._cols.get(t := tuple(keys))
        if got is None:
            parts = [np.arange(self.index[k], self.index[k] + self.dims[k]) for k in keys]
            got = self._cols[t] = np.concatenate(parts) if parts else np.zeros(0, int)
        return got


def reduce(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, terms: Sequence[Term], dim: Dim = key_dim,
    skip: Sequence[str] = (), extra: Extra | None = None,
) -> Reduced:  # fmt: skip
    """Linearise ``graph`` at ``values`` (whitened) and eliminate the boards; rows of the kinds in
    ``skip`` are left out (e.g. a prior, to get the data's information alone); ``extra``: virtual
    rows kept in ``blocks`` (no information)."""
    blocks = [b for b in _linear_blocks(graph, values, terms, dim, extra) if b[0] not in skip]
    index: dict[int, int] = {}
    dims: dict[int, int] = {}
    G = 0
    for *_, g_keys, _, _, _ in blocks:
        for key in g_keys:
            if key not in index:
                index[key], dims[key] = G, dim(key)
                G += dims[key]
    red = Reduced(blocks, index, dims, {}, {}, np.zeros((G, G)))
    D: dict[int, np.ndarray] = {}
    for _, _, board_key, A_b, g_keys, A_g, _, count in blocks:
        if count is not None:
            continue  # virtual rows: no information of their own
        c = red.cols(g_keys)
        if board_key is not None and A_b is not None:  # a board's rows have its columns
            D[board_key] = D.get(board_key, np.zeros((POSE3_DOF, POSE3_DOF))) + A_b.T @ A_b
            Ci = red.C.setdefault(board_key, np.zeros((POSE3_DOF, G)))
            Ci[:, c] += A_b.T @ A_g
        red.S[np.ix_(c, c)] += A_g.T @ A_g
    red.Dinv = {k: np.linalg.inv(d) for k, d in D.items()}
    for k, ci in red.C.items():
        red.S -= ci.T @ red.Dinv[k] @ ci
    return red


def redundancies(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, terms: Sequence[Term], dim: Dim = key_dim,
    extra: Extra | None = None, information: dict[tuple[str, str], float] | None = None,
) -> dict[tuple[str, str], tuple[float, float]]:  # fmt: skip
    """Per (kind, group): (whitened chi-square, redundancy ``m_g - trace(N^-1 N_g)``) at ``values``.

    N is the information matrix of the whitened linear system. Boards are eliminated first (each
    factor touches at most one), so the cost is O(boards) plus a dense inverse over the globals.
    ``dim(key)``: the tangent dimension of a variable (``Assembly.dim``). ``extra``: virtual rows
    ``Z^T`` of a random effect marginalised in some rows (``Extra``): their chi-square is
    ``|Z^T r|^2`` and their redundancy ``trace(Z^T Z) - trace(N^-1 A^T Z Z^T A)`` (the random
    effect made explicit with its prior as pseudo-observations gives the same numbers).
    ``information``: filled, per kind of virtual rows, with ``sum ||Z^T P Z||_F^2`` over the factors
    (P the residuals' projector; each factor's own block, the couplings between boards left out):
    twice the expected information of the random effect's variance scale (Fisher scoring).
    """
    red = reduce(graph, values, terms, dim, extra=extra)
    G = len(red.S)
    try:
        S_inv = np.linalg.inv(red.S) if G else red.S
    except np.linalg.LinAlgError:
        raise IndeterminateSystem("the graph does not determine its global variables") from None
    out: dict[tuple[str, str], list[float]] = {}
    sigs: dict[tuple[int | None, tuple[int, ...]], np.ndarray] = {}  # a board's rows share its Sig
    for kind, group, board_key, A_b, g_keys, A_g, b, count in red.blocks:
        bk = board_key if A_b is not None else None
        Sig = sigs.get(sk := (bk, tuple(g_keys)))
        if Sig is None:
            Sig = sigs[sk] = _joint_inverse(red, S_inv, bk, g_keys)
        A = np.hstack([A_b, A_g]) if A_b is not None and bk is not None else A_g
        acc = out.setdefault((kind, group), [0.0, 0.0])
        acc[0] += float(b @ b)
        if count is None:
            acc[1] += len(b) - float(np.sum(Sig * (A.T @ A)))
            continue
        ZPZ = count - A @ Sig @ A.T
        acc[1] += float(np.trace(ZPZ))
        if information is not None:
            information[(kind, group)] = information.get((kind, group), 0.0) + float(np.sum(ZPZ * ZPZ))
    return {k: (v[0], v[1]) for k, v in out.items()}


def _joint_inverse(
    red: Reduced, S_inv: np.ndarray, board_key: int | None, g_keys: Sequence[int]
) -> np.ndarray:
    """The inverse information of ``board_key`` (None: no board) and the global ``g_keys``, jointly
    (the board's block first): what a factor's rows on those variables see of ``N^-1``."""
    c = red.cols(g_keys)
    if board_key is None:
        return S_inv[np.ix_(c, c)]
    di, ci = red.Dinv[board_key], red.C[board_key]
    S_bg = -di @ ci @ S_inv  # (6, G)
    S_bb = di - S_bg @ ci.T @ di
    return np.block([[S_bb, S_bg[:, c]], [S_bg[:, c].T, S_inv[np.ix_(c, c)]]])


def consider_covariance(sol: Solution, e: int = 0) -> np.ndarray:
    """(6, 6) what the stated sigmas of the cameras' unrefined intrinsics add to extrinsic ``e``'s
    covariance, to first order: ``J Sigma_theta J^T`` with ``J = -S_rr^-1 S_r_theta`` from the data's
    information over the globals (the intrinsics as variables, without a prior)."""
    from ilcc_graph.estimation.assembly import Assembly
    from ilcc_graph.estimation.intrinsics import refinable

    asm = sol.assembly
    stated = {c for c, cam in enumerate(asm.cameras)
              if c not in asm.refined and refinable(cam) and cam.intrinsics_sigma is not None}  # fmt: skip
    if not stated:
        return np.zeros((POSE3_DOF, POSE3_DOF))
    alt = Assembly(sol.problem, None, asm.layouts, refine=stated, per_view=asm.per_view)
    cams = alt.view_cameras(sol.boards)
    if not cams:
        return np.zeros((POSE3_DOF, POSE3_DOF))
    graph, terms = alt.graph(sol.boards, sol.scales)
    values = gtsam.Values(sol.values)
    for c in cams:
        values.insert(I(c), alt.cameras[c].intrinsics())
    red = reduce(graph, values, terms, alt.dim, skip=("intrinsics",))
    theta_keys = [I(c) for c in cams]
    th = red.cols(theta_keys)
    rest = np.setdiff1d(np.arange(len(red.S)), th)
    J = -np.linalg.solve(red.S[np.ix_(rest, rest)], red.S[np.ix_(rest, th)])
    x = np.searchsorted(rest, red.cols([X(e)]))
    sig = np.concatenate([np.asarray(alt.cameras[c].intrinsics_sigma, dtype=np.float64) for c in cams])
    Jx = J[x]
    add = Jx @ np.diag(sig**2) @ Jx.T
    return 0.5 * (add + add.T)
