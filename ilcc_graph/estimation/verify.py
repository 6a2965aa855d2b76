"""Verify a stored rig calibration against a short new capture (issue 24): has a sensor moved?

Method: the new capture is solved **alone** (a rig: ``rig_solve.solve_rig``, the stored poses serving
only as the start that orders its corners, ``init.rig_start.place_boards``; a pair of one camera and
one LiDAR: by the caller as ``calibrate`` solves a pair, then ``verify_pair``) and compared with the
stored poses. For each sensor s other than the reference, with ``T0`` stored and ``T1`` new (both
``T_ref_s``), the change is ``d = Log(T0^-1 T1)`` (rotation first, rad and m, about and along the
sensor's own axes) and, the two estimates being independent (different boards), its covariance is
``C = Ad(D^-1) P0 Ad(D^-1)^T + P1`` (``sessions.compare_estimates``; P0 the stored covariance, P1
the capture's). Why alone and not the capture with the stored poses as a prior: with a prior, a
moved sensor's new boards pull the shared boards, and through them every other sensor, towards the
prior, which smears one sensor's change over the others; alone, the capture is self-consistent (the
rig is rigid while it is taken), so each sensor's change stays its own. In the linear-Gaussian case
both give the same test statistic for a sensor the capture determines; a sensor the capture does not
determine is said to be unchecked rather than passed on the strength of the prior.

Tests: per sensor ``m = d^T C^-1 d`` against chi-square with 6 dof (p-value), per axis
``z = d_k / sqrt(C_kk)`` (chi-square with 1 dof); a global test over every sensor's change with their
joint covariance (6 (N - 1) dof).

Smallest detectable change: the sensor test at level ``alpha / n`` detects a change ``D`` with
probability ``power`` when its noncentrality ``D^T C^-1 D`` reaches ``lambda*`` (noncentral
chi-square, 6 dof). Along axis k alone that is ``sqrt(lambda* / (C^-1)_kk)``; for a rotation (or a
translation) about (along) the worst axis, ``sqrt(lambda* / min eig((C^-1)_block))``.

Verdict per sensor (``VerifyOptions``; rule also in ``RULE``):

- **fail**: its test rejects at ``alpha / n`` (Bonferroni over the n sensors checked, so an
  unchanged rig fails with probability at most ``alpha``); also a sensor whose every observation
  disagrees with where the stored poses put the board (a gross change);
- **warn**: not failed, but the capture could not have detected a change of ``tolerance_deg`` (any
  axis) or ``tolerance_mm`` (any direction) with probability ``power``, or the capture does not
  relate the sensor to the others (unchecked);
- **pass**: otherwise.

The rig's verdict is its worst sensor's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import gtsam
import numpy as np
from scipy.special import chndtrinc

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import ORDER_INCONSISTENT, CalibrationImpossible
from ilcc_graph.estimation import chi2
from ilcc_graph.estimation.keys import POSE3_DOF
from ilcc_graph.estimation.rig_solve import RigOptions, RigSolution, solve_rig, to_reference
from ilcc_graph.estimation.sessions import compare_estimates
from ilcc_graph.init.rig_start import RigStart, StartOptions, adjoint, place_boards
from ilcc_graph.types import SIGMA_NAMES, Estimate, MomentResult, PoseTerms

__all__ = [
    "RULE",
    "VERDICTS",
    "AxisCheck",
    "SensorCheck",
    "StoredRig",
    "VerifyOptions",
    "VerifyResult",
    "detectable_change",
    "net_of_terms",
    "verify_pair",
    "verify_rig",
]

VERDICTS = ("pass", "warn", "fail")
RULE = (
    "fail: the sensor's 6-dof change test rejects at alpha / n (n sensors checked; an unchanged rig "
    "fails with probability <= alpha), or every board it saw disagrees with the stored poses; warn: "
    "not failed, but this capture could not have detected a change of the tolerance (rotation about "
    "any axis, translation in any direction) with the stated power, or it does not relate the sensor "
    "to the others; pass: otherwise. The rig's verdict is its worst sensor's."
)
_SCALE = np.array([math.degrees(1.0)] * 3 + [1e3] * 3)  # rad, m -> deg, mm


@dataclass(frozen=True)
class StoredRig:
    """A stored calibration: every sensor's ``T_ref_sensor`` (4, 4) in ``reference``'s frame and their
    (6N, 6N) joint covariance in ``sensors`` order (right tangent, rotation first; the reference's
    block zero)."""

    sensors: tuple[str, ...]
    reference: str
    T_ref_sensor: Mapping[str, np.ndarray]
    covariance: np.ndarray

    @classmethod
    def from_solution(cls, sol: RigSolution) -> StoredRig:
        return cls(sol.sensors, sol.reference, dict(sol.T_ref_sensor), sol.covariance)

    @classmethod
    def pair(
        cls, T_cam_lidar: np.ndarray, covariance: np.ndarray, camera: str = "camera", lidar: str = "lidar"
    ) -> StoredRig:
        """A single-pair calibration (``calibration.yaml``'s ``T_cam_lidar`` and covariance) as a rig
        of two sensors with the LiDAR as the reference: ``T_lidar_cam = T_cam_lidar^-1``, whose
        right-tangent perturbation is ``-Ad(T_cam_lidar) xi``."""
        T = np.asarray(T_cam_lidar, dtype=np.float64)
        A = adjoint(T)
        C = np.zeros((12, 12))
        C[6:, 6:] = A @ np.asarray(covariance, dtype=np.float64) @ A.T
        return cls((lidar, camera), lidar, {lidar: np.eye(4), camera: np.linalg.inv(T)}, C)

    def pose(self, s: str) -> Estimate:
        k = self.sensors.index(s)
        sl = slice(POSE3_DOF * k, POSE3_DOF * (k + 1))
        return Estimate(np.asarray(self.T_ref_sensor[s], dtype=np.float64), self.covariance[sl, sl])

    def in_frame(self, base: str) -> dict[str, np.ndarray]:
        """Every sensor's pose in sensor ``base``'s frame."""
        return to_reference(dict(self.T_ref_sensor), self.covariance, base)[0]


@dataclass(frozen=True)
class VerifyOptions:
    """alpha: the rig's false-alarm probability for ``fail`` (split over the sensors checked).
    power: the detection probability at which the smallest detectable change is stated.
    tolerance_deg, tolerance_mm: the change the capture must be able to detect for ``pass``.
    rig: how the capture is solved (its noise policy)."""

    alpha: float = 0.05
    power: float = 0.95
    tolerance_deg: float = 0.25
    tolerance_mm: float = 10.0
    rig: RigOptions = RigOptions()

    def __post_init__(self) -> None:
        if not (0 < self.alpha < 1 and 0 < self.power < 1):
            raise ValueError(f"VerifyOptions: alpha and power in (0, 1), got {self.alpha}, {self.power}")
        if not (self.tolerance_deg > 0 and self.tolerance_mm > 0):
            raise ValueError("VerifyOptions: tolerance_deg and tolerance_mm must be > 0")


@dataclass(frozen=True)
class AxisCheck:
    """One axis of a sensor's change: ``name`` (``rx_deg`` .. ``tz_mm``), ``change`` and ``sigma`` in
    deg or mm, ``z`` = change / sigma, ``p_value`` of the 1-dof test, ``detectable``: the smallest
    change along this axis alone the sensor's test detects with the stated power (deg or mm).
    verdict: ``fail`` when the axis's own test rejects at the sensor's level / 6, ``warn`` when not
    but its detectable change exceeds the tolerance, else ``pass``."""

    name: str
    change: float
    sigma: float
    z: float
    p_value: float
    detectable: float
    verdict: str = "pass"


@dataclass(frozen=True)
class SensorCheck:
    """One sensor's verdict (module docstring).

    delta: (6,) the change ``Log(T_stored^-1 T_new)`` (rad, m; the sensor's own axes), covariance:
    (6, 6) its covariance. chi2, p_value: its 6-dof test. detectable_deg, detectable_mm: the
    smallest rotation about the worst axis and translation in the worst direction the test detects
    with the stated power. boards: the capture's kept boards the sensor saw. NaN where unchecked.
    """

    sensor: str
    verdict: str
    reason: str
    delta: np.ndarray
    covariance: np.ndarray
    chi2: float
    p_value: float
    axes: tuple[AxisCheck, ...]
    detectable_deg: float
    detectable_mm: float
    boards: int

    @property
    def rotation_deg(self) -> float:
        return float(math.degrees(np.linalg.norm(self.delta[:3])))

    @property
    def translation_mm(self) -> float:
        return float(1e3 * np.linalg.norm(self.delta[3:]))


@dataclass(frozen=True)
class VerifyResult:
    """The rig's verdict, each sensor's check (every sensor but the reference), the level each sensor
    was tested at, the global test (chi2, dof, p-value) over the sensors checked, the capture's own
    solution (None when it could not be solved) and the rule applied."""

    verdict: str
    reference: str
    sensors: dict[str, SensorCheck]
    alpha_sensor: float
    global_test: tuple[float, int, float] | None
    solution: RigSolution | None
    rule: str = RULE
    notes: list[str] = field(default_factory=list)


def detectable_change(
    C: np.ndarray, alpha: float, power: float, dof: int = POSE3_DOF
) -> tuple[np.ndarray, float, float]:
    """(per axis (6,), worst rotation, worst translation): the smallest change (rad, m) the test
    ``d^T C^-1 d > chi2_{1-alpha}(dof)`` detects with probability ``power`` (module docstring)."""
    q = chi2.ppf(1.0 - alpha, dof)
    lam = float(chndtrinc(q, dof, 1.0 - power))
    W = np.linalg.inv(C)
    axes = np.sqrt(lam / np.diag(W))
    rot = math.sqrt(lam / np.linalg.eigvalsh(W[:3, :3]).min())
    trans = math.sqrt(lam / np.linalg.eigvalsh(W[3:, 3:]).min())
    return axes, rot, trans


def _unchecked(s: str, verdict: str, reason: str, boards: int = 0) -> SensorCheck:
    nan6 = np.full(POSE3_DOF, np.nan)
    return SensorCheck(
        s, verdict, reason, nan6, np.full((6, 6), np.nan), np.nan, np.nan, (), np.nan, np.nan, boards
    )


def _check(
    s: str, d: np.ndarray, C: np.ndarray, alpha: float, opts: VerifyOptions, boards: int
) -> SensorCheck:
    """Sensor ``s``'s verdict on its change ``d`` (6,) with covariance ``C`` (module docstring)."""
    m = float(d @ np.linalg.solve(C, d))
    p = chi2.sf(m, POSE3_DOF)
    det, rot, trans = detectable_change(C, alpha, opts.power)
    sig = np.sqrt(np.diag(C))
    tol = [opts.tolerance_deg] * 3 + [opts.tolerance_mm] * 3
    axes = []
    for k, n in enumerate(SIGMA_NAMES):
        pk, dk = chi2.sf(float((d[k] / sig[k]) ** 2), 1), float(_SCALE[k] * det[k])
        word = "fail" if pk < alpha / POSE3_DOF else ("warn" if dk > tol[k] else "pass")
        axes.append(
            AxisCheck(
                n, float(_SCALE[k] * d[k]), float(_SCALE[k] * sig[k]), float(d[k] / sig[k]), pk, dk, word
            )
        )
    rot_deg, trans_mm = math.degrees(rot), 1e3 * trans
    size = f"{math.degrees(np.linalg.norm(d[:3])):.3f} deg, {1e3 * np.linalg.norm(d[3:]):.1f} mm"
    can = f"{rot_deg:.3f} deg / {trans_mm:.1f} mm"
    if p < alpha:
        verdict, reason = "fail", f"changed: {size} (chi2 {m:.1f} on 6 dof, p = {p:.2g} < {alpha:.2g})"
    elif rot_deg > opts.tolerance_deg or trans_mm > opts.tolerance_mm:
        verdict = "warn"
        reason = (f"no change found ({size}, p = {p:.2g}), but this capture detects only {can} "
                  f"(tolerance {opts.tolerance_deg:g} deg / {opts.tolerance_mm:g} mm)")  # fmt: skip
    else:
        verdict, reason = "pass", f"no change found ({size}, p = {p:.2g}); detectable: {can}"
    return SensorCheck(s, verdict, reason, d, C, m, p, tuple(axes), rot_deg, trans_mm, boards)


def verify_rig(
    stored: StoredRig,
    moments: Sequence[MomentResult],
    board: Board,
    lidars: Sequence[str],
    cameras: Mapping[str, CameraModel],
    options: VerifyOptions = VerifyOptions(),
    terms: Mapping[str, PoseTerms] | None = None,
) -> VerifyResult:
    """Check every sensor of a stored calibration against a new capture's stages' answers
    (``moments``), module docstring. ``lidars`` (the first is the graph's base) and ``cameras`` are
    the rig's; sensors missing from ``stored`` are a ValueError. ``terms``: {camera: its stored pose
    in the base LiDAR's frame with that LiDAR's range terms}: where the capture's solve has the terms
    too, that camera's change is tested net of them (``net_of_terms``, as ``verify_pair`` does; the
    global test stays on the poses alone)."""
    missing = [s for s in (*lidars, *cameras) if s not in stored.sensors]
    if missing:
        raise ValueError(
            f"verify: sensors {missing} are not in the stored calibration {list(stored.sensors)}"
        )
    base = lidars[0]
    T_base = stored.in_frame(base)
    T_board, flips, dropped = place_boards(moments, T_base, board, base, StartOptions())
    start = RigStart(base, T_base, T_board, flips, dropped)
    others = [s for s in stored.sensors if s != stored.reference]
    notes: list[str] = []
    try:
        sol = solve_rig(moments, start, board, lidars, cameras, stored.reference, options.rig, stored.sensors)
    except CalibrationImpossible as err:
        sol = None
        notes.append(f"the capture could not be solved: {err}")
    solved = [s for s in others if sol is not None and s in sol.sensors]
    new_terms = {}  # the capture's cameras with the LiDAR's terms, where the stored ones have them
    if terms and sol is not None and sol.base == stored.reference:
        new_terms = sol.camera_terms(list(cameras))
    n = max(1, len(solved))
    alpha = options.alpha / n
    checks: dict[str, SensorCheck] = {}
    netted: dict[str, list[str]] = {}  # each note of the terms (one test of one LiDAR's) and its cameras
    for s in others:
        seen = [m.name for m in moments if s in m.sensors]
        kept = (
            []
            if sol is None
            else [m for m in seen if m in sol.T_base_board and flips.get(m, {}).get(s) is not None]
        )
        off = [r for _, x, r in dropped if x == s and r.startswith(ORDER_INCONSISTENT)]
        if seen and len(off) == len(seen):  # every board it saw is far from where the others put it
            checks[s] = _unchecked(s, "fail", f"every board it saw disagrees with the stored poses: {off[0]}")
        elif s not in solved:
            why = "not seen by the capture" if not seen else (sol.unsolved.get(s) if sol else notes[0])
            checks[s] = _unchecked(s, "warn", f"unchecked: {why}", len(kept))
        else:
            assert sol is not None
            d, C = compare_estimates(stored.pose(s), sol.pose(s))
            if terms and s in terms:
                new = new_terms[s].inverse() if s in new_terms else None
                d, C, note = _net(d, C, terms[s], new, alpha)
                if note:
                    netted.setdefault(note, []).append(s)
            checks[s] = _check(s, d, C, alpha, options, len(kept))
    notes += [f"{', '.join(cams)}: {note}" for note, cams in netted.items()]
    glob = None
    if sol is not None and solved:
        glob = _global_test(stored, sol, solved)
    worst = max((VERDICTS.index(c.verdict) for c in checks.values()), default=1)
    return VerifyResult(VERDICTS[worst], stored.reference, checks, alpha, glob, sol, RULE, notes)


def _net(
    d: np.ndarray, C: np.ndarray, stored: PoseTerms, new: PoseTerms | None, alpha: float
) -> tuple[np.ndarray, np.ndarray, str | None]:
    """A change ``(d, C)`` net of the LiDAR's range terms both solves have, with ``net_of_terms``'s
    note; as given (the note saying why, or None when they share none) when the terms changed."""
    net = None if new is None else net_of_terms(stored, new, alpha)
    if net is None:
        return d, C, None
    if net[0] is None or net[1] is None:
        return d, C, net[2]
    return net[0], net[1], net[2]


def verify_pair(
    stored: StoredRig,
    sensor: str,
    new: Estimate | None,
    boards: int,
    options: VerifyOptions = VerifyOptions(),
    notes: Sequence[str] = (),
    terms: tuple[PoseTerms | None, PoseTerms | None] = (None, None),
) -> VerifyResult:
    """Check a stored pair's non-reference ``sensor`` against the capture's own calibration of it
    (``new``: its pose in the reference's frame with covariance, solved as ``calibrate`` solves a
    pair; None when the capture could not be solved, ``notes`` saying why). ``boards``: the boards
    the capture's solve used. ``terms``: the sensor's pose with the LiDAR's range terms, stored and
    new, when each solve had such terms: the change is then tested net of them (``net_of_terms``).
    The verdicts and the rule as ``verify_rig``'s (module docstring)."""
    if sensor not in stored.sensors or sensor == stored.reference:
        raise ValueError(f"verify: {sensor!r} is not a checked sensor of {list(stored.sensors)}")
    if new is None:
        why = notes[0] if notes else "the capture could not be solved"
        check = _unchecked(sensor, "warn", f"unchecked: {why}", boards)
        return VerifyResult(
            "warn", stored.reference, {sensor: check}, options.alpha, None, None, RULE, list(notes)
        )
    d, C = compare_estimates(stored.pose(sensor), new)
    notes = list(notes)
    if terms[0] is not None:
        d, C, note = _net(d, C, terms[0], terms[1], options.alpha)
        if note:
            notes.append(note)
    check = _check(sensor, d, C, options.alpha, options, boards)
    glob = (check.chi2, POSE3_DOF, check.p_value)
    sensors = {sensor: check}
    return VerifyResult(check.verdict, stored.reference, sensors, options.alpha, glob, None, RULE, notes)


def net_of_terms(
    stored: PoseTerms, new: PoseTerms, alpha: float
) -> tuple[np.ndarray | None, np.ndarray | None, str] | None:
    """A pose's change net of the LiDAR's own range terms estimated with it: (d, C, note), or None
    when the two solves share no term.

    With ``D = T0^-1 T1`` and the terms both solves have, the joint difference ``(d, db)``, ``d =
    Log(D)`` (rad, m) and ``db = b1 - b0``, has covariance ``S = A S0 A^T + S1`` (``A`` is
    ``Ad(D^-1)`` on the pose, the identity on the terms; the two solves independent). The LiDAR's
    terms are the sensor's own and do not move with its mount, so under "the terms unchanged" the
    mount's change is ``d - S_db S_bb^-1 db`` with covariance ``S_dd - S_db S_bb^-1 S_bd``: a range
    offset both solves leave loosely known (the translation along the rays) drops out of the test.
    When ``db`` itself rejects "unchanged" (chi-square at ``alpha``), the terms are not taken as
    shared: (None, None, the note saying so), and the poses are compared alone."""
    common = [t for t in stored.terms if t in new.terms]
    if not common:
        return None
    i0 = np.r_[np.arange(POSE3_DOF), [POSE3_DOF + stored.terms.index(t) for t in common]]
    i1 = np.r_[np.arange(POSE3_DOF), [POSE3_DOF + new.terms.index(t) for t in common]]
    D = np.linalg.solve(stored.T, new.T)
    A = np.eye(len(i0))
    A[:POSE3_DOF, :POSE3_DOF] = adjoint(np.linalg.inv(D))
    S = A @ stored.covariance[np.ix_(i0, i0)] @ A.T + new.covariance[np.ix_(i1, i1)]
    S = 0.5 * (S + S.T)
    d = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(D)), dtype=np.float64)
    db = np.array([new.values[new.terms.index(t)] - stored.values[stored.terms.index(t)] for t in common])
    Sdd, Sdb, Sbb = S[:POSE3_DOF, :POSE3_DOF], S[:POSE3_DOF, POSE3_DOF:], S[POSE3_DOF:, POSE3_DOF:]
    m = float(db @ np.linalg.solve(Sbb, db))
    p = chi2.sf(m, len(common))
    units = [stored.units[stored.terms.index(t)] for t in common]
    sig = np.sqrt(np.diag(Sbb))
    shown = ", ".join(_term_change(*x) for x in zip(common, units, db, sig, strict=True))
    if p < alpha:
        return None, None, (
            f"the LiDAR's own range terms changed ({shown}; chi2 {m:.1f} on {len(common)} dof, p = {p:.2g}): "
            "the mount is tested without them"
        )
    K = np.linalg.solve(Sbb, Sdb.T).T
    C = Sdd - K @ Sdb.T
    return d - K @ db, 0.5 * (C + C.T), (
        f"the mount's change is tested net of the LiDAR's own range terms, estimated in both solves and "
        f"unchanged ({shown}; chi2 {m:.1f} on {len(common)} dof, p = {p:.2g})"
    )


def _term_change(term: str, unit: str, value: float, sigma: float) -> str:
    """``offset -0.4 +- 8.3 mm``: a term's change in the unit it is shown in."""
    if unit == "m":
        return f"{term} {1e3 * value:+.1f} +- {1e3 * sigma:.1f} mm"
    return f"{term} {value:+.2g} +- {sigma:.1g}"


def _global_test(stored: StoredRig, sol: RigSolution, sensors: Sequence[str]) -> tuple[float, int, float]:
    """Every checked sensor's change at once, with the joint covariances (6 n dof)."""
    P0 = stored.covariance
    idx0 = np.concatenate(
        [np.arange(6 * stored.sensors.index(s), 6 * stored.sensors.index(s) + 6) for s in sensors]
    )
    P0 = P0[np.ix_(idx0, idx0)]
    P1 = sol.joint(sensors)
    A = np.zeros_like(P0)
    d = []
    for k, s in enumerate(sensors):
        D = np.linalg.solve(stored.T_ref_sensor[s], sol.T_ref_sensor[s])
        A[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] = adjoint(np.linalg.inv(D))
        d.append(compare_estimates(stored.pose(s), sol.pose(s))[0])
    C = A @ P0 @ A.T + P1
    v = np.concatenate(d)
    m = float(v @ np.linalg.solve(C, v))
    dof = POSE3_DOF * len(sensors)
    return m, dof, chi2.sf(m, dof)
