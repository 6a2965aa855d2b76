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
at chi-square 106), a panorama (nothing to refine) or when a refined solve fails, they are not
refined all together.

**Several cameras** (a rig's; cameras stated alike are still two lenses, ``View.lens``): each is
judged as a pair's camera, all its intrinsics refined and the others' held as stated, on the boards
it sees (its halves of them; every other board in both); those that pass are refined together.
Subsets are not tried there.

**Subsets** (``IntrinsicsOptions.subsets``; none by default, ``LIDAR_SUBSETS``: fx, fy, k1, then
k1). When all of them are not refined (too few boards, or their halves disagree: one board per
frame does not separate the focal length from the whole lens polynomial) and the config states no
``intrinsics_sigma``, each subset is judged in turn by the same two tests, the others held as stated
(``subset_problem``), and the first that passes is refined; a smaller one is not tried once a larger
one refines the stated values within their sigma. The LiDAR's ranges fix each board's distance,
which a focal length or first radial term stated a little off moves along the camera's rays
(docs/bench_intrinsics.md: simulated VLP-16, a typical published calibration's error and no sigma
stated, 10 boards: translation error 18.6 -> 3.7 mm on a fisheye, 8.1 -> 1.4 mm on a pinhole;
stated right: nothing refined in 64 sets). The principal point is not in them: on
acfr-vlp16-fisheye fx, fy, cx, cy, k1 passed their halves narrowly (13.4 <= 15.1 on 5 dof) and
turned the extrinsic by 0.49 deg, chi-square 250 from each half's own answer; fx, fy, k1 (halves
2.5 <= 11.3) move it 3.8 mm, within the halves' answers (chi-square 3.6 and 8.9). Not the default
yet: a rig's door has no camera choice (the pair and its rig of two would then differ by those
3.8 mm), the test suite took 14:08 with them instead of 10:55, and they leave the rotation's
coverage where it was (docs/bench_intrinsics.md). A stated ``camera.intrinsics_sigma`` is
propagated into the covariance (``linear.consider_covariance``) and no subset is tried.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.estimation import chi2 as chi2_dist
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions, default_sigmas, refinable
from ilcc_graph.estimation.keys import I
from ilcc_graph.estimation.noise import NoiseOptions, Solution, solve_problem
from ilcc_graph.estimation.problem import Problem

log = logging.getLogger(__name__)

__all__ = ["ALPHA", "LIDAR_SUBSETS", "MIN_BOARDS", "CameraChoice", "choose_intrinsics", "subset_problem"]

#: significance level of both tests
ALPHA = 0.01
#: fewer boards than this, or than twice the intrinsics: the halves cannot tell, the stated ones stay
MIN_BOARDS = 8
#: subsets of intrinsics that the boards' ranges can tell (module docstring; ``IntrinsicsOptions.subsets``)
LIDAR_SUBSETS: tuple[tuple[str, ...], ...] = (("fx", "fy", "k1"), ("k1",))
#: the others' prior sigmas then, times their weak defaults: held, and the solve well conditioned (a
#: sigma of 0, ``intrinsics.EXACT_SIGMA``, left 2 of 6 simulated pinhole sets "indeterminate")
HELD = 1e-4


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
    free: Sequence[int] | None = None,
    c: int = 0,
) -> tuple[Solution, np.ndarray, np.ndarray]:
    """(solution, intrinsics, their covariance) of ``problem`` with camera ``c``'s intrinsics refined;
    ``free``: the indices of those not held as stated (all when None), the only ones returned."""
    sol = solve(problem, options, boards=boards)
    got = sol.intrinsics(c)
    if got is None:
        raise IndeterminateSystem("no view enters with refined intrinsics")
    v = got[1]
    C = sol.marginals.covariance(I(c), f"the intrinsics of camera {c}") + sol.spread_of([I(c)], [len(v)])
    k = np.arange(len(v)) if free is None else np.asarray(free)
    return sol, v[k], C[np.ix_(k, k)]


def subset_problem(problem: Problem, names: Sequence[str]) -> Problem | None:
    """``problem`` with camera 0's intrinsics ``names`` alone refinable, every other one held as
    stated (``HELD``), or None when the camera lacks one of them or its config states the
    intrinsics' sigmas (then those are propagated as stated)."""
    cam = problem.views[0].camera
    if not set(names) <= set(cam.intrinsic_names) or cam.intrinsics_sigma is not None:
        return None
    free = np.isin(cam.intrinsic_names, list(names))
    one = replace(cam, intrinsics_sigma=default_sigmas(cam) * np.where(free, 1.0, HELD))
    return replace(problem, views=tuple(replace(v, camera=one) for v in problem.views))


def choose_intrinsics(
    problem: Problem, options: NoiseOptions = NoiseOptions(), solve: Callable[..., Solution] = solve_problem
) -> tuple[Solution | None, CameraChoice | None]:
    """Refine the cameras' intrinsics in ``problem`` (its LiDAR model chosen, intrinsics as stated) and
    judge them (module docstring). One camera: all of them, else each of its options' ``subsets`` in
    turn. Several (a rig's): each camera's all, the others as stated, on the boards it sees; those
    that pass refined together. (the refined solution when chosen, else None; the choice, or None
    when no camera has anything to refine)."""
    lenses = _lenses(problem)
    if len(lenses) > 1:
        sol, each = _each_camera(problem, lenses, options, solve)
        return (sol, each) if each is None else _said(sol, each)
    cam = problem.views[0].camera
    if not refinable(cam):
        return None, None
    opts = replace(problem.intrinsics or IntrinsicsOptions(), refine=True)
    sol, choice = _judge(replace(problem, intrinsics=opts), cam, None, options, solve)
    reasons = [f"all {len(cam.intrinsic_names)}: {choice.reason}"]
    last = choice
    for names in opts.subsets:
        if sol is not None or _stated(last) or (part := subset_problem(problem, names)) is None:
            continue
        free = [cam.intrinsic_names.index(n) for n in names]
        sol, last = _judge(replace(part, intrinsics=opts), cam, free, options, solve)
        reasons.append(f"{', '.join(names)} alone: {last.reason}")
        choice = last if sol is not None else choice
    if len(reasons) > 1:  # subsets were tried: each one's reason after all's
        choice = replace(choice, reason="; ".join(reasons))
    return _said(sol, choice)


def _lenses(problem: Problem) -> list[tuple[CameraModel, str, list[str]]]:
    """Per camera of the graph (``View.lens_key``, in the assembly's order): its model, its views'
    group (a rig's camera name) and the names of the boards it sees."""
    got: dict[object, tuple[CameraModel, str, list[str]]] = {}
    for v in problem.views:
        seen = got.setdefault(v.lens_key(), (v.camera, v.group, []))[2]
        if (name := problem.boards[v.board].name) not in seen:
            seen.append(name)
    return list(got.values())


def _each_camera(
    problem: Problem, lenses: list[tuple[CameraModel, str, list[str]]], options: NoiseOptions,
    solve: Callable[..., Solution],
) -> tuple[Solution | None, CameraChoice | None]:  # fmt: skip
    """Several cameras: each one's intrinsics judged alone (the others as stated), those that pass
    refined together; the choice says each camera's reason."""
    opts = replace(problem.intrinsics or IntrinsicsOptions(), refine=True)
    chosen: dict[int, Solution] = {}
    reasons = []
    for c, (cam, name, seen) in enumerate(lenses):
        if not refinable(cam):
            continue
        one = replace(problem, intrinsics=replace(opts, cameras=(c,)))
        sol, choice = _judge(one, cam, None, options, solve, c, seen)
        reasons.append(f"{name or f'camera {c}'}: {choice.reason}")
        if sol is not None:
            chosen[c] = sol
    if not reasons:
        return None, None
    if len(chosen) > 1:
        both = replace(problem, intrinsics=replace(opts, cameras=tuple(chosen)))
        try:
            chosen = {0: solve(both, options)}
        except (CalibrationImpossible, IndeterminateSystem, np.linalg.LinAlgError) as err:
            reasons.append(f"refined together, the solve failed ({err})")
            chosen = {}
    sol = next(iter(chosen.values()), None)
    return sol, CameraChoice(sol is not None, reason="; ".join(reasons))


def _stated(choice: CameraChoice) -> bool:
    """The refined intrinsics were the stated ones within their sigma (fewer of them are not tried)."""
    k = choice.significance_dof
    return k > 0 and choice.significance <= float(chi2_dist.ppf(1 - ALPHA, k))


def _judge(
    problem: Problem, cam: CameraModel, free: Sequence[int] | None, options: NoiseOptions,
    solve: Callable[..., Solution], c: int = 0, seen: Sequence[str] | None = None,
) -> tuple[Solution | None, CameraChoice]:  # fmt: skip
    """The two tests of camera ``c``'s intrinsics ``free`` (all when None) refined in ``problem``
    (halves of the boards it sees, ``seen``, default all; the others in both): (its solution when
    both pass, else None; the choice)."""
    n_free = len(cam.intrinsic_names) if free is None else len(free)
    names = [b.name for b in problem.boards] if seen is None else list(seen)
    n, need = len(names), max(MIN_BOARDS, 2 * n_free)
    if n < need:
        why = f"{n} boards: too few to tell (halves of {need // 2} or more)"
        return None, CameraChoice(False, reason=why)
    others = [b.name for b in problem.boards if b.name not in names]
    failed = (CalibrationImpossible, IndeterminateSystem, np.linalg.LinAlgError)
    try:
        sol, v, C = _refined(problem, options, solve, free=free, c=c)
    except failed as err:
        return None, CameraChoice(False, reason=f"a refined solve failed ({err})")
    stated = cam.intrinsics() if free is None else cam.intrinsics()[list(free)]
    d = v - stated
    sig, k = float(d @ np.linalg.solve(C, d)), len(d)
    q_sig = float(chi2_dist.ppf(1 - ALPHA, max(k, 1)))
    if sig <= q_sig:  # stated within their sigma: stated, whatever the halves say (they are not solved)
        why = f"the refined ones are the stated ones within their sigma ({sig:.1f} <= {q_sig:.1f}, {k} dof)"
        return None, CameraChoice(False, sig, k, reason=why)
    try:
        half = [sorted(others + names[j::2], key=problem.index) for j in (0, 1)]  # in the problem's order
        halves = [_refined(problem, options, solve, h, free, c) for h in half]
        (_, va, Ca), (_, vb, Cb) = halves
    except failed as err:
        return None, CameraChoice(False, sig, k, reason=f"a refined solve of half the boards failed ({err})")
    dh = va - vb
    rep = float(dh @ np.linalg.solve(Ca + Cb, dh))
    q_rep = float(chi2_dist.ppf(1 - ALPHA, len(dh)))
    if rep <= q_rep:
        why = f"the boards move them ({sig:.1f} > {q_sig:.1f}), two halves agree ({rep:.1f} <= {q_rep:.1f})"
        return sol, CameraChoice(True, sig, k, rep, len(dh), why)
    carried = "their stated sigma carried"
    if cam.intrinsics_sigma is None:
        carried = "taken as exact: state camera.intrinsics_sigma (a lens calibration's) to carry their sigma"
    why = (
        f"the boards move them off the stated ones ({sig:.1f} > {q_sig:.1f}, {k} dof), but two halves of the "
        f"boards refine them differently ({rep:.1f} > {q_rep:.1f}, {len(dh)} dof): the boards do not "
        f"determine them; the stated ones look off, {carried}"
    )
    return None, CameraChoice(False, sig, k, rep, len(dh), why)


def _said(sol: Solution | None, choice: CameraChoice) -> tuple[Solution | None, CameraChoice]:
    log.info("%s", choice.summary())
    return sol, choice
