"""Has the mount moved? Chi-square tests of independent estimates of one extrinsic (docs/joint.md).

``compare_estimates``: the difference of two independent estimates and its covariance;
``consistency_test``: one chi-square test of it; ``session_tests``: each session alone against the
others jointly, and the global test of the alone estimates against one mount.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ilcc_graph.estimation.keys import POSE3_DOF
from ilcc_graph.types import Estimate

from . import chi2 as chi2_dist

__all__ = ["ConsistencyTest", "compare_estimates", "consistency_test", "session_tests"]


@dataclass(frozen=True)
class ConsistencyTest:
    """Is ``session``'s extrinsic the same as the reference's?

    label: what was compared (``"B vs others"``, ``"A -> B"``, ``"all sessions"``).
    session: the session under test (None for the global test).
    delta: (6,) ``Logmap(T_ref^-1 T_session)``, rotation first (rad, m); zeros for the global test.
    rotation_deg, translation_mm: size of ``delta``.
    mahalanobis: ``delta^T C^-1 delta`` (C the covariance of the difference), or the global sum.
    dof: degrees of freedom of its chi-square law when nothing moved. p_value: chance of a value at
    least this large when nothing moved. moved: ``p_value < alpha``.
    kind: ``"global"``, ``"session"`` (one session against the others) or ``"pair"`` (consecutive).
    """

    label: str
    session: str | None
    delta: np.ndarray
    rotation_deg: float
    translation_mm: float
    mahalanobis: float
    dof: int
    p_value: float
    moved: bool
    kind: str = "pair"


def compare_estimates(ref: Estimate, other: Estimate) -> tuple[np.ndarray, np.ndarray]:
    """``delta = Logmap(T_ref^-1 T_other)`` (6,) and its covariance (6, 6) for independent estimates.

    With ``T_ref * Expmap(a)`` and ``T_other * Expmap(c)`` the difference is
    ``D * Expmap(c - Ad(D^-1) a)`` (first order), ``D = T_ref^-1 T_other``, so
    ``C = Ad(D^-1) P_ref Ad(D^-1)^T + P_other``.
    """
    import gtsam

    D = ref.pose.between(other.pose)
    delta = np.asarray(gtsam.Pose3.Logmap(D), dtype=np.float64)
    Ad = D.inverse().AdjointMap()
    C = Ad @ ref.covariance @ Ad.T + other.covariance
    return delta, 0.5 * (C + C.T)


def consistency_test(
    label: str, session: str | None, delta: np.ndarray, m: float, dof: int, alpha: float, kind: str
) -> ConsistencyTest:
    """The test of a difference ``delta`` whose Mahalanobis distance is ``m`` (chi-square, ``dof``)."""
    p = float(chi2_dist.sf(m, dof))
    return ConsistencyTest(
        label=label,
        session=session,
        delta=delta,
        rotation_deg=float(np.degrees(np.linalg.norm(delta[:3]))),
        translation_mm=float(1e3 * np.linalg.norm(delta[3:])),
        mahalanobis=float(m),
        dof=dof,
        p_value=p,
        moved=p < alpha,
        kind=kind,
    )


def session_tests(
    names: list[str],
    others: Callable[[str], Estimate],
    T_rigid: Estimate,
    alone: dict[str, Estimate],
    Q: np.ndarray,
    alpha: float,
) -> tuple[list[ConsistencyTest], ConsistencyTest | None]:
    """Each session alone against all others jointly (``others(name)``: their joint estimate), and the
    global test of the alone estimates against one mount (none with one session); ``Q``: the
    session-to-session scatter added to each session's covariance."""
    S = len(names)
    tests: list[ConsistencyTest] = []
    if S < 2:
        return tests, None
    for n in names:
        delta, C = compare_estimates(others(n), alone[n])
        C = C + Q * (1.0 + 1.0 / (S - 1))  # the joint of S-1 others carries about Q / (S-1) of it
        m = float(delta @ np.linalg.solve(C, delta))
        tests.append(consistency_test(f"{n} vs others", n, delta, m, POSE3_DOF, alpha, "session"))
    total = 0.0
    for n in names:
        d = T_rigid.pose.localCoordinates(alone[n].pose)
        total += float(d @ np.linalg.solve(alone[n].covariance + Q, d))
    dof = POSE3_DOF * (S - 1)
    return tests, consistency_test("all sessions", None, np.zeros(POSE3_DOF), total, dof, alpha, "global")
