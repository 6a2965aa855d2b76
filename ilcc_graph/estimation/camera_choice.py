"""Whether the boards support refining the camera's intrinsics (the camera half of ``selection``).

With the LiDAR model chosen, the intrinsics are refined (``--refine-intrinsics``' graph: the views
as pixel factors on ``I(c)`` with the stated values as a prior) and judged twice:

- **significance**: are the refined intrinsics off the stated values by more than their own
  uncertainty, ``d^T C_post^-1 d`` against the chi-square quantile (``d`` the offset, ``C_post``
  their covariance)? Then the boards know them better than the stated values are: refining gains
  accuracy. (Not the offset against the stated ``intrinsics_sigma``: values off within their stated
  sigma are honest as stated, their sigma propagated, but refining still gains where the boards
  determine them: simulated VLP-16 + pinhole, typical error, 8.3 -> 1.5 mm.)
- **reproducibility**: do two disjoint halves of the boards (odd and even positions) refine the
  same intrinsics within their covariances (``d_h^T (C_a + C_b)^-1 d_h``, chi-square)?

Refined only when both pass at ``ALPHA`` (1 %): a real error of the stated intrinsics that the
boards determine. The halves are solved only when the first test passes (otherwise the stated
intrinsics stay whatever they say: two solves saved; ``reproducibility`` is then NaN). With fewer
boards than twice the intrinsics (each half must hold as many boards
as there are intrinsics, else two halves agree only because each knows little: the recorded
fisheye's halves of 10 boards refined from quarters of 5 passed, and the two halves then disagreed
at chi-square 106), a panorama (nothing to refine) or when a refined solve fails, the stated
intrinsics stay. On the recorded fisheye sets the halves' refined
intrinsics differ far beyond their covariances (acfr-vlp16-fisheye: chi-square 91 on 8 dof; one
board per frame does not separate the focal length from the lens polynomial), so they stay as
stated there; a stated ``camera.intrinsics_sigma`` then enters the covariance as before
(``linear.consider_covariance``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.estimation import chi2 as chi2_dist
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions, refinable
from ilcc_graph.estimation.keys import I
from ilcc_graph.estimation.noise import NoiseOptions, Solution, solve_problem
from ilcc_graph.estimation.problem import Problem

log = logging.getLogger(__name__)

__all__ = ["ALPHA", "MIN_BOARDS", "CameraChoice", "choose_intrinsics"]

#: significance level of both tests
ALPHA = 0.01
#: fewer boards than this, or than twice the intrinsics: the halves cannot tell, the stated ones stay
MIN_BOARDS = 8


@dataclass(frozen=True)
class CameraChoice:
    """refined: the intrinsics were refined. significance / reproducibility: the two chi-squares
    (nan when not computed) with their dof; reason: one line."""

    refined: bool
    significance: float = math.nan
    significance_dof: int = 0
    reproducibility: float = math.nan
    reproducibility_dof: int = 0
    reason: str = ""

    def summary(self) -> str:
        return f"camera intrinsics {'refined' if self.refined else 'as stated'}: {self.reason}"

    def to_dict(self) -> dict:
        def num(x: float) -> float | None:
            return None if not math.isfinite(x) else float(x)

        return {
            "refined": self.refined,
            "significance_chi2": num(self.significance),
            "significance_dof": int(self.significance_dof),
            "reproducibility_chi2": num(self.reproducibility),
            "reproducibility_dof": int(self.reproducibility_dof),
            "reason": self.reason,
        }

    @classmethod
    def from_dict(cls, d: dict) -> CameraChoice:
        def num(x: object) -> float:
            return math.nan if x is None else float(x)  # type: ignore[arg-type]

        return cls(
            bool(d["refined"]), num(d.get("significance_chi2")), int(d.get("significance_dof", 0)),
            num(d.get("reproducibility_chi2")), int(d.get("reproducibility_dof", 0)),
            str(d.get("reason", "")),
        )  # fmt: skip


def _refined(
    problem: Problem,
    options: NoiseOptions,
    solve: Callable[..., Solution],
    boards: Sequence[str] | None = None,
) -> tuple[Solution, np.ndarray, np.ndarray]:
    """(solution, intrinsics (n,), their covariance) of ``problem`` with camera 0's intrinsics refined."""
    sol = solve(problem, options, boards=boards)
    got = sol.intrinsics(0)
    if got is None:
        raise IndeterminateSystem("no view enters with refined intrinsics")
    v = got[1]
    C = sol.marginals.covariance(I(0), "the intrinsics of camera 0") + sol.spread_of([I(0)], [len(v)])
    return sol, v, C


def choose_intrinsics(
    problem: Problem, options: NoiseOptions = NoiseOptions(), solve: Callable[..., Solution] = solve_problem
) -> tuple[Solution | None, CameraChoice | None]:
    """Refine camera 0's intrinsics in ``problem`` (its LiDAR model chosen, intrinsics as stated) and
    judge it (module docstring): (the refined solution when chosen, else None; the choice, or None
    when the camera has nothing to refine)."""
    cams = {v.camera for v in problem.views}
    if len(cams) != 1:
        return None, None
    cam = next(iter(cams))
    if not refinable(cam):
        return None, None
    n, need = len(problem.boards), max(MIN_BOARDS, 2 * len(cam.intrinsic_names))
    if n < need:
        why = f"{n} boards: too few to tell (halves of {need // 2} or more)"
        return None, CameraChoice(False, reason=why)
    opts = problem.intrinsics or IntrinsicsOptions()
    ref = replace(problem, intrinsics=replace(opts, refine=True))
    names = [b.name for b in problem.boards]
    failed = (CalibrationImpossible, IndeterminateSystem, np.linalg.LinAlgError)
    try:
        sol, v, C = _refined(ref, options, solve)
    except failed as err:
        return None, CameraChoice(False, reason=f"a refined solve failed ({err})")
    d = v - cam.intrinsics()
    sig, k = float(d @ np.linalg.solve(C, d)), len(d)
    q_sig = float(chi2_dist.ppf(1 - ALPHA, max(k, 1)))
    if sig <= q_sig:  # stated within their sigma: stated, whatever the halves say (they are not solved)
        why = f"the refined ones are the stated ones within their sigma ({sig:.1f} <= {q_sig:.1f}, {k} dof)"
        return _said(None, CameraChoice(False, sig, k, reason=why))
    try:
        (va, Ca), (vb, Cb) = [_refined(ref, options, solve, names[j::2])[1:] for j in (0, 1)]
    except failed as err:
        return None, CameraChoice(False, sig, k, reason=f"a refined solve of half the boards failed ({err})")
    dh = va - vb
    rep = float(dh @ np.linalg.solve(Ca + Cb, dh))
    q_rep = float(chi2_dist.ppf(1 - ALPHA, len(dh)))
    if rep <= q_rep:
        why = f"the boards move them ({sig:.1f} > {q_sig:.1f}), two halves agree ({rep:.1f} <= {q_rep:.1f})"
        return _said(sol, CameraChoice(True, sig, k, rep, len(dh), why))
    why = (
        f"two halves of the boards refine them differently ({rep:.1f} > {q_rep:.1f}, {len(dh)} dof): the "
        "boards do not determine them"
    )
    return _said(None, CameraChoice(False, sig, k, rep, len(dh), why))


def _said(sol: Solution | None, choice: CameraChoice) -> tuple[Solution | None, CameraChoice]:
    log.info("%s", choice.summary())
    return sol, choice
