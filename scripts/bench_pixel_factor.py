"""Accuracy of the camera intrinsics Jacobians and of the pixel factor (factors/pixel.py).

1. Every lens model's analytic ``d uv / d theta`` against central differences of
   ``with_intrinsics(theta).project`` over random valid cameras (tests/test_camera_intrinsics.py's
   strategies) and points imaged inside the picture.
2. Pixel vs bearing factors at fixed intrinsics (tests/test_factors_pixel.py's views: 8 boards of
   35 corners, correlated pixel covariances of ~0.3 px, board priors 0.01 rad / 10 mm): distance
   of the optima in sigmas, covariance agreement, chi-square.
3. Intrinsics as a variable (10 views, stated intrinsics drawn around the truth from their prior):
   extrinsic and intrinsics NEES, recovered intrinsics in posterior sigmas, sigma shrinkage.

Run: ``nice python3 scripts/bench_pixel_factor.py [--runs 100] [--cameras 200] [--write]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gtsam
import numpy as np
from scipy.stats import chi2

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import test_camera_intrinsics as cams  # noqa: E402
import test_factors_pixel as px  # noqa: E402
from camera_checks import intrinsics_jacobian_errors  # noqa: E402
from gtsam.symbol_shorthand import B, X  # noqa: E402
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from factors import FrameBearingFactor, FramePixelFactor, tangent_bases  # noqa: E402
from ilcc_graph.cameras import camera_kinds  # noqa: E402
from ilcc_graph.simulate import default_camera, default_T_cam_lidar  # noqa: E402

DOC = ROOT / "docs" / "bench_pixel_factor.md"
LENS_KINDS = [k for k in camera_kinds() if default_camera(k).intrinsic_names]  # a panorama has none
RECOVERY = {
    "fisheye": [0.005, 0.002, 0.001, 0.0005],
    "pinhole": [0.01, 0.005, 5e-4, 5e-4, 0.002],
}


def _jacobian_errors(strategy, max_deg: float, n_cameras: int) -> tuple[dict, dict]:
    rel: dict[str, float] = {}
    absolute: dict[str, float] = {}

    @settings(max_examples=n_cameras, deadline=None, database=None, derandomize=True)
    @given(strategy, st.integers(0, 2**31 - 1))
    def run(cam, seed):
        p = cams.imaged_points(cam, seed, max_deg=max_deg)
        err = intrinsics_jacobian_errors(cam, p)
        scale = np.abs(cam.project_with_intrinsics_jacobian(p)[2]).max(axis=(0, 1))
        for n, e, s in zip(cam.intrinsic_names, err, scale, strict=True):
            rel[n], absolute[n] = max(rel.get(n, 0.0), e / s), max(absolute.get(n, 0.0), e)

    run()
    return rel, absolute


def jacobian_table(n_cameras: int) -> str:
    rows = [
        f"Largest |analytic - central difference| of d uv / d theta_j over {n_cameras} random cameras per "
        "model (about 60 points each), relative to the column's largest entry; absolute (px per unit of "
        "theta_j) in brackets.",
        "",
        "| model | parameter: relative (absolute px) |",
        "|---|---|",
    ]
    models = [
        ("pinhole", cams.pinholes(), 50.0),
        ("fisheye", cams.fisheyes(), 95.0),
        ("double_sphere", cams.double_spheres(), 95.0),
        ("unified", cams.unifieds(), 85.0),
    ]
    for name, strategy, max_deg in models:
        rel, absolute = _jacobian_errors(strategy, max_deg, n_cameras)
        cells = ", ".join(f"{n} {rel[n]:.1e} ({absolute[n]:.1e})" for n in rel)
        rows.append(f"| {name} | {cells} |")
        print(rows[-1], flush=True)
    return "\n".join(rows)


def comparison_table(runs: int) -> str:
    rows = [
        f"Pixel vs bearing factors at fixed (true) intrinsics, {runs} seeds per model: the largest (median) "
        "Mahalanobis distance of the two optima of T_cam_lidar in the pixel graph's sigmas, the largest "
        "|1 - eigenvalue| of one covariance whitened by the other, the largest relative chi-square "
        "difference.",
        "",
        "| model | optima apart, max (median) sigma | covariance, max abs(1 - eig) "
        "| chi-square, max rel. diff |",
        "|---|---|---|---|",
    ]
    for kind in LENS_KINDS:
        cam = default_camera(kind, 1280)
        T_cl = gtsam.Pose3(default_T_cam_lidar(cam))
        dist, eig, c2 = [], [], []
        for seed in range(runs):
            rng = np.random.default_rng(seed)
            g_px, g_b, values = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph(), gtsam.Values()
            values.insert(X(0), T_cl.retract(rng.normal(0, 0.02, 6)))
            for i, T_cb in enumerate(px.board_views(cam, rng, 8)):
                measured, prior = px._board_prior(rng, i, T_cl.inverse().compose(gtsam.Pose3(T_cb)))
                values.insert(B(i), measured)
                cov = px.random_cov_px(rng, 35, 0.3)
                uv = px.sample_px(rng, cam.project(px.P_BOARD @ T_cb[:3, :3].T + T_cb[:3, 3]), cov)
                b = cam.bearing(uv)
                theta = cam.intrinsics()
                g_px.add(prior)
                g_px.add(
                    FramePixelFactor(
                        X(0), B(i), None, px.P_BOARD, uv, cov, px.projection(cam), theta
                    ).factor()
                )
                cov_t = cam.bearing_tangent_cov(b, cov, tangent_bases(b))
                g_b.add(prior)
                g_b.add(FrameBearingFactor(X(0), B(i), px.P_BOARD, b, cov_t).factor())
            r_px, r_b = px._lm(g_px, values), px._lm(g_b, values)
            C_px = gtsam.Marginals(g_px, r_px).marginalCovariance(X(0))
            C_b = gtsam.Marginals(g_b, r_b).marginalCovariance(X(0))
            d = r_px.atPose3(X(0)).localCoordinates(r_b.atPose3(X(0)))
            dist.append(float(np.sqrt(d @ np.linalg.solve(C_px, d))))
            L = np.linalg.cholesky(np.linalg.inv(C_px))
            eig.append(float(np.abs(np.linalg.eigvalsh(L.T @ C_b @ L) - 1).max()))
            c2.append(abs(g_px.error(r_px) / g_b.error(r_b) - 1))
        rows.append(f"| {kind} | {max(dist):.1e} ({np.median(dist):.1e}) | {max(eig):.1e} | {max(c2):.1e} |")
        print(rows[-1], flush=True)
    return "\n".join(rows)


def recovery_table(runs: int) -> str:
    rows = [
        f"Intrinsics as a variable, {runs} seeds per model (10 views; stated intrinsics = truth + N(0, prior "
        "sigma^2): 0.5 % on f, 3 px on c, the coefficients' sigmas listed). NEES of T_cam_lidar (6 dof) and "
        "of the intrinsics (n dof), their 99.8 % bands for the mean; per parameter: prior sigma, RMS "
        "recovered error / posterior sigma, posterior / prior sigma, RMS error in prior sigmas stated -> "
        "recovered.",
        "",
        "| model | extrinsic NEES (band) | intrinsics NEES (band) | max abs(err) / sigma |",
        "|---|---|---|---|",
    ]
    details = []
    for kind, sigma_dist in RECOVERY.items():
        out = [px._recovery(kind, seed, sigma_dist) for seed in range(runs)]
        nees, nees_t = np.array([r[0] for r in out]), np.array([r[1] for r in out])
        z, z0, shrink = (np.array([r[k] for r in out]) for k in (2, 3, 4))
        n = z.shape[1]
        band = chi2.ppf([0.001, 0.999], 6 * runs) / runs
        band_t = chi2.ppf([0.001, 0.999], n * runs) / runs
        rows.append(
            f"| {kind} | {nees.mean():.2f} ({band[0]:.2f}-{band[1]:.2f}) | {nees_t.mean():.2f} "
            f"({band_t[0]:.2f}-{band_t[1]:.2f}) | {np.abs(z).max():.2f} |"
        )
        print(rows[-1], flush=True)
        cam = default_camera(kind, 1280)
        prior = np.r_[0.005 * cam.intrinsics()[:2], 3.0, 3.0, sigma_dist]
        details += [
            "",
            f"| {kind} | prior sigma | RMS err / post. sigma | post. / prior sigma "
            "| RMS err (prior sigmas) |",
            "|---|---|---|---|---|",
        ]
        rms_z, rms_0 = np.sqrt((z**2).mean(axis=0)), np.sqrt((z0**2).mean(axis=0))
        rms_1 = np.sqrt(((z * shrink) ** 2).mean(axis=0))
        for j, name in enumerate(cam.intrinsic_names):
            details.append(
                f"| {name} | {prior[j]:.3g} | {rms_z[j]:.2f} | {shrink[:, j].mean():.2f} "
                f"| {rms_0[j]:.2f} -> {rms_1[j]:.2f} |"
            )
    return "\n".join(rows + details)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100, help="seeds of the recovery study")
    parser.add_argument("--comparisons", type=int, default=10, help="seeds of the pixel-vs-bearing study")
    parser.add_argument("--cameras", type=int, default=200, help="random cameras per model (Jacobians)")
    parser.add_argument("--write", action="store_true", help=f"write {DOC.relative_to(ROOT)}")
    args = parser.parse_args()
    parts = [
        "# The pixel factor and the intrinsics Jacobians (scripts/bench_pixel_factor.py)",
        "## 1. Camera intrinsics Jacobians",
        jacobian_table(args.cameras),
        "## 2. Pixel vs bearing factor at fixed intrinsics",
        comparison_table(args.comparisons),
        "## 3. Intrinsics as a variable with a prior",
        recovery_table(args.runs),
    ]
    text = "\n\n".join(parts) + "\n"
    print(text)
    if args.write:
        DOC.write_text(text, encoding="utf-8")
        print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
