"""Studies that re-solve on subsets of frames: cross-validation and frames vs accuracy.

Both take the per-frame observations (``FrameResult`` with ``board`` and ``corners``) and a solver
callable ``solve(frames) -> (T_cam_lidar (4, 4), covariance (6, 6))`` (the pipeline's
``solve_observed`` wrapped by the caller), so they run with any refinement and never touch files.
A subset the solver rejects (it raises) is recorded with the reason and skipped.

Pose differences are tangent vectors in the covariance convention of ``shared/interface.md``:
``xi = (rotvec(R_ref^T R), R_ref^T (t - t_ref))`` for ``T = T_ref * Exp(xi)`` to first order,
rotation first (radians, metres).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..board import Board
from ..cameras import CameraModel
from ..errors import CalibrationImpossible, IndeterminateSystem
from ..types import FrameResult
from .frame_errors import eval_frame, evaluate, evaluate_many
from .metric import EvalFrame, Evaluation, FrameEvaluation

__all__ = [
    "Refused",
    "Solver",
    "study_subsets",
    "try_solve",
    "pose_difference",
    "Fold",
    "CrossValidation",
    "cross_validate",
    "FramesCurve",
    "frames_vs_accuracy",
    "usable_frames",
    "Valley",
    "valley",
]

Solver = Callable[[Sequence[FrameResult]], tuple[np.ndarray, np.ndarray]]
PARAMETERS = ("rx", "ry", "rz", "tx", "ty", "tz")


def pose_difference(T_ref: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(6,) tangent of ``T`` at ``T_ref`` (module docstring): rotation vector (rad), translation (m)."""
    T_ref, T = np.asarray(T_ref, dtype=np.float64), np.asarray(T, dtype=np.float64)
    R_ref = T_ref[:3, :3]
    rot = Rotation.from_matrix(R_ref.T @ T[:3, :3]).as_rotvec()
    return np.concatenate([rot, R_ref.T @ (T[:3, 3] - T_ref[:3, 3])])


def study_subsets(observed: Sequence[FrameResult], folds: int = 5) -> list[list[FrameResult]]:
    """Every subset ``frames_vs_accuracy`` (input order) and ``cross_validate`` (``folds``) ask their
    solver for, in that order, so that a caller can solve them all at once (on several processes)."""
    frames = usable_frames(observed)
    growing = [frames[:n] for n in range(1, len(frames) + 1)]
    if len(frames) < 2:  # cross_validate refuses before it solves
        return growing
    return growing + [train for _, train in _folds(frames, folds)]


def _folds(frames: Sequence[FrameResult], folds: int) -> list[tuple[list[FrameResult], list[FrameResult]]]:
    """(test, train) of each fold: frame i in fold i % k, k = ``folds`` capped to 2 .. len(frames)."""
    k = max(2, min(int(folds), len(frames)))
    return [([r for i, r in enumerate(frames) if i % k == f], [r for i, r in enumerate(frames) if i % k != f])
            for f in range(k)]  # fmt: skip


def usable_frames(observed: Sequence[FrameResult]) -> list[FrameResult]:
    """Frames that have both a board fit and image corners (whatever their ``used`` flag says).

    A frame the solver dropped is still usable here: pass the observed frames (``run.observe.observe``'s
    ``Observation.frames``).
    """
    return [r for r in observed if r.board is not None and r.corners is not None]


class Refused(Exception):
    """A subset the solver refused, solved before (on another process): its reason is the message."""


def try_solve(solve: Solver, frames: Sequence[FrameResult]) -> tuple[np.ndarray, np.ndarray] | str:
    """``solve(frames)`` as (T (4, 4), covariance (6, 6)), or the reason it failed (the study's record)."""
    try:
        T, cov = solve(frames)
    except (CalibrationImpossible, IndeterminateSystem, Refused) as err:  # the solver refused: it says why
        return str(err)
    except Exception as err:  # noqa: BLE001 - any other failure is a result of the study too, named
        return f"{type(err).__name__}: {err}"
    return np.asarray(T, dtype=np.float64), np.asarray(cov, dtype=np.float64)


# ------------------------------------------------------------------------ cross-validation
@dataclass(frozen=True)
class Fold:
    """One fold: fitted on ``train``, evaluated on ``test``.

    T_cam_lidar, covariance: the fit (None with ``failure`` when the solver raised).
    test: evaluation of the fit on the held-out frames. offset: (6,) pose difference of the fit
    from the all-frames fit (rad, m).
    """

    train: tuple[str, ...]
    test: tuple[str, ...]
    T_cam_lidar: np.ndarray | None
    covariance: np.ndarray | None
    test_evaluation: Evaluation | None
    offset: np.ndarray | None
    failure: str | None = None


@dataclass(frozen=True)
class CrossValidation:
    """k-fold cross-validation of a calibration.

    held_out: every frame evaluated with the fit of the fold that did not see it.
    in_sample: every frame evaluated with the all-frames fit (``T_all``).
    """

    folds: tuple[Fold, ...]
    T_all: np.ndarray
    held_out: Evaluation
    in_sample: Evaluation

    def summary(self) -> dict[str, float]:
        (hm, h3), (im, i3) = self.held_out.intensity_mrad, self.in_sample.intensity_mrad
        (hcm, hc3), (icm, ic3) = self.held_out.corner_mrad, self.in_sample.corner_mrad
        return {
            "folds": float(len(self.folds)),
            "failed_folds": float(sum(f.failure is not None for f in self.folds)),
            "held_out_intensity_mrad_mean": hm,
            "held_out_intensity_mrad_3sigma": h3,
            "in_sample_intensity_mrad_mean": im,
            "in_sample_intensity_mrad_3sigma": i3,
            "held_out_corner_mrad_mean": hcm,
            "held_out_corner_mrad_3sigma": hc3,
            "in_sample_corner_mrad_mean": icm,
            "in_sample_corner_mrad_3sigma": ic3,
        }


def cross_validate(
    observed: Sequence[FrameResult],
    solve: Solver,
    camera: CameraModel,
    board: Board,
    folds: int = 5,
    T_all: np.ndarray | None = None,
) -> CrossValidation:
    """Calibrate on all but one fold of the frames, evaluate on that fold, for every fold.

    Frames go to folds round-robin in input order (frame k to fold k % folds); ``folds`` is capped
    by the number of usable frames (``folds >= n`` is leave-one-out). ``T_all``: the all-frames fit,
    solved here when not given. Raises ValueError with fewer than 2 usable frames.
    """
    frames = usable_frames(observed)
    n = len(frames)
    if n < 2:
        raise ValueError(f"cross_validate: need at least 2 frames with board and corners, got {n}")
    if T_all is None:
        res = try_solve(solve, frames)
        if isinstance(res, str):
            raise ValueError(f"cross_validate: the all-frames fit failed: {res}")
        T_all = res[0]
    T_all = np.asarray(T_all, dtype=np.float64)
    ev_frames = {r.name: eval_frame(r) for r in frames}
    out: list[Fold] = []
    held: dict[str, FrameEvaluation] = {}
    for test, train in _folds(frames, folds):
        names_tr, names_te = tuple(r.name for r in train), tuple(r.name for r in test)
        res = try_solve(solve, train)
        if isinstance(res, str):
            out.append(Fold(names_tr, names_te, None, None, None, None, res))
            for r in test:
                held[r.name] = FrameEvaluation(r.name, float("nan"), 0, 0, 0, float("nan"))
            continue
        T, cov = res
        ev = evaluate([ev_frames[r.name] for r in test], camera, board, T)  # type: ignore[misc]
        held.update(ev.by_name())
        out.append(Fold(names_tr, names_te, T, cov, ev, pose_difference(T_all, T)))
    held_out = Evaluation(tuple(held[r.name] for r in frames), T_all)
    in_sample = evaluate([ev_frames[r.name] for r in frames], camera, board, T_all)  # type: ignore[misc]
    return CrossValidation(tuple(out), T_all, held_out, in_sample)


# -------------------------------------------------------------------- frames vs accuracy
@dataclass(frozen=True)
class FramesCurve:
    """The estimate against the number of frames (the paper's Figures 15 and 14c).

    n_frames: (L,) frames used per point (the first n of ``order``).
    offset: (L, 6) pose difference of each estimate from ``T_ref`` (rad, m).
    sigma: (L, 6) square roots of each estimate's covariance diagonal (rad, m; NaN if none).
    error_mean, error_3sigma: (L,) the intensity re-projection error (mrad) of each estimate on
        all usable frames: mean and 3 x SD over frames.
    heldout_mean: (L,) its mean over the frames not used for that estimate (NaN at n = N).
    corner_mrad_mean: (L,) mean RMS corner bearing error on all frames.
    T_ref: the reference (ground truth when given, else the estimate with the most frames).
    reference: "ground truth" or "all frames". failures: (n, reason) of subsets the solver refused.
    order: names of the frames in the order they were added.
    """

    n_frames: np.ndarray
    offset: np.ndarray
    sigma: np.ndarray
    error_mean: np.ndarray
    error_3sigma: np.ndarray
    heldout_mean: np.ndarray
    corner_mrad_mean: np.ndarray
    T_ref: np.ndarray
    reference: str
    failures: tuple[tuple[int, str], ...]
    order: tuple[str, ...]


def frames_vs_accuracy(
    observed: Sequence[FrameResult],
    solve: Solver,
    camera: CameraModel,
    board: Board,
    T_ground_truth: np.ndarray | None = None,
    order: Sequence[int] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> FramesCurve:
    """Solve with the first 1, 2, ..., N usable frames (in ``order``, default input order).

    Each estimate is compared with ``T_ground_truth`` when given, else with the N-frame estimate,
    and evaluated with the paper's metric on all usable frames.
    """
    frames = usable_frames(observed)
    N = len(frames)
    if N == 0:
        raise ValueError("frames_vs_accuracy: no frame has both a board fit and image corners")
    idx = list(range(N)) if order is None else [int(i) for i in order]
    if sorted(idx) != list(range(N)):
        raise ValueError(f"frames_vs_accuracy: order must be a permutation of 0..{N - 1}, got {idx}")
    frames = [frames[i] for i in idx]
    ev_frames = [eval_frame(r) for r in frames]
    results: list[tuple[int, np.ndarray, np.ndarray]] = []
    failures: list[tuple[int, str]] = []
    for n in range(1, N + 1):
        res = try_solve(solve, frames[:n])
        if isinstance(res, str):
            failures.append((n, res))
        else:
            results.append((n, res[0], res[1]))
        if progress:
            progress(n, N)
    if T_ground_truth is not None:
        T_ref, reference = np.asarray(T_ground_truth, dtype=np.float64), "ground truth"
    elif results:
        T_ref, reference = results[-1][1], "all frames"
    else:
        T_ref, reference = np.eye(4), "none"
    L = len(results)
    offset, sigma = np.full((L, 6), np.nan), np.full((L, 6), np.nan)
    e_mean, e_3s, held, corner = (np.full(L, np.nan) for _ in range(4))
    for row, (n, T, cov) in enumerate(results):
        offset[row] = pose_difference(T_ref, T)
        if cov.shape == (6, 6):
            sigma[row] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        ev = evaluate(ev_frames, camera, board, T)  # type: ignore[arg-type]
        e_mean[row], e_3s[row] = ev.intensity_mrad
        corner[row] = ev.corner_mrad[0]
        rest = np.array([f.intensity_mrad for f in ev.frames[n:]])
        held[row] = float(np.mean(rest)) if rest.size else np.nan
    return FramesCurve(
        n_frames=np.array([r[0] for r in results], dtype=int),
        offset=offset,
        sigma=sigma,
        error_mean=e_mean,
        error_3sigma=e_3s,
        heldout_mean=held,
        corner_mrad_mean=corner,
        T_ref=T_ref,
        reference=reference,
        failures=tuple(failures),
        order=tuple(r.name for r in frames),
    )


# --------------------------------------------------------------------------- the valley
@dataclass(frozen=True)
class Valley:
    """The metrics around an estimate, one parameter at a time (is the estimate at the bottom?).

    steps: (S,) multiples of the step; offsets (6, S): the tangent offsets applied
    (``T * Exp(xi)``, rad and m, the covariance convention). intensity, corner: (6, S) mean over
    frames of the intensity error and of the RMS corner error (mrad). sigma: (6,) of the
    estimate (NaN when unknown).
    """

    steps: np.ndarray
    offsets: np.ndarray
    intensity: np.ndarray
    corner: np.ndarray
    sigma: np.ndarray


def _exp_right(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``T * Exp(xi)`` to first order in the translation (rotation exact): xi = (rotvec, t)."""
    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec(xi[:3]).as_matrix()
    D[:3, 3] = xi[3:]
    return np.asarray(T, dtype=np.float64) @ D


def valley(
    frames: Sequence[EvalFrame],
    camera: CameraModel,
    board: Board,
    T_cam_lidar: np.ndarray,
    covariance: np.ndarray | None = None,
    rotation_deg: float = 0.5,
    translation_m: float = 0.03,
    n: int = 5,
) -> Valley:
    """Evaluate ``T_cam_lidar * Exp(xi)`` with xi along each of the six parameters in turn, over
    ``[-1, 1]`` x (``rotation_deg``, ``translation_m``) in ``2 n + 1`` steps."""
    steps = np.linspace(-1.0, 1.0, 2 * n + 1)
    scale = np.array([np.radians(rotation_deg)] * 3 + [translation_m] * 3)
    offsets = scale[:, None] * steps[None, :]
    Ts = []
    for k in range(6):
        for a in offsets[k]:
            xi = np.zeros(6)
            xi[k] = a
            Ts.append(_exp_right(T_cam_lidar, xi))
    evs = evaluate_many(frames, camera, board, Ts)
    inten = np.array([ev.intensity_mrad[0] for ev in evs]).reshape(6, steps.size)
    corner = np.array([ev.corner_mrad[0] for ev in evs]).reshape(6, steps.size)
    cov = np.full((6, 6), np.nan) if covariance is None else np.asarray(covariance, dtype=np.float64)
    sigma = np.sqrt(np.clip(np.diag(cov), 0.0, None)) if cov.shape == (6, 6) else np.full(6, np.nan)
    return Valley(steps, offsets, inten, corner, sigma)
