"""Benchmark of ilcc_graph.init.upnp: global optimality, accuracy, time per call.

1. Optimality: random problems (4-700 points; full-sphere, narrow-cone and planar-board bearings;
   noise 0-2 mrad). The best UPnP candidate's cost is compared with the best of many random-start
   local minimisations of the same cost with scipy (least_squares on the 6-DoF residual, cost
   computed from its definition, independent of UPnP's quartic). Also: how many of the distinct
   local minima scipy found are in UPnP's candidate list.
2. Accuracy vs OpenGV's C++ UPnP (figures measured by the project through its Python binding):
   camera within 0.5 m, depths 1.5-8 m, full-sphere bearings, 0.5 mrad noise; 35 and 700 bearings.
3. Corner order across frames (resolve_half_turns): random multi-frame problems (2-20 frames of a
   6x8 board, panoramic or pinhole geometry, random half turns, LiDAR corners 3 mm / bearings
   0.5 mrad noise), a third of those with 4+ frames carrying one outlier frame.

Usage: nice python3 scripts/bench_upnp.py [--problems 1000] [--trials 300] [--out docs/bench_upnp.md]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ilcc_graph.init.correspondence import resolve_half_turns
from ilcc_graph.init.upnp import object_space_cost, refine_angular, upnp

OPENGV = {35: (0.011, 0.84, 0.35), 700: (0.0025, 0.19, 0.95)}  # deg, mm, ms (medians)


def random_problem(rng: np.random.Generator, n: int, kind: str, noise_rad: float):
    """Points (LiDAR-like frame), noisy unit bearings (camera frame), true R, t."""
    R = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
    t = rng.normal(size=3)
    t *= rng.uniform(0, 0.5) / np.linalg.norm(t)
    if kind == "sphere":
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        X = d * rng.uniform(1.5, 8.0, (n, 1))
    elif kind == "narrow":
        half = np.radians(rng.uniform(5.0, 30.0))
        ang = np.arccos(rng.uniform(np.cos(half), 1.0, n))
        az = rng.uniform(0, 2 * np.pi, n)
        d = np.stack([np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)], 1)
        X = d * rng.uniform(1.5, 8.0, (n, 1))
    else:  # planar board, 0.4-1.2 m, anywhere around the camera, tilted up to 60 deg
        side = rng.uniform(0.4, 1.2)
        uv = rng.uniform(-side / 2, side / 2, (n, 2))
        c = rng.normal(size=3)
        c *= rng.uniform(1.5, 8.0) / np.linalg.norm(c)
        Rb = Rotation.from_rotvec(rng.normal(size=3) * 0.5).as_matrix()
        z = -c / np.linalg.norm(c)
        x = np.cross(z, rng.normal(size=3))
        x /= np.linalg.norm(x)
        Rb = np.stack([x, np.cross(z, x), z], 1) @ Rb
        X = c + uv @ Rb[:, :2].T
    P = (X - t) @ R  # R^T (X - t): points in the LiDAR frame
    F = X / np.linalg.norm(X, axis=1, keepdims=True)
    if noise_rad > 0:
        F = F + rng.normal(size=F.shape) * noise_rad
        F /= np.linalg.norm(F, axis=1, keepdims=True)
    return P, F, R, t


def scipy_minima(P: np.ndarray, F: np.ndarray, rng: np.random.Generator, starts: int):
    """Local minima of the object-space cost from random starts: list of (cost, R)."""
    V = np.eye(3)[None] - F[:, :, None] * F[:, None, :]
    c = P.mean(axis=0)
    Pc = P - c

    def res(x, R0):
        R = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
        X = Pc @ R.T + x[3:]
        return np.einsum("nab,nb->na", V, X).ravel()

    def jac(x, R0):
        # X = Exp(w) R0 p + t: dX/dw = -[Exp(w) R0 p]x J_l(w), dX/dt = I
        w = x[:3]
        th = np.linalg.norm(w)
        K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        if th < 1e-8:
            Jl = np.eye(3) + 0.5 * K
        else:
            Jl = np.eye(3) + (1 - np.cos(th)) / th**2 * K + (th - np.sin(th)) / th**3 * K @ K
        Y = Pc @ (Rotation.from_rotvec(w).as_matrix() @ R0).T
        S = np.zeros((len(Y), 3, 3))
        S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -Y[:, 2], Y[:, 1], -Y[:, 0]
        S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = Y[:, 2], -Y[:, 1], Y[:, 0]
        J = np.concatenate([-(V @ S) @ Jl, V], axis=2)
        return J.reshape(-1, 6)

    out = []
    for _ in range(starts):
        R0 = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
        # start t at its optimum for R0 so that each start is a fair local search
        H = V.sum(0)
        t0 = -np.linalg.solve(H, np.einsum("nab,nb->a", V, Pc @ R0.T))
        sol = least_squares(
            res,
            np.r_[np.zeros(3), t0],
            jac=jac,
            args=(R0,),
            method="lm",
            xtol=1e-15,
            ftol=1e-15,
            gtol=1e-15,
            max_nfev=4000,
        )
        R = Rotation.from_rotvec(sol.x[:3]).as_matrix() @ R0
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = sol.x[3:] - R @ c
        out.append((object_space_cost(T, P, F), R))
    return out


def rot_err_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))


def optimality(n_problems: int, starts: int, seed: int):
    rng = np.random.default_rng(seed)
    kinds = ["sphere", "narrow", "planar"]
    rows = {k: dict(n=0, ok=0, worse=[], found=0, ref_minima=0, times=[], ncand=[]) for k in kinds}
    failures = []
    for i in range(n_problems):
        kind = kinds[i % 3]
        n = int(np.round(np.exp(rng.uniform(np.log(4), np.log(700)))))
        noise = rng.uniform(0, 2e-3)
        P, F, R, t = random_problem(rng, n, kind, noise)
        t0 = time.perf_counter()
        sols = upnp(P, F)
        rows[kind]["times"].append(time.perf_counter() - t0)
        ref = scipy_minima(P, F, rng, starts)
        best_ref = min(c for c, _ in ref)
        scale = float(np.sum((P - P.mean(0)) ** 2))
        tol = 1e-7 * best_ref + 1e-12 * scale
        ours = sols[0].cost
        r = rows[kind]
        r["n"] += 1
        r["ncand"].append(len(sols))
        if ours <= best_ref + tol:
            r["ok"] += 1
        else:
            r["worse"].append((ours - best_ref) / max(best_ref, 1e-300))
            failures.append((i, kind, n, noise, ours, best_ref))
        # recall of distinct scipy minima (cost and rotation match)
        distinct: list[tuple[float, np.ndarray]] = []
        for c, Rr in sorted(ref, key=lambda x: x[0]):
            if all(rot_err_deg(Rr, Rd) > 0.05 for _, Rd in distinct):
                distinct.append((c, Rr))
        for _c, Rr in distinct:
            r["ref_minima"] += 1
            if any(rot_err_deg(Rr, s.T_cam_points[:3, :3]) < 0.05 for s in sols):
                r["found"] += 1
        if (i + 1) % 50 == 0:
            print(f"  {i + 1}/{n_problems} problems", flush=True)
    return rows, failures


def accuracy(trials: int, seed: int):
    rng = np.random.default_rng(seed)
    out = {}
    for n in (35, 700):
        er, et, erf, etf, tm, tmr = [], [], [], [], [], []
        for _ in range(trials):
            P, F, R, t = random_problem(rng, n, "sphere", 0.5e-3)
            t0 = time.perf_counter()
            T = upnp(P, F)[0].T_cam_points
            t1 = time.perf_counter()
            Tr = refine_angular(T, P, F)
            t2 = time.perf_counter()
            tm.append(t1 - t0)
            tmr.append(t2 - t1)
            er.append(rot_err_deg(T[:3, :3], R))
            et.append(1e3 * np.linalg.norm(T[:3, 3] - t))
            erf.append(rot_err_deg(Tr[:3, :3], R))
            etf.append(1e3 * np.linalg.norm(Tr[:3, 3] - t))
        out[n] = dict(
            rot=np.median(er),
            trans=np.median(et),
            ms=1e3 * np.median(tm),
            rot_ref=np.median(erf),
            trans_ref=np.median(etf),
            ms_ref=1e3 * np.median(tmr),
        )
    return out


def order_frames(rng: np.random.Generator, n: int, geometry: str):
    """Simulated frames of a 6x8 board (35 inner corners, half-turn symmetric)."""
    i, j = np.meshgrid(np.arange(5), np.arange(7), indexing="ij")
    corners = np.c_[(j.ravel() + 1) * 0.075, (i.ravel() + 1) * 0.075, np.zeros(35)]
    perm = np.arange(35)[::-1].copy()
    centre = corners.mean(axis=0)
    R = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
    t = rng.uniform(-0.3, 0.3, 3)
    lidar, bearings, flips = [], [], []
    for _ in range(n):
        if geometry == "panoramic":
            d = rng.normal(size=3) * np.array([1.0, 1.0, 0.3])
        else:
            d = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.35, 0.35), 1.0])
        d /= np.linalg.norm(d)
        z = Rotation.from_rotvec(rng.normal(size=3) * 0.4).as_matrix() @ -d
        x = np.cross(rng.normal(size=3), z)
        x /= np.linalg.norm(x)
        X = d * rng.uniform(2.0, 6.0) + (corners - centre) @ np.c_[x, np.cross(z, x), z].T
        P = (X - t) @ R + rng.normal(size=X.shape) * 0.003
        F = X / np.linalg.norm(X, axis=1, keepdims=True) + rng.normal(size=X.shape) * 0.5e-3
        F /= np.linalg.norm(F, axis=1, keepdims=True)
        flip = bool(rng.integers(2))
        lidar.append(P)
        bearings.append(F[perm] if flip else F)
        flips.append(flip)
    return lidar, bearings, perm, flips


def order_study(n_problems: int, seed: int):
    rng = np.random.default_rng(seed)
    sizes = [2, 3, 4, 6, 10, 20]
    rows = {k: dict(problems=0, good=0, wrong=0, good_dropped=0, outliers=0, out_dropped=0, amb=0, times=[])
            for k in sizes}  # fmt: skip
    for p in range(n_problems):
        n = sizes[p % len(sizes)]
        geometry = ("panoramic", "pinhole")[(p // len(sizes)) % 2]
        lidar, bearings, perm, flips = order_frames(rng, n, geometry)
        bad = None
        if n >= 4 and rng.random() < 1 / 3:
            bad = int(rng.integers(n))
            kind = int(rng.integers(3))
            c = lidar[bad].mean(axis=0)
            if kind == 0:  # the LiDAR stage found the board 0.3-0.6 m off
                s = rng.normal(size=3)
                lidar[bad] = lidar[bad] + s / np.linalg.norm(s) * rng.uniform(0.3, 0.6)
            elif kind == 1:  # scrambled image corners
                bearings[bad] = bearings[bad][rng.permutation(35)]
            else:  # the LiDAR board turned by 20-40 degrees
                Rt = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
                ang = np.radians(rng.uniform(20, 40))
                Rt = Rotation.from_rotvec(Rotation.from_matrix(Rt).as_rotvec() / np.linalg.norm(
                    Rotation.from_matrix(Rt).as_rotvec()) * ang).as_matrix()  # fmt: skip
                lidar[bad] = c + (lidar[bad] - c) @ Rt.T
        names = [f"{k:04d}" for k in range(n)]
        t0 = time.perf_counter()
        r = resolve_half_turns(lidar, bearings, perm, names)
        dt = time.perf_counter() - t0
        row = rows[n]
        row["problems"] += 1
        row["times"].append(dt)
        row["amb"] += r.ambiguous is not None
        for k, name in enumerate(names):
            if k == bad:
                row["outliers"] += 1
                row["out_dropped"] += name not in r.flip
            elif name in r.flip:
                row["good"] += 1
                row["wrong"] += r.flip[name] != flips[k]
            else:
                row["good_dropped"] += 1
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", type=int, default=1000)
    ap.add_argument("--starts", type=int, default=30, help="scipy random starts per problem")
    ap.add_argument("--trials", type=int, default=300)
    ap.add_argument("--order-problems", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "bench_upnp.md"
    )
    args = ap.parse_args()

    rows, failures = optimality(args.problems, args.starts, args.seed)
    acc = accuracy(args.trials, args.seed + 1)
    orders = order_study(args.order_problems, args.seed + 2)

    lines = [
        "# UPnP benchmark",
        "",
        f"Produced by `scripts/bench_upnp.py --problems {args.problems} "
        f"--starts {args.starts} --trials {args.trials} --seed {args.seed}` "
        f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load average at the end "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores: times are wall clock).",
        "",
        "## 1. Is the answer the global minimum?",
        "",
        f"Best UPnP candidate's cost vs the best of {args.starts} random-start scipy `least_squares` "
        "minimisations of the same object-space cost (equal: within 1e-7 relative). "
        "Recall: distinct scipy local minima (rotation apart > 0.05 deg) that are in UPnP's list.",
        "",
        "| bearings | problems | answer = best (%) | worse | recall of scipy minima | candidates (mean) "
        "| ms/call median | ms/call p90 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    tot_n = tot_ok = 0
    for k, r in rows.items():
        tot_n += r["n"]
        tot_ok += r["ok"]
        lines.append(
            f"| {k} | {r['n']} | {100 * r['ok'] / max(r['n'], 1):.1f} | {len(r['worse'])} | "
            f"{r['found']}/{r['ref_minima']} | {np.mean(r['ncand']):.2f} | "
            f"{1e3 * np.median(r['times']):.2f} | {1e3 * np.percentile(r['times'], 90):.2f} |"
        )
    lines.append(f"| **all** | {tot_n} | **{100 * tot_ok / max(tot_n, 1):.2f}** | {tot_n - tot_ok} | | | | |")
    if failures:
        lines += ["", "Problems where UPnP's answer was worse than scipy's best:", ""]
        for i, kind, n, noise, ours, ref in failures:
            lines.append(f"- #{i} {kind}, N={n}, noise {1e3 * noise:.2f} mrad: {ours:.6g} vs {ref:.6g}")
    lines += [
        "",
        "## 2. Accuracy (camera within 0.5 m, depths 1.5-8 m, full sphere, 0.5 mrad noise)",
        "",
        f"Medians over {args.trials} problems each. OpenGV: C++ UPnP measured by the project through "
        "its Python binding (figures given in the issue). `+ angular GN`: our `refine_angular` "
        "(Gauss-Newton on the tangent-plane bearing error) after UPnP.",
        "",
        "| N | method | rotation err (deg) | translation err (mm) | time (ms) |",
        "|---|---|---|---|---|",
    ]
    for n, a in acc.items():
        rd, td, ms = OPENGV[n]
        lines.append(f"| {n} | OpenGV UPnP (C++) | {rd} | {td} | {ms} |")
        lines.append(f"| {n} | ilcc_graph upnp | {a['rot']:.4f} | {a['trans']:.3f} | {a['ms']:.2f} |")
        lines.append(
            f"| {n} | ilcc_graph upnp + angular GN | {a['rot_ref']:.4f} | {a['trans_ref']:.3f} | "
            f"{a['ms'] + a['ms_ref']:.2f} |"
        )
    lines += [
        "",
        "## 3. Corner order across frames (`resolve_half_turns`)",
        "",
        f"{args.order_problems} simulated problems: a 6x8 board (35 corners, half-turn symmetric), "
        "panoramic or pinhole geometry (boards 2-6 m), each frame's image order half-turned at random, "
        "LiDAR corners 3 mm and bearings 0.5 mrad noise. With 4+ frames, a third of the problems "
        "carry one outlier frame (LiDAR board 0.3-0.6 m off, scrambled image corners, or LiDAR board "
        "turned 20-40 deg).",
        "",
        "| frames | problems | good frames kept | wrong order | good dropped | outliers dropped "
        "| ambiguous flagged | s/call median |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for n, r in orders.items():
        lines.append(
            f"| {n} | {r['problems']} | {r['good']} | {r['wrong']} | {r['good_dropped']} | "
            f"{r['out_dropped']}/{r['outliers']} | {r['amb']} | {np.median(r['times']):.3f} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.write_text(text)
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
