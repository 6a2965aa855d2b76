"""Calibrate two disjoint halves of a data set's frames and test whether they agree.

With no ground truth (recorded data), this is the check that the reported covariances are honest:
the two estimates are independent, so their difference d (Pose3 tangent, interface.md convention)
should satisfy d^T (C_a + C_b)^-1 d ~ chi-square(6) (95 % below 12.59).

    python scripts/split_halves.py ../shared/data/acfr-vlp16-fisheye [--out docs/split_halves_acfr.md]
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import gtsam
import numpy as np
from scipy.stats import chi2

from ilcc_graph.datasets import open_source
from ilcc_graph.io import atomic_write
from ilcc_graph.run.observe import observe
from ilcc_graph.run.pipeline import solve_observed
from ilcc_graph.run.stages import StageOptions


def agreement(T_a: np.ndarray, C_a: np.ndarray, T_b: np.ndarray, C_b: np.ndarray) -> tuple[np.ndarray, float]:
    """d = Logmap(T_a^-1 T_b) and its Mahalanobis distance under C_a + C_b (first order)."""
    d = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(T_a).between(gtsam.Pose3(T_b))))
    # C_b lives in T_b's tangent; carry it to T_a's through the adjoint of T_a^-1 T_b
    Ad = gtsam.Pose3(T_a).between(gtsam.Pose3(T_b)).AdjointMap()
    C = C_a + Ad @ C_b @ Ad.T
    return d, float(d @ np.linalg.solve(C, d))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("--out", help="markdown file for the table")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s: %(message)s")
    data = Path(args.data)
    t0 = time.perf_counter()
    obs = observe(open_source(data), StageOptions(jobs=args.jobs))
    config, observed = obs.config, obs.frames
    halves = {"odd positions": observed[0::2], "even positions": observed[1::2]}
    rows, est = [], {}
    for name, part in halves.items():
        cal = solve_observed(part, config)
        est[name] = cal
        s = np.sqrt(np.diag(cal.covariance))
        used = [f.name for f in cal.frames if f.used]
        rows.append(
            f"| {name} | {len(used)} of {len(part)} | "
            + " | ".join(f"{v:.4f}" for v in np.degrees(s[:3]))
            + " | "
            + " | ".join(f"{v:.2f}" for v in 1e3 * s[3:])
            + f" | {cal.diagnostics.get('variance_component_board', 1.0):.2f} / "
            f"{cal.diagnostics.get('variance_component_bearing', 1.0):.2f} |"
        )
    a, b = est.values()
    d, m2 = agreement(a.T_cam_lidar, a.covariance, b.T_cam_lidar, b.covariance)
    p = float(chi2.sf(m2, 6))
    lines = [
        f"# Two disjoint halves of `{data.name}`",
        "",
        f"`python scripts/split_halves.py {args.data}` "
        f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {time.perf_counter() - t0:.0f} s).",
        "",
        "| half | frames used | sigma rx deg | ry | rz | sigma tx mm | ty | tz | var. comp. board/bearing |",
        "|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        "Difference of the halves (T_a^-1 T_b, Pose3 tangent): rotation "
        + ", ".join(f"{v:+.4f}" for v in np.degrees(d[:3]))
        + " deg; translation "
        + ", ".join(f"{v:+.2f}" for v in 1e3 * d[3:])
        + " mm.",
        "",
        f"Mahalanobis distance squared under C_a + C_b: **{m2:.2f}** (chi-square, 6 dof: p = {p:.3f}; "
        "95 % of honest pairs fall below 12.59).",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        atomic_write(Path(args.out), text)


if __name__ == "__main__":
    main()
