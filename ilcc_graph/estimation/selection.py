"""Which model of the sensors' own errors the boards support, chosen per run (issue 21).

Candidates (``MODELS``), each a way of reading the LiDAR:

- ``none``: each board the LiDAR stage's 6-dof pose with its covariance;
- ``offset``: the same with one range offset of the LiDAR (``O(l)``, every board shifted along its
  rays), what ``--range-offset`` estimates;
- ``beams``: the boards' returns with the LiDAR's per-beam and dark-print range offsets, each
  board's own plane and each beam's offset on each board as random effects (``--lidar-errors``).

Each candidate is solved under the one noise policy (``noise.solve_problem``) and scored by how
well it predicts each board's image from the other boards and the board's own LiDAR data
(``held_out``: leave-one-board-out cross-validation, summed over the boards every candidate kept;
a rig's: each camera's view of each board held out in turn, summed over the cameras).
The weights ``exp(score)`` normalised (pseudo Bayesian model averaging with cross-validated
densities) choose the model with the largest, and its covariance carries the others it does not
contain: about the chosen estimate, ``sum_m w_m (C_m + d_m d_m^T)`` with ``d_m`` the other model's
estimate's offset (``averaged_covariance``). A decisive score leaves the chosen model's own
covariance; two models that the boards cannot tell apart widen it by their difference. A model the
chosen one contains (``SensorModel.contains``: its terms held at zero) is not carried: where it is
right, the chosen model's estimate is unbiased and its covariance already holds the spread between
the two (``C_chosen - C_m`` in expectation), so carrying it would count that spread twice; where it
is wrong, its offset is the bias the chosen model removes (docs/bench_joint_lidar.md).

Why a held-out score and not an information criterion on the chi-square: the candidates read
different data (poses against returns), and a model's own chi-square trusts its own noise model,
which is what a term the boards barely determine gets wrong (docs/estimation.md,
docs/bench_sensor_model.md).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TypeVar

import gtsam
import numpy as np

from ilcc_graph.errors import IndeterminateSystem
from ilcc_graph.estimation.camera_choice import CameraChoice
from ilcc_graph.estimation.chi2 import sf as chi2_sf
from ilcc_graph.estimation.held_out import HeldOut
from ilcc_graph.estimation.keys import POSE3_DOF
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.noise import Solution
from ilcc_graph.estimation.problem import Problem

log = logging.getLogger(__name__)

__all__ = [
    "AUTO",
    "MODELS",
    "BoardKey",
    "Candidate",
    "Selection",
    "SensorModel",
    "averaged_covariance",
    "candidates",
    "choose",
    "contradicted",
    "mixture",
    "range_terms",
]

#: the prior sigma of the ``offset`` model's range offset (m): weak, the boards determine it
OFFSET_PRIOR_M = 0.1
#: weights below this are left out of the averaged covariance
MIN_WEIGHT = 1e-4


@dataclass(frozen=True)
class SensorModel:
    """One way of reading the sensors' own errors: the LiDAR's error terms (None: none), a range
    offset's prior sigma (None: no offset), a description, and the models it contains (``contains``:
    the names of the models that are this one with some of its terms held at zero)."""

    name: str
    lidar_errors: LidarErrorOptions | None = None
    range_offset_m: float | None = None
    description: str = ""
    contains: frozenset[str] = frozenset()

    def problem(self, base: Problem) -> Problem:
        """``base`` (a problem without sensor terms) with this model's."""
        return replace(base, lidar_errors=self.lidar_errors, range_offset_sigma_m=self.range_offset_m)


MODELS: dict[str, SensorModel] = {
    "none": SensorModel("none", description="each board the LiDAR stage's 6-dof pose"),
    "offset": SensorModel(
        "offset",
        range_offset_m=OFFSET_PRIOR_M,
        description="the LiDAR stage's poses and one range offset",
        contains=frozenset({"none"}),
    ),
    "beams": SensorModel(
        "beams",
        LidarErrorOptions(),
        description="the returns with per-beam and dark-print range offsets, the boards' planes as random "
        "effects",
        contains=frozenset({"none", "offset", "range"}),
    ),
}
MODELS["range"] = SensorModel(
    "range",
    LidarErrorOptions(beam_offsets=False, global_offset=True),
    description="the returns with one range offset and the dark-print offset, the boards' planes as random "
    "effects",
    contains=frozenset({"none", "offset"}),
)
#: the candidates of the default (``--sensor-model auto``)
AUTO = ("none", "range", "beams")
AUTO_MODELS = tuple(MODELS[n] for n in AUTO)  # select_model's default candidates


@dataclass(frozen=True)
class Candidate:
    """One candidate's result: its held-out log density and chi-square over the boards every
    candidate kept (``boards``; 6 dof each), the boards it kept itself (``used``), its weight, and
    why it failed (then the rest are None / 0) or was left out with its scores (``left_out``: weight 0)."""

    name: str
    log_density: float = math.nan
    chi2: float = math.nan
    boards: int = 0
    used: int = 0
    weight: float = 0.0
    factor: float = 1.0
    failure: str | None = None
    left_out: str | None = None


@dataclass(frozen=True)
class Selection:
    """The model chosen and the evidence: every candidate, whether the choice was forced (a flag or
    ``--sensor-model``), whether the covariance carries other candidates (``averaged``) and the
    camera's choice (``camera_choice``; None when not made)."""

    chosen: str
    candidates: tuple[Candidate, ...]
    forced: bool = False
    averaged: bool = False
    camera: CameraChoice | None = None

    def carried(self) -> tuple[str, ...]:
        """The candidates the covariance carries: the chosen one and each other with weight that the
        chosen model does not contain (module docstring)."""
        return carried(self.chosen, {c.name: c.weight for c in self.candidates})

    @property
    def factor(self) -> float:
        """The chosen model's held-out factor, its own covariance's scale (1 for a forced model)."""
        return next(c.factor for c in self.candidates if c.name == self.chosen)

    def summary(self) -> str:
        """One or two lines: the model and the evidence (held-out log densities against the chosen
        one), the camera's intrinsics."""
        cam = "" if self.camera is None else "\n" + self.camera.summary()
        return self._lidar_summary() + cam

    def _lidar_summary(self) -> str:
        if self.forced:
            return f"sensor model: {self.chosen} (as asked)"
        best = next(c for c in self.candidates if c.name == self.chosen)
        parts = []
        for c in self.candidates:
            if c.failure is not None:
                parts.append(f"{c.name} failed")
            elif c.left_out is not None:
                parts.append(f"{c.name} {c.log_density - best.log_density:+.1f} (left out: {c.left_out})")
            elif c.name != self.chosen:
                parts.append(f"{c.name} {c.log_density - best.log_density:+.1f} (w {c.weight:.2f})")
        carried = "; covariance averaged over the models" if self.averaged else ""
        return (
            f"sensor model: {self.chosen} (held-out images of {best.boards} boards, log density against "
            f"it: {', '.join(parts) or 'no other'}; chi2 {best.chi2:.0f} for {POSE3_DOF * best.boards})"
            + carried
        )

    @classmethod
    def from_dict(cls, d: Mapping) -> Selection:
        """The selection ``to_dict`` wrote (calibration.yaml's ``sensor_errors.model``)."""

        def num(x: object, default: float = math.nan) -> float:
            return default if x is None else float(x)  # type: ignore[arg-type]

        cands = tuple(
            Candidate(
                str(c["name"]),
                num(c.get("log_density")),
                num(c.get("chi2")),
                int(c.get("boards", 0)),
                int(c.get("used", 0)),
                num(c.get("weight"), 0.0),
                num(c.get("factor"), 1.0),
                c.get("failure"),
                c.get("left_out"),
            )  # fmt: skip
            for c in d.get("candidates") or ()
        )
        cam = CameraChoice.from_dict(d["camera"]) if d.get("camera") else None
        return cls(str(d["chosen"]), cands, bool(d.get("forced", False)), bool(d.get("averaged", False)), cam)

    def to_dict(self) -> dict:
        """Plain data for calibration.yaml."""
        return {
            "chosen": self.chosen,
            "forced": self.forced,
            "averaged": self.averaged,
            "criterion": "leave-one-board-out log density of each board's image pose given its LiDAR data",
            **({"camera": self.camera.to_dict()} if self.camera is not None else {}),
            "candidates": [
                {
                    "name": c.name,
                    "description": MODELS[c.name].description if c.name in MODELS else "",
                    "log_density": None if not math.isfinite(c.log_density) else float(c.log_density),
                    "chi2": None if not math.isfinite(c.chi2) else float(c.chi2),
                    "boards": int(c.boards),
                    "used": int(c.used),
                    "weight": float(c.weight),
                    "factor": float(c.factor),
                    **({"failure": c.failure} if c.failure else {}),
                    **({"left_out": c.left_out} if c.left_out else {}),
                }
                for c in self.candidates
            ],
        }


CV_FACTOR = True
BOOTSTRAP = 1000


def carried(chosen: str, weights: Mapping[str, float]) -> tuple[str, ...]:
    """Of the candidates' ``weights`` (by name), the ones a covariance about ``chosen`` carries: the
    chosen one and each other with weight at least ``MIN_WEIGHT`` that the chosen model does not
    contain (a name not in ``MODELS`` contains none)."""
    inner = MODELS[chosen].contains if chosen in MODELS else frozenset()
    return tuple(n for n, w in weights.items() if n == chosen or (w >= MIN_WEIGHT and n not in inner))


#: a board's key in the held-out scores (its index in the problem; with several sources, with its
#: source's)
BoardKey = TypeVar("BoardKey", bound=Hashable)


def _calibrated(h: HeldOut, f: float) -> float:
    """The held-out log density with the predictive covariance scaled by f."""
    return -0.5 * (h.chi2 / f + POSE3_DOF * math.log(f) + h.logdet)


def _weights(per_board: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Pseudo-BMA+ weights (Yao et al. 2018): softmax of the summed held-out log densities, averaged over
    Bayesian-bootstrap reweightings of the boards (the sum's own uncertainty with few boards)."""
    names = list(per_board)
    L = np.array([per_board[n] for n in names])  # (models, boards)
    n = L.shape[1]
    if n == 0:
        return {m: 1.0 / len(names) for m in names}
    rng = np.random.default_rng(0)
    a = rng.dirichlet(np.ones(n), size=BOOTSTRAP) if BOOTSTRAP else np.full((1, n), 1.0 / n)
    z = n * a @ L.T  # (draws, models)
    z -= z.max(axis=1, keepdims=True)
    w = np.exp(z)
    w /= w.sum(axis=1, keepdims=True)
    return dict(zip(names, (float(x) for x in w.mean(axis=0)), strict=True))


def mixture(estimates: Mapping[str, tuple[np.ndarray, np.ndarray]], selection: Selection) -> np.ndarray:
    """(6n, 6n) the mixture's covariance about the chosen model's poses: ``sum_m w_m (f_m C_m +
    d_m d_m^T)`` over the candidates' ``estimates`` (by name: T (4, 4), or (n, 4, 4) for n poses
    such as a rig's, and their (6n, 6n) joint C) that the selection carries (``Selection.carried``),
    ``d_m`` the poses' ``Logmap(T_chosen^-1 T_m)`` stacked, ``C_m`` carried into the chosen's
    tangents and scaled by its held-out factor ``f_m``."""
    T0 = [gtsam.Pose3(T) for T in np.reshape(estimates[selection.chosen][0], (-1, 4, 4))]
    n = POSE3_DOF * len(T0)
    out = np.zeros((n, n))
    total = 0.0
    keep = selection.carried()
    for c in selection.candidates:
        if c.name not in keep or c.name not in estimates:
            continue
        T, C = estimates[c.name]
        D = [t0.between(gtsam.Pose3(t)) for t0, t in zip(T0, np.reshape(T, (-1, 4, 4)), strict=True)]
        d = np.concatenate([np.asarray(gtsam.Pose3.Logmap(x), dtype=np.float64) for x in D])
        Ad = np.zeros((n, n))
        for k, x in enumerate(D):
            Ad[POSE3_DOF * k : POSE3_DOF * (k + 1), POSE3_DOF * k : POSE3_DOF * (k + 1)] = x.AdjointMap()
        out += c.weight * (c.factor * Ad @ C @ Ad.T + np.outer(d, d))
        total += c.weight
    out /= total
    return 0.5 * (out + out.T)


def averaged_covariance(sols: Mapping[str, Solution], selection: Selection, e: int = 0) -> np.ndarray:
    """``mixture`` of the solutions' extrinsic ``e``."""
    est = {n: sol.extrinsic(e) for n, sol in sols.items()}
    return mixture({n: (x.T, x.covariance) for n, x in est.items()}, selection)


def choose(
    scores: Mapping[str, Mapping[BoardKey, HeldOut]],
    used: Mapping[str, int],
    names: Sequence[str],
    failures: Mapping[str, str] | None = None,
    left_out: Mapping[str, str] | None = None,
) -> Selection:
    """The choice among ``names`` from each solved candidate's held-out ``scores`` (per board) and the
    boards it kept (``used``); ``failures``: why the others have none; ``left_out``: candidates the
    data contradict (``contradicted``), scored but given no weight (module docstring)."""
    failures = dict(failures or {})
    left_out = {n: why for n, why in (left_out or {}).items() if n in scores}
    if len(left_out) == len(scores):  # nothing would remain: the choice stays with the scores
        left_out = {}
    common = sorted(set.intersection(*(set(s) for s in scores.values())), key=str) if scores else []
    factors = {n: 1.0 for n in scores}
    if CV_FACTOR and common:
        factors = {
            n: max(1.0, sum(s[k].chi2 for k in common) / (POSE3_DOF * len(common))) for n, s in scores.items()
        }
    per_board = {n: np.array([_calibrated(s[k], factors[n]) for k in common]) for n, s in scores.items()}
    weights = {n: 0.0 for n in left_out} | _weights({n: x for n, x in per_board.items() if n not in left_out})
    chosen = max(weights, key=lambda n: weights[n]) if weights else next(iter(used))
    cands = []
    for name in names:
        if name not in scores:
            cands.append(Candidate(name, used=used.get(name, 0), failure=failures.get(name, "not solved")))
            continue
        s = scores[name]
        cands.append(
            Candidate(name, float(per_board[name].sum()), sum(s[k].chi2 for k in common), len(common),
                      used[name], weights[name], factors[name], left_out=left_out.get(name))
        )  # fmt: skip
    averaged = len(carried(chosen, weights)) > 1
    return Selection(chosen, tuple(cands), forced=False, averaged=averaged)


#: a model without range terms is left out of the choice when another model's range terms are this
#: far from zero (the p-value of their Wald chi-square): the boards then show a range error the model
#: ignores, and the held-out score cannot see an error that every board shares (a dense LiDAR's dark
#: print moves each board's plane by ~0.7 mm, 15 of its sigmas, all boards alike; docs/estimation.md)
TERMS_P = 1e-3


def range_terms(sol: Solution) -> tuple[float, int]:
    """Wald chi-square and dof of the LiDARs' own error terms of ``sol`` against zero ((0, 0): none;
    a LiDAR whose terms the boards do not determine is left out of the sum, not tested)."""
    chi2, dof = 0.0, 0
    for lidar in sol.assembly.layouts:
        try:
            got = sol.lidar_estimate(lidar)
            if got is None:
                continue
            v, C = got
            chi2 += float(v @ np.linalg.solve(C, v))
        except (IndeterminateSystem, np.linalg.LinAlgError):
            continue
        dof += v.size
    return chi2, dof


def contradicted(terms: Mapping[str, tuple[float, int]], models: Sequence[SensorModel]) -> dict[str, str]:
    """The models of ``models`` without range terms that the range terms of the model with the fewest
    of them contradict (``terms``: each solved model's ``range_terms``; ``TERMS_P``; per-beam terms
    that few boards barely determine are not tested), each with the reason; empty when those terms
    are not significant."""
    tested = min((n for n in terms if terms[n][1]), key=lambda n: terms[n][1], default=None)
    if tested is None or chi2_sf(*terms[tested]) >= TERMS_P:
        return {}
    chi2, dof = terms[tested]
    why = f"the {tested} model's range terms are far from zero (chi2 {chi2:.0f} for {dof})"
    return {m.name: why for m in models if m.lidar_errors is None and m.range_offset_m is None}


def candidates(models: Sequence[SensorModel], corrected: bool) -> list[SensorModel]:
    """The models to choose among: ``models``, or with boards fitted on corrected ranges
    (``corrected``) only those with range terms (when a choice remains): those boards' poses rest on
    the LiDAR's estimated errors, whose uncertainty only the range terms carry."""
    with_terms = [m for m in models if m.lidar_errors is not None or m.range_offset_m is not None]
    if not corrected or len(models) < 2 or not with_terms or len(with_terms) == len(models):
        return list(models)
    log.info("sensor model: the boards were fitted on corrected ranges; only the models with range terms")
    return with_terms
