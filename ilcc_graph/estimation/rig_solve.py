"""Rig strategy: every camera and LiDAR of a rig in one graph, one board per moment (issue 24).

Variables: ``B(i)`` the board of moment i in the base LiDAR's frame (the rig's first LiDAR);
``X(c) = T_cam_base`` per camera c (``p_cam = X(c) p_base``); ``Y(l) = T_base_lidar`` per other
LiDAR l (``kinds.lidar_boards``). Factors: the base LiDAR's board fits as board priors (a board it
did not see has none), every other LiDAR's fits as ``BetweenFactorPose3(Y(l), B(i))``, every
camera's view as a grouped bearing factor on ``(X(c), B(i))``. Noise groups: the base LiDAR's
boards, each other LiDAR's boards and each camera's views have their own (with
``NoiseOptions.view_components`` every view its own bearing component); solved by the core's noise
policy (``noise.solve_problem``: gate, variance components, final factor).

The base LiDAR's sensor model is chosen, and the cameras' intrinsics refined when asked or when the
boards support them, by the pair's one solve (``sources.solve_sources`` over ``RigOptions.models``,
the pair's candidates ``batch.sensor_models``; the intrinsics' choice, ``camera_choice``, each
camera judged as a pair's): each candidate reads the base LiDAR's boards its way (``none``: their 6-dof poses;
``range`` and ``beams``: their returns with the LiDAR's own range errors; ``offset``: one range
offset), is solved under the noise policy and scored by every camera's views held out in turn; the
joint covariance carries the candidates the boards cannot tell apart (``selection.mixture`` over the
graph's poses; the refined intrinsics' solve alone, times its held-out factor, as a pair's). The
other LiDARs' boards enter as 6-dof fits in every candidate. A rig of one camera and one LiDAR is
today's single-pair problem and gives the batch answer (``batch.solve`` with the same ``models``).

Answer: every sensor's ``T_ref_sensor`` in the frame of a chosen reference sensor (a camera or any
LiDAR) with their joint covariance, and any pair's ``T_a_b`` with its own. Covariances follow
interface.md: ``T_true = T_est Exp(xi)``, xi = (rotation, translation), rad and m. From the base
frame: a camera's ``T_base_cam = X^-1`` perturbs by ``-Ad(X) xi``; a pose ``T_ref_s = T_base_ref^-1
T_base_s`` by ``d_s - Ad(T_s_ref) d_ref`` (``d`` the base-frame perturbations).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from gtsam.symbol_shorthand import Y

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel, RefinedIntrinsics
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation.batch import sensor_models
from ilcc_graph.estimation.gate import BoardStats
from ilcc_graph.estimation.geometry import same_pose
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.keys import POSE3_DOF, X
from ilcc_graph.estimation.kinds.lidar_boards import LidarBoard, LidarBoards
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.next_board import solved_globals
from ilcc_graph.estimation.noise import NoiseOptions, Solution
from ilcc_graph.estimation.problem import BoardPrior, Problem, View
from ilcc_graph.estimation.selection import AUTO, MODELS, Selection, SensorModel, mixture
from ilcc_graph.estimation.sources import solve_sources
from ilcc_graph.init.rig_start import RigStart, adjoint, orient_moment
from ilcc_graph.types import Estimate, MomentResult, PoseTerms

__all__ = ["RigOptions", "RigSolution", "between", "rig_problem", "solve_rig", "to_reference"]


@dataclass(frozen=True)
class RigOptions:
    """noise: the noise policy. models: the base LiDAR's sensor models to choose among
    (``selection.MODELS`` names; one name forces it; default the pair's ``selection.AUTO``);
    lidar_errors: the ``beams`` model's options. range_offset: force the ``offset`` model, the base
    LiDAR's range offset with the weak prior ``range_offset_prior_sigma_m`` (``models`` then unused);
    samples_board: (M, 3) board-face points for it (None: from the corners). intrinsics,
    intrinsics_choice: the cameras' intrinsics as a pair's ``sources.solve_sources`` takes them
    (refined when asked, or with ``auto`` each camera's when the boards support it)."""

    noise: NoiseOptions = NoiseOptions()
    models: tuple[str, ...] = AUTO
    range_offset: bool = False
    range_offset_prior_sigma_m: float = 0.1
    samples_board: np.ndarray | None = None
    lidar_errors: LidarErrorOptions | None = None
    intrinsics: IntrinsicsOptions | None = None
    intrinsics_choice: str = "stated"

    def candidates(self) -> list[SensorModel]:
        """The sensor models solved (``batch.sensor_models``, the ``beams`` model with
        ``lidar_errors``; ``range_offset``: ``offset`` alone)."""
        if self.range_offset:
            return [replace(MODELS["offset"], range_offset_m=self.range_offset_prior_sigma_m)]
        return sensor_models(self.models, self.lidar_errors)


def between(T_ref_a: np.ndarray, T_ref_b: np.ndarray, C: np.ndarray) -> Estimate:
    """``T_a_b = T_ref_a^-1 T_ref_b`` with its covariance from the (12, 12) joint covariance ``C``
    of (``T_ref_a``, ``T_ref_b``): ``xi_ab = xi_b - Ad(T_b_a) xi_a``."""
    T_ab = np.linalg.solve(T_ref_a, T_ref_b)
    J = np.hstack([-adjoint(np.linalg.inv(T_ab)), np.eye(POSE3_DOF)])
    S = J @ C @ J.T
    return Estimate(T_ab, 0.5 * (S + S.T))


def to_reference(
    T_base: Mapping[str, np.ndarray], C_base: np.ndarray, reference: str
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Poses ``T_base_s`` (in ``T_base``'s order) and their (6N, 6N) joint covariance re-expressed
    in sensor ``reference``'s frame: ``T_ref_s`` and the joint covariance (the reference's block
    zero)."""
    names = list(T_base)
    r = names.index(reference)
    M = np.eye(POSE3_DOF * len(names))
    out = {}
    for k, s in enumerate(names):
        out[s] = np.linalg.solve(T_base[reference], T_base[s])
        sl = slice(POSE3_DOF * k, POSE3_DOF * (k + 1))
        M[sl, POSE3_DOF * r : POSE3_DOF * (r + 1)] -= adjoint(np.linalg.inv(out[s]))
    C = M @ C_base @ M.T
    return out, 0.5 * (C + C.T)


@dataclass(frozen=True)
class RigSolution:
    """The rig's answer.

    sensors: the sensors solved, in the rig's order. reference: the sensor whose frame the poses are
    in. base: the base LiDAR (the graph's frame). T_ref_sensor: {sensor: (4, 4)}. covariance: (6N,
    6N) their joint covariance in ``sensors`` order (right tangent, rotation first; the reference's
    block zero). T_base_board: the refined boards of the kept moments. per_moment: their residual
    statistics. dropped: ``(moment, reason)`` of the boards the graph left out (the gate, or seen by
    one sensor only); left_out: ``(moment, sensor, reason)`` of observations the start left out.
    unsolved: {sensor: reason} of the rig's sensors without an answer. scales: the variance
    components by (kind, noise group); variance_factor: the final factor. range_offset: the base
    LiDAR's (value, sigma) metres when the model estimates it. solution: the core's
    ``noise.Solution`` of the chosen model (graph frame). selection: the base LiDAR's sensor model
    chosen and the evidence (``selection.Selection``; with candidates the boards could not tell
    apart, ``covariance`` is averaged over them).
    """

    sensors: tuple[str, ...]
    reference: str
    base: str
    T_ref_sensor: dict[str, np.ndarray]
    covariance: np.ndarray
    T_base_board: dict[str, np.ndarray]
    per_moment: dict[str, BoardStats]
    dropped: list[tuple[str, str]]
    left_out: list[tuple[str, str, str]] = field(default_factory=list)
    unsolved: dict[str, str] = field(default_factory=dict)
    scales: dict[tuple[str, str], float] = field(default_factory=dict)
    variance_factor: float = 1.0
    iterations: int = 0
    range_offset: tuple[float, float] | None = None
    solution: Solution | None = None
    selection: Selection | None = None

    def _slice(self, s: str) -> slice:
        k = self.sensors.index(s)
        return slice(POSE3_DOF * k, POSE3_DOF * (k + 1))

    def joint(self, sensors: Sequence[str]) -> np.ndarray:
        """(6n, 6n) joint covariance of the poses of ``sensors``, in that order."""
        idx = np.concatenate([np.arange(POSE3_DOF * len(self.sensors))[self._slice(s)] for s in sensors])
        return self.covariance[np.ix_(idx, idx)]

    def pose(self, s: str) -> Estimate:
        """``T_ref_s`` with its covariance."""
        return Estimate(self.T_ref_sensor[s], self.covariance[self._slice(s), self._slice(s)])

    def relative(self, a: str, b: str) -> Estimate:
        """``T_a_b`` (``p_a = T_a_b p_b``) with its covariance (e.g. ``relative(cam, lidar)`` is the
        pair's ``T_cam_lidar``)."""
        return between(self.T_ref_sensor[a], self.T_ref_sensor[b], self.joint([a, b]))

    def camera_terms(self, cameras: Sequence[str]) -> dict[str, PoseTerms]:
        """{camera: its ``T_camera_lidar`` in the base LiDAR's frame with that LiDAR's range terms}
        for every solved camera of the rig's ``cameras`` (graph extrinsic ``X(c)``, c its place
        there), each covariance times the chosen model's held-out factor as a pair's
        ``Calibration.with_terms`` (``next_board.solved_globals``); empty without terms."""
        if self.solution is None:
            return {}
        factor = 1.0 if self.selection is None else self.selection.factor
        out = {}
        for c, name in enumerate(cameras):
            t = solved_globals(self.solution, c).pose_terms(factor) if name in self.sensors else None
            if t is not None:
                out[name] = t
        return out

    def intrinsics(self, camera: str) -> RefinedIntrinsics | None:
        """``camera``'s refined intrinsics (its views' ``I(c)``), or None when they were taken as
        stated."""
        views = [] if self.solution is None else self.solution.problem.views
        j = next((j for j, v in enumerate(views) if v.group == camera), None)
        if self.solution is None or j is None:
            return None
        got = self.solution.intrinsics(self.solution.assembly.camera_of(j))
        if got is None:
            return None
        names, values, sigmas = got
        return RefinedIntrinsics(tuple(names), views[j].camera.intrinsics(), values, sigmas)

    def in_frame(self, reference: str) -> RigSolution:
        """The same answer with every pose in sensor ``reference``'s frame."""
        T, C = to_reference(self.T_ref_sensor, self.covariance, reference)
        return RigSolution(
            self.sensors, reference, self.base, T, C, self.T_base_board, self.per_moment, self.dropped,
            self.left_out, self.unsolved, self.scales, self.variance_factor, self.iterations,
            self.range_offset, self.solution, self.selection,
        )  # fmt: skip


def rig_problem(
    moments: Sequence[MomentResult],
    start: RigStart,
    board: Board,
    lidars: Sequence[str],
    cameras: Mapping[str, CameraModel],
    options: RigOptions = RigOptions(),
) -> tuple[Problem, list[tuple[str, str]]]:
    """The rig's ``Problem`` (module docstring) from the stages' answers put in order by ``start``;
    and the moments left out with the reason (not placed, or seen by one sensor only). Camera c is
    extrinsic c (``cameras``' order), LiDAR l is ``lidars[l]`` (0: the base)."""
    base = lidars[0]
    if start.base != base:
        raise ValueError(f"rig_problem: the start's base is {start.base!r}, the rig's first LiDAR {base!r}")
    corners = board.corners_board()
    middle = corners.mean(axis=0)
    centres: list[np.ndarray] = []  # the kept boards' centres, base frame
    cams = list(cameras)
    boards: list[BoardPrior] = []
    views: list[View] = []
    lidar_views: list[LidarBoard] = []
    skipped: list[tuple[str, str]] = []
    for m in moments:
        flips = start.flips.get(m.name)
        if flips is None or m.name not in start.T_base_board:
            if m.sensors:
                skipped.append((m.name, "the board could not be placed"))
            continue
        o = orient_moment(m, flips, board)
        n_obs = len(o.boards) + len([c for c in o.corners if c in cameras])
        if n_obs < 2:
            skipped.append((m.name, f"seen by one sensor only ({', '.join(o.sensors)}): relates nothing"))
            continue
        fit = o.boards.get(base)  # none: the board's place from the start, no LiDAR prior
        T, C = (fit.T_lidar_board, fit.covariance) if fit else (start.T_base_board[m.name], None)
        centre = T[:3, :3] @ middle + T[:3, 3]
        first = next((b.name for b, c in zip(boards, centres, strict=True)
                      if same_pose(b.T_lidar_board, T, c, centre)), None)  # fmt: skip
        if first is not None:  # as a pair's prepare: what is wrong with a placement is shared
            skipped.append((m.name, f"same board pose as {first}: one observation, not an independent one"))
            continue
        i = len(boards)
        centres.append(centre)
        boards.append(BoardPrior(m.name, T, C, base, 0, options.samples_board, fit.returns if fit else None))
        for lid, f in o.boards.items():
            if lid != base:
                lidar_views.append(LidarBoard(i, lidars.index(lid), f.T_lidar_board, f.covariance, lid))
        for cam, c in o.corners.items():
            if cam in cameras:
                k = cams.index(cam)
                views.append(View(i, k, corners, c.bearings, c.cov_px, cameras[cam], cam, c.uv, lens=k))
    if not boards:
        raise CalibrationImpossible(
            "no moment with the board seen by two sensors of the rig"
            + (f" ({'; '.join(f'{n}: {r}' for n, r in skipped[:4])})" if skipped else "")
        )
    placed = start.T_base_sensor
    T_init = {c: np.linalg.inv(placed[n]) for c, n in enumerate(cams) if n in placed}
    T_lidar = {k: placed[n] for k, n in enumerate(lidars) if k and n in placed}
    problem = Problem(
        tuple(boards),
        tuple(views),
        T_init,
        range_offset_sigma_m=options.range_offset_prior_sigma_m if options.range_offset else None,
        lidar_names=(base,),
        evidence={"lidar_boards": LidarBoards(tuple(lidar_views), T_lidar)},
    )
    return problem, skipped


def _found(sol: Solution, lidars: Sequence[str], cams: Sequence[str]) -> list[tuple[str, int]]:
    """(sensor, graph key) of the sensors but the base that the kept boards relate: the other LiDARs'
    ``Y(l)``, then the cameras' ``X(c)``."""
    seen_cams = set(sol.assembly.extrinsics(sol.boards))
    views = sol.problem.evidence["lidar_boards"].views
    seen_lidars = {lv.lidar for lv in views if lv.board in sol.boards}
    found = [(n, Y(k)) for k, n in enumerate(lidars) if k in seen_lidars]
    return found + [(n, X(c)) for c, n in enumerate(cams) if c in seen_cams]


def _graph_joint(sol: Solution, keys: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """(n, 4, 4) the poses of the graph's ``keys`` and their (6n, 6n) joint covariance (the final
    factor's, plus the variance components' spread)."""
    dims = [POSE3_DOF] * len(keys)
    T = np.array([np.asarray(sol.values.atPose3(k).matrix(), dtype=np.float64) for k in keys])
    return T.reshape(-1, 4, 4), sol.marginals.joint(keys, dims) + sol.spread_of(keys, dims)


def _averaged(
    sols: Mapping[str, Solution], selection: Selection, found: list[tuple[str, int]], lidars: Sequence[str],
    cams: Sequence[str],
) -> np.ndarray:  # fmt: skip
    """The graph poses' joint covariance: the chosen model's, or the mixture over the candidates that
    relate the same sensors (``selection.mixture``)."""
    keys = [key for _, key in found]
    if selection.forced:
        return _graph_joint(sols[selection.chosen], keys)[1]
    same = {n: s for n, s in sols.items() if _found(s, lidars, cams) == found}
    return mixture({n: _graph_joint(s, keys) for n, s in same.items()}, selection)


def solve_rig(
    moments: Sequence[MomentResult],
    start: RigStart,
    board: Board,
    lidars: Sequence[str],
    cameras: Mapping[str, CameraModel],
    reference: str | None = None,
    options: RigOptions = RigOptions(),
    order: Sequence[str] | None = None,
) -> RigSolution:
    """Every sensor's pose in ``reference``'s frame (default the base, ``lidars[0]``) with the joint
    covariance, from the stages' answers (``moments``) and the start (``init.rig_start``, or
    ``init.rig_start.place_boards`` with known poses); the base LiDAR's sensor model chosen among
    ``options.models`` (module docstring).

    order: the sensors' order in the answer (default LiDARs then cameras). Raises
    CalibrationImpossible (no moment relates two sensors), IndeterminateSystem (the boards do not
    determine a pose), ValueError (malformed input, an unknown model).
    """
    problem, skipped = rig_problem(moments, start, board, lidars, cameras, options)
    got = solve_sources([problem], options.candidates(), options.noise, options.intrinsics,
                        options.intrinsics_choice)  # fmt: skip
    sols, selection, sol = got.sols[0], got.selection, got.chosen[0]
    cams = list(cameras)
    found = _found(sol, lidars, cams)
    solved, keys = [lidars[0], *(n for n, _ in found)], [key for _, key in found]
    unsolved = {
        n: start.unplaced.get(n) or "no kept moment relates it to the others"
        for n in [*lidars, *cams]
        if n not in solved
    }
    if got.refined:  # the intrinsics refined: its covariance, times the model's held-out factor
        J = selection.factor * _graph_joint(sol, keys)[1]
    else:
        J = _averaged(sols, selection, found, lidars, cams)
    # base-frame perturbations d_s of T_base_s: a LiDAR's Y is T_base_lidar (d = eta); a camera's
    # X = T_cam_base, T_base_cam = X^-1 (d = -Ad(X) xi); the base's own pose is fixed (d = 0)
    M = np.zeros((POSE3_DOF * len(solved), POSE3_DOF * len(keys)))
    T_base: dict[str, np.ndarray] = {lidars[0]: np.eye(4)}
    six = POSE3_DOF
    for k, (n, key) in enumerate(zip(solved[1:], keys, strict=True)):
        rows, cols = slice(six * (k + 1), six * (k + 2)), slice(six * k, six * (k + 1))
        T = np.asarray(sol.values.atPose3(key).matrix(), dtype=np.float64)
        if n in cameras:
            T_base[n], M[rows, cols] = np.linalg.inv(T), -adjoint(T)
        else:
            T_base[n], M[rows, cols] = T, np.eye(POSE3_DOF)
    reference = reference or lidars[0]
    if reference not in solved:
        raise CalibrationImpossible(
            f"the reference sensor {reference!r} has no pose: {unsolved.get(reference)}"
        )
    rank = {n: i for i, n in enumerate(order or [*lidars, *cams])}
    perm = sorted(range(len(solved)), key=lambda k: rank.get(solved[k], len(rank) + k))
    idx = np.concatenate([np.arange(POSE3_DOF * k, POSE3_DOF * (k + 1)) for k in perm])
    C_base = (M @ J @ M.T)[np.ix_(idx, idx)]
    names = tuple(solved[k] for k in perm)
    T_ref, C = to_reference({n: T_base[n] for n in names}, C_base, reference)
    kept = [problem.boards[i].name for i in sol.boards]
    return RigSolution(
        sensors=names,
        reference=reference,
        base=lidars[0],
        T_ref_sensor=T_ref,
        covariance=C,
        T_base_board={n: sol.board_pose(i) for n, i in zip(kept, sol.boards, strict=True)},
        per_moment={n: sol.stats[i] for n, i in zip(kept, sol.boards, strict=True)},
        dropped=[*skipped, *sol.dropped],
        left_out=list(start.dropped),
        unsolved=unsolved,
        scales=dict(sol.scales),
        variance_factor=sol.variance_factor,
        iterations=sol.iterations,
        range_offset=sol.offset(0) if sol.problem.range_offset_sigma_m is not None else None,
        solution=sol,
        selection=selection,
    )
