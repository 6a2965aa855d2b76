"""Monte Carlo of the rig in one graph and of ``verify`` (issue 24) -> docs/bench_rig.md.

Rig kinds (the simulator's presets): ``ring-pinhole`` (an HDL-32 and four 480 px pinhole cameras at
90 deg; no two cameras share a board), ``ring-fisheye`` (the same with 480 px fisheyes; front+left
and left+back share a few boards), ``backpack`` (a VLP-16, an OS1-64 turned 90 deg, a 2400 px
panorama); 12 boards per calibration capture.

1. **Observation level** (``simulate.rig_observations``: the simulator's boards and visibility, each
   observation drawn from its stated covariance; no rendering): ``--runs`` rigs per kind. Every
   sensor pair's NEES (mean of ``xi^T C^-1 xi``, 6 expected) and 95 % coverage (NEES below
   chi2_0.95(6) = 12.59); RMS error of the joint solve against each pair solved alone (a
   camera-LiDAR or LiDAR-LiDAR pair: the graph of those two sensors and their shared boards, which is
   today's single-pair problem; a pair without shared boards, or two cameras: the chain of the two
   camera-LiDAR pairs solved alone through the reference LiDAR, the way pairs are chained today).
2. **Rendered** (``scripts/bench_rig_observe.py``'s cache: the simulator's scans and images through
   the real stages): the same NEES and coverage on every cached calibration capture.
3. **verify**: a 12-board calibration, then 5-board captures of the unchanged rig and of the rig with
   one sensor (not the reference; cycled) turned 0.25 deg about a random axis or shifted 10 mm in a
   random direction (``RigSpec.moved``): how often the rig's verdict is ``fail`` (false alarms /
   detections) and the moved sensor's own verdict; the smallest detectable change (median).
   Observation level per ``--verify`` seeds; rendered on the cached captures.
4. **Sensor models** (``--models N``, on the cached captures): the rendered rigs solved with the
   base LiDAR's sensor model forced to ``none``, forced to ``beams`` and chosen (``auto``, the
   default): every pair's NEES, coverage, RMS error and RMS sigma under each.

Run: ``nice -n 10 python3 scripts/bench_rig.py [--runs 50] [--verify 50] [--models 20] [--write]``
(one process).
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from _shared import write_between  # noqa: E402
from bench_rig_observe import CACHE, moved_mount  # noqa: E402

from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem  # noqa: E402
from ilcc_graph.estimation.rig_solve import RigOptions, RigSolution, between  # noqa: E402
from ilcc_graph.estimation.selection import AUTO  # noqa: E402
from ilcc_graph.estimation.verify import StoredRig, VerifyResult, verify_rig  # noqa: E402
from ilcc_graph.run.rig_calibrate import RigRunOptions, solve_observed  # noqa: E402
from ilcc_graph.run.rig_observe import RigObservation  # noqa: E402
from ilcc_graph.simulate.rig_observations import observe_spec  # noqa: E402
from ilcc_graph.simulate.rig_spec import RigSpec, backpack_rig, ring_rig  # noqa: E402
from ilcc_graph.types import Estimate, MomentResult  # noqa: E402

DOC = ROOT / "docs" / "bench_rig.md"
Q95 = 12.5916  # chi2_0.95(6)
VERIFY_MOMENTS = 5
#: per kind the views of a 5-board verify capture: every camera sees one board (docs/bench_rig.md)
VERIFY_VIEWS = {
    "ring-pinhole": (("front",), ("left",), ("back",), ("right",), ("front",)),
    "ring-fisheye": (("front", "left"), ("left", "back"), ("back",), ("right",), ("front",)),
    "backpack": None,
}


def make(kind: str, seed: int, verify: bool = False) -> RigSpec:
    n = VERIFY_MOMENTS if verify else 12
    if kind == "backpack":
        return backpack_rig(width=2400, n_moments=n, seed=seed)
    spec = ring_rig(kind.split("-")[1], width=480, n_moments=n, seed=seed)
    views = VERIFY_VIEWS[kind]
    return spec.with_(views=tuple((*v, "lidar") for v in views)) if verify and views else spec


def xi_error(est: Estimate, T_true: np.ndarray) -> np.ndarray:
    return np.asarray(gtsam.Pose3(est.T).localCoordinates(gtsam.Pose3(T_true)))


def solve(  # noqa: ANN001
    rig,
    moments: Sequence[MomentResult],
    keep: Sequence[str] | None = None,
    options: RigOptions = RigOptions(),
) -> RigSolution:
    """The joint solve of ``moments`` (only sensors ``keep``'s observations when given)."""
    if keep is not None:
        moments = [
            MomentResult(
                m.name,
                {s: f for s, f in m.boards.items() if s in keep},
                {s: c for s, c in m.corners.items() if s in keep},
            )
            for m in moments
        ]
        sensors = tuple(s for s in rig.sensors if s.name in keep)
        ref = rig.reference if rig.reference in keep else next(s.name for s in sensors if s.kind == "lidar")
        rig = type(rig)(rig.board, sensors, ref, rig.data, rig.base_dir, rig.source)
    return solve_observed(RigObservation(rig, list(moments)), RigRunOptions(solve=options)).solution


def alone(rig, moments: Sequence[MomentResult], a: str, b: str) -> Estimate | None:  # noqa: ANN001
    """Pair (a, b) solved alone (module docstring), or None when it cannot be."""
    lidar = rig.lidars[0]
    kinds = {rig.sensor(s).kind for s in (a, b)}
    shared = sum(1 for m in moments if {a, b} <= {*m.boards, *m.corners})
    try:
        if kinds != {"camera"} and shared >= 3:
            return solve(rig, moments, (a, b)).relative(a, b)
        if lidar in (a, b):
            return None
        # two cameras, or a pair with too few shared boards: the chain through the reference LiDAR
        ea, eb = (solve(rig, moments, (s, lidar)).relative(lidar, s) for s in (a, b))
        C = np.zeros((12, 12))
        C[:6, :6], C[6:, 6:] = ea.covariance, eb.covariance
        return between(ea.T, eb.T, C)
    except (CalibrationImpossible, IndeterminateSystem, ValueError):
        return None


# ------------------------------------------------------------------------------ 1. calibration
def calibration_stats(
    runs: Sequence[tuple[object, list[MomentResult], dict[str, np.ndarray]]],
    with_alone: bool,
    options: RigOptions = RigOptions(),
    chosen: list[str] | None = None,
) -> dict[tuple[str, str], dict[str, list[float]]]:
    """Per pair its figures over ``runs`` (``options``: the joint solve's; ``chosen``: filled with each
    rig's sensor model)."""
    out: dict[tuple[str, str], dict[str, list[float]]] = {}
    for rig, moments, truth in runs:
        try:
            sol = solve(rig, moments, options=options)
        except (CalibrationImpossible, IndeterminateSystem) as err:
            print(f"  not solved: {err}", flush=True)
            continue
        if chosen is not None and sol.selection is not None:
            chosen.append(sol.selection.chosen)
        names = sol.sensors
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                T_ab = np.linalg.solve(truth[a], truth[b])
                est = sol.relative(a, b)
                xi = xi_error(est, T_ab)
                row = out.setdefault((a, b), {})
                row.setdefault("nees", []).append(float(xi @ np.linalg.solve(est.covariance, xi)))
                row.setdefault("rot", []).append(float(np.degrees(np.linalg.norm(xi[:3]))))
                row.setdefault("trans", []).append(float(1e3 * np.linalg.norm(xi[3:])))
                row.setdefault("sig_rot", []).append(
                    float(np.degrees(np.sqrt(np.trace(est.covariance[:3, :3]))))
                )
                row.setdefault("sig_trans", []).append(float(1e3 * np.sqrt(np.trace(est.covariance[3:, 3:]))))
                row.setdefault("shared", []).append(
                    float(sum(1 for m in moments if {a, b} <= {*m.boards, *m.corners}))
                )
                if with_alone:
                    e2 = alone(rig, moments, a, b)
                    if e2 is not None:
                        x2 = xi_error(e2, T_ab)
                        row.setdefault("rot_alone", []).append(float(np.degrees(np.linalg.norm(x2[:3]))))
                        row.setdefault("trans_alone", []).append(float(1e3 * np.linalg.norm(x2[3:])))
                        row.setdefault("rot_joint_paired", []).append(row["rot"][-1])
                        row.setdefault("trans_joint_paired", []).append(row["trans"][-1])
                        row.setdefault("nees_alone", []).append(
                            float(x2 @ np.linalg.solve(e2.covariance, x2))
                        )
    return out


def rms(v: Sequence[float]) -> float:
    return float(np.sqrt(np.mean(np.square(v)))) if len(v) else float("nan")


def calibration_table(stats: dict[tuple[str, str], dict[str, list[float]]], with_alone: bool) -> str:
    head = "| pair | rigs | shared boards | NEES | 95 % coverage | RMS error joint (deg / mm) |"
    sep = "|---|---|---|---|---|---|"
    if with_alone:
        head += " RMS error alone (deg / mm) | alone / joint (rot, trans) | NEES alone |"
        sep += "---|---|---|"
    lines = [head, sep]
    all_nees: list[float] = []
    for (a, b), r in stats.items():
        n = np.asarray(r["nees"])
        all_nees += list(n)
        line = (
            f"| {a}-{b} | {len(n)} | {np.mean(r['shared']):.1f} | {n.mean():.2f} | "
            f"{100 * np.mean(n < Q95):.0f} % | {rms(r['rot']):.3f} / {rms(r['trans']):.2f} |"
        )
        if with_alone:
            if r.get("rot_alone"):
                ra, ta = rms(r["rot_alone"]), rms(r["trans_alone"])
                rj, tj = rms(r["rot_joint_paired"]), rms(r["trans_joint_paired"])
                line += (
                    f" {ra:.3f} / {ta:.2f} | {ra / rj:.2f}, {ta / tj:.2f} | "
                    f"{np.mean(r['nees_alone']):.2f} ({len(r['rot_alone'])}) |"
                )
            else:
                line += " - | - | - |"
        lines.append(line)
    a = np.asarray(all_nees)
    means = [float(np.mean(r["nees"])) for r in stats.values()]
    cover = [100 * float(np.mean(np.asarray(r["nees"]) < Q95)) for r in stats.values()]
    lines.append("")
    lines.append(
        f"All pairs pooled: NEES {a.mean():.2f}, coverage {100 * np.mean(a < Q95):.1f} % "
        f"({len(a)} pair estimates); per-pair NEES range "
        f"{min(means):.2f}-{max(means):.2f}, coverage {min(cover):.0f}-{max(cover):.0f} %."
    )
    return "\n".join(lines)


# ------------------------------------------------------------------------------ 3. verify
def verify_stats(
    cases: Sequence[tuple[object, StoredRig, str, list[MomentResult], str | None]],
) -> dict[str, dict[str, list]]:
    """cases: (rig, stored, what ('same', 'rot', 'trans'), capture, moved sensor)."""
    out: dict[str, dict[str, list]] = {}
    for rig, stored, what, moments, moved in cases:
        cams = {c: rig.sensor(c).camera for c in rig.cameras}
        res: VerifyResult = verify_rig(stored, moments, rig.board, list(rig.lidars), cams)
        row = out.setdefault(what, {})
        row.setdefault("rig_fail", []).append(res.verdict == "fail")
        row.setdefault("verdict", []).append(res.verdict)
        if moved is not None:
            c = res.sensors[moved]
            row.setdefault("sensor_fail", []).append(c.verdict == "fail")
            others = [x.verdict == "fail" for s, x in res.sensors.items() if s != moved]
            row.setdefault("others_fail", []).append(any(others))
        for c in res.sensors.values():
            if np.isfinite(c.detectable_deg):
                row.setdefault("det_deg", []).append(c.detectable_deg)
                row.setdefault("det_mm", []).append(c.detectable_mm)
    return out


def verify_table(stats: dict[str, dict[str, list]]) -> str:
    lines = [
        "| capture | n | rig verdict fail | moved sensor fail | another sensor fail | "
        "verdicts (pass/warn/fail) | smallest detectable, median (deg / mm) |",
        "|---|---|---|---|---|---|---|",
    ]
    label = {"same": "unchanged", "rot": "one sensor turned 0.25 deg", "trans": "one sensor shifted 10 mm"}
    for what in ("same", "rot", "trans"):
        r = stats.get(what)
        if not r:
            continue
        n = len(r["rig_fail"])
        v = r["verdict"]
        counts = "/".join(str(v.count(x)) for x in ("pass", "warn", "fail"))
        sf = f"{100 * np.mean(r['sensor_fail']):.0f} %" if "sensor_fail" in r else "-"
        of = f"{100 * np.mean(r['others_fail']):.0f} %" if "others_fail" in r else "-"
        lines.append(
            f"| {label[what]} | {n} | {100 * np.mean(r['rig_fail']):.0f} % | {sf} | {of} | {counts} | "
            f"{np.median(r['det_deg']):.3f} / {np.median(r['det_mm']):.1f} |"
        )
    return "\n".join(lines)


# ------------------------------------------------------------------------------ main
def observation_runs(kind: str, seeds: Sequence[int]) -> list:
    out = []
    for seed in seeds:
        spec = make(kind, seed)
        out.append((spec.rig_config(), observe_spec(spec), spec.T_ref_sensor()))
    return out


def observation_verify(kind: str, seeds: Sequence[int]) -> list:
    cases = []
    for seed in seeds:
        cal = make(kind, seed)
        rig = cal.rig_config()
        try:
            stored = StoredRig.from_solution(solve(rig, observe_spec(cal)))
        except (CalibrationImpossible, IndeterminateSystem) as err:
            print(f"  {kind} {seed}: no stored calibration: {err}", flush=True)
            continue
        spec = make(kind, 1000 + seed, verify=True)
        cases.append((rig, stored, "same", observe_spec(spec), None))
        for what in ("rot", "trans"):
            m = moved_mount(spec, 1000 + seed, what)
            cases.append((rig, stored, what, observe_spec(spec.with_(moved=m)), m.sensor))
    return cases


def _load(p: Path) -> dict:
    return pickle.loads(p.read_bytes())


def rendered_runs(kind: str, limit: int) -> list:
    files = sorted((CACHE / kind).glob("cal-*.pkl"))[:limit]
    return [(d["rig"], d["moments"], d["truth"]) for d in map(_load, files)]


def rendered_verify(kind: str, limit: int) -> list:
    cases = []
    cal = {int(p.stem.split("-")[1]): p for p in (CACHE / kind).glob("cal-*.pkl")}
    for p in sorted((CACHE / kind).glob("ver-*.pkl"))[:limit]:
        seed = int(p.stem.split("-")[1])
        c = cal.get(seed - 1000)
        moved = {w: CACHE / kind / f"{w}-{seed:04d}.pkl" for w in ("rot", "trans")}
        if c is None or not all(q.exists() for q in moved.values()):
            continue
        d = _load(c)
        try:
            stored = StoredRig.from_solution(solve(d["rig"], d["moments"]))
        except (CalibrationImpossible, IndeterminateSystem):
            continue
        cases.append((d["rig"], stored, "same", _load(p)["moments"], None))
        for w, q in moved.items():
            dm = _load(q)
            cases.append((d["rig"], stored, w, dm["moments"], dm["moved"].sensor))
    return cases


def timed(what: str, fn: Callable[[], str]) -> str:
    t0 = time.perf_counter()
    text = fn()
    print(f"{what}: {time.perf_counter() - t0:.0f} s", flush=True)
    return text


def observation_part(kind: str, runs: int, verify: int) -> str:
    obs = timed(
        f"{kind} calibration (observation level)",
        lambda: calibration_table(calibration_stats(observation_runs(kind, range(1, runs + 1)), True), True),
    )
    ver = timed(
        f"{kind} verify (observation level)",
        lambda: verify_table(verify_stats(observation_verify(kind, range(1, verify + 1)))),
    )
    return (
        f"### {kind}\n\nCalibration, {runs} rigs x 12 boards:\n\n{obs}\n\n"
        f"verify, {verify} stored calibrations x 3 captures of 5 boards:\n\n{ver}\n"
    )


def rendered_part(kind: str, limit: int) -> str:
    rendered = rendered_runs(kind, limit)
    ren = (
        timed(
            f"{kind} calibration (rendered)",
            lambda: calibration_table(calibration_stats(rendered, False), False),
        )
        if rendered
        else "no cached captures"
    )
    cases = rendered_verify(kind, limit)
    ver = (
        timed(f"{kind} verify (rendered)", lambda: verify_table(verify_stats(cases)))
        if cases
        else "none cached"
    )
    return (
        f"### {kind}\n\nCalibration, {len(rendered)} rigs x 12 boards:\n\n{ren}\n\n"
        f"verify, {len(cases) // 3} stored calibrations x 3 captures of 5 boards:\n\n{ver}\n"
    )


#: the base LiDAR's sensor models compared on the rendered rigs (``--models``)
MODEL_RUNS = {"none": ("none",), "beams": ("beams",), "auto": AUTO}


def models_part(kind: str, limit: int) -> str:
    """The rendered rigs solved with the base LiDAR's sensor model forced to ``none``, to ``beams``,
    and chosen (``auto``): every pair's NEES, coverage and RMS error under each."""
    rendered = rendered_runs(kind, limit)
    if not rendered:
        return f"### {kind}\n\nno cached captures\n"
    pooled, chosen, by_model = [], [], {}
    t0 = time.perf_counter()
    for label, models in MODEL_RUNS.items():
        picks: list[str] = []
        by_model[label] = calibration_stats(rendered, False, RigOptions(models=models), picks)
        if len(models) > 1:
            chosen = picks
        allv = np.concatenate([r["nees"] for r in by_model[label].values()])
        pooled.append(f"{label} NEES {allv.mean():.2f}, coverage {100 * np.mean(allv < Q95):.1f} %")
    lines = [
        "| pair | NEES none / beams / auto | coverage none / beams / auto | RMS error none, auto (deg / mm) "
        "| RMS sigma none, auto (deg / mm) |",
        "|---|---|---|---|---|",
    ]
    for pair in by_model["none"]:
        if any(pair not in stats for stats in by_model.values()):
            continue  # a sensor one model left without a pose
        rs = [stats[pair] for stats in by_model.values()]
        nees = " / ".join(f"{np.mean(r['nees']):.2f}" for r in rs)
        cover = " / ".join(f"{100 * np.mean(np.asarray(r['nees']) < Q95):.0f}" for r in rs)
        err = ", ".join(f"{rms(r['rot']):.4f} / {rms(r['trans']):.3f}" for r in (rs[0], rs[-1]))
        sig = ", ".join(f"{rms(r['sig_rot']):.4f} / {rms(r['sig_trans']):.3f}" for r in (rs[0], rs[-1]))
        lines.append(f"| {pair[0]}-{pair[1]} | {nees} | {cover} % | {err} | {sig} |")
    print(f"{kind} sensor models (rendered): {time.perf_counter() - t0:.0f} s", flush=True)
    picked = ", ".join(f"{m} {chosen.count(m)}" for m in dict.fromkeys(sorted(chosen)))
    return (
        f"### {kind}\n\n{len(rendered)} rigs x 12 boards; the model chosen: {picked}. All pairs pooled: "
        f"{'; '.join(pooled)}.\n\n" + "\n".join(lines) + "\n"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50, help="observation-level rigs per kind (0: none)")
    ap.add_argument("--verify", type=int, default=50, help="observation-level verify seeds per kind")
    ap.add_argument(
        "--rendered", type=int, default=50, help="at most this many cached captures per kind (0: none)"
    )
    ap.add_argument(
        "--models",
        type=int,
        default=0,
        help="compare the base LiDAR's sensor models on this many cached captures",
    )
    ap.add_argument("--kinds", nargs="*", default=["ring-pinhole", "ring-fisheye", "backpack"])
    ap.add_argument("--write", action="store_true", help=f"write the tables into {DOC.name}")
    a = ap.parse_args()
    for name, on, part in (
        ("observations", a.runs > 0, lambda k: observation_part(k, a.runs, a.verify)),
        ("rendered", a.rendered > 0, lambda k: rendered_part(k, a.rendered)),
        ("models", a.models > 0, lambda k: models_part(k, a.models)),
    ):
        if not on:
            continue
        text = "\n".join(part(kind) for kind in a.kinds)
        print(text, flush=True)
        if a.write:
            write_between(DOC, f"<!-- {name}:begin -->", f"<!-- {name}:end -->", text)


if __name__ == "__main__":
    main()
