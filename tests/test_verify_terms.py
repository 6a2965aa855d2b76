"""``verify`` tests a mount's change net of the LiDAR's own range terms (issue 34): calibration.yaml
stores the extrinsic with the chosen model's range terms and their joint covariance
(``sensor_errors.extrinsic_with_lidar_terms``), read back exactly, refused when it is not a
covariance; ``net_of_terms`` removes what a range offset explains from the change, keeps the test's
size (chi-square with 6 dof when nothing changed), stays unbiased for a moved mount, and falls back
to the poses alone, saying so, when the terms themselves changed."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.errors import InputError
from ilcc_graph.estimation.verify import net_of_terms
from ilcc_graph.io import read_calibration
from ilcc_graph.io.stored import read_stored
from ilcc_graph.types import PoseTerms

T0 = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.1, -0.2, 0.3), gtsam.Point3(0.1, -0.3, 0.5)).matrix()


def _joint(rho: float = 0.9) -> np.ndarray:
    """(8, 8): a pose (2 mrad, 3 mm) and an offset and a dark term (8 mm, 1 mm); tz and the offset
    correlated by ``rho``."""
    s = np.array([2e-3, 2e-3, 2e-3, 3e-3, 3e-3, 3e-3, 8e-3, 1e-3])
    R = np.eye(8)
    R[5, 6] = R[6, 5] = rho
    return np.outer(s, s) * R


def _terms(T: np.ndarray, values: np.ndarray, C: np.ndarray) -> PoseTerms:
    return PoseTerms(T, ("offset", "dark"), ("m", "m"), np.asarray(values, dtype=np.float64), C)


def _moved(xi: np.ndarray) -> np.ndarray:
    return T0 @ gtsam.Pose3.Expmap(np.asarray(xi, dtype=np.float64)).matrix()


def test_an_offset_the_solves_share_drops_out_of_the_mount_change() -> None:
    """The second solve's tz and offset both off by what their correlation says: the change net of
    the terms is far smaller than the poses alone say, and its covariance is the conditional one."""
    C = _joint(0.95)
    stored = _terms(T0, [0.02, 0.001], C)
    # the capture's error along the (tz, offset) correlation: +2.9 mm tz with +8 mm offset
    new = _terms(_moved([0, 0, 0, 0, 0, 0.0029]), [0.028, 0.001], C)
    d, Cn, note = net_of_terms(stored, new, alpha=0.05)  # type: ignore[misc]
    S = 2.0 * C
    alone = 0.0029**2 / S[5, 5]
    net = float(d @ np.linalg.solve(Cn, d))
    assert net < 0.2 * alone, (net, alone)
    assert Cn[5, 5] == pytest.approx(S[5, 5] - S[5, 6] ** 2 / S[6, 6], rel=1e-6)
    assert "net of the LiDAR's own range terms" in note and "offset +8.0" in note


def test_unchanged_rigs_give_chi_square_6_and_a_moved_mount_is_found_unbiased() -> None:
    """Draws of two independent solves from their joint covariance: the statistic averages 6 (its
    dof); with the mount moved by ``delta`` (terms unchanged) the net change averages ``delta``."""
    rng = np.random.default_rng(3)
    C = _joint(0.9)
    L = np.linalg.cholesky(C)
    b0 = np.array([0.02, 0.001])
    delta = np.array([0.0, 0.0, 0.002, 0.0, 0.004, 0.006])
    stats, nets = [], []
    for moved in (False, True):
        for _ in range(400):
            e0, e1 = L @ rng.standard_normal(8), L @ rng.standard_normal(8)
            T1 = _moved(delta) if moved else T0
            s = _terms(T0 @ gtsam.Pose3.Expmap(e0[:6]).matrix(), b0 + e0[6:], C)
            n = _terms(T1 @ gtsam.Pose3.Expmap(e1[:6]).matrix(), b0 + e1[6:], C)
            d, Cn, _ = net_of_terms(s, n, alpha=1e-12)  # type: ignore[misc]
            (nets if moved else stats).append(d if moved else float(d @ np.linalg.solve(Cn, d)))
    assert 5.3 < np.mean(stats) < 6.7, np.mean(stats)
    err = np.mean(nets, axis=0) - delta
    assert np.all(np.abs(err) < 4 * np.sqrt(np.diag(Cn)) / np.sqrt(400)), err


def test_terms_that_changed_are_not_taken_as_shared() -> None:
    """An offset 60 mm apart (8 mm sigmas): the terms changed, the poses are compared alone and the
    note says why."""
    C = _joint(0.9)
    d, Cn, note = net_of_terms(_terms(T0, [0.0, 0.0], C), _terms(T0, [0.06, 0.0], C), alpha=0.05)  # type: ignore[misc]
    assert d is None and Cn is None  # the caller compares the poses alone
    assert "terms changed" in note and "tested without them" in note and "offset +60.0" in note
    other = PoseTerms(T0, ("scale",), ("1",), np.zeros(1), np.eye(7) * 1e-6)
    assert net_of_terms(_terms(T0, [0.0, 0.0], C), other, alpha=0.05) is None  # nothing in common


def _data(simulated) -> Path:  # noqa: ANN001
    """A simulated VLP-16 + fisheye set whose LiDAR reads 25 mm long."""
    return simulated("fisheye", "--lidar", "vlp16", "--range-offset-mm", "25", frames=8, seed=5)


@pytest.fixture()
def range_calibration(simulated, calibrated) -> Path:  # noqa: ANN001
    """That set calibrated (the sensor model chosen: one with range terms, the offset being 25 mm)."""
    return calibrated(_data(simulated)) / "calibration.yaml"


def test_calibration_yaml_keeps_the_extrinsic_with_its_terms(range_calibration: Path) -> None:
    """Written by calibrate, read back equal: the extrinsic, the terms, their units and the joint
    covariance, whose pose block is the written covariance's chosen-model part."""
    cal = read_calibration(range_calibration)
    w = cal.with_terms
    assert w is not None and any(t.startswith("offset") for t in w.terms), w.terms
    assert set(w.units) == {"m"} and len(w.values) == len(w.terms) == len(w.covariance) - 6
    assert np.array_equal(w.T, cal.T_cam_lidar)
    doc = yaml.safe_load(range_calibration.read_text(encoding="utf-8"))
    stored = doc["sensor_errors"]["extrinsic_with_lidar_terms"]
    assert np.array_equal(np.array(stored["covariance"]), w.covariance)
    lid = doc["sensor_errors"]["lidar"]["terms"]
    assert 1e3 * w.values[0] == pytest.approx(lid[w.terms[0]]["value_mm"])
    assert np.all(np.linalg.eigvalsh(w.covariance) > 0)


def test_verify_says_it_tests_net_of_the_terms_and_refuses_a_broken_joint(
    range_calibration: Path, simulated, tmp_path: Path  # noqa: ANN001
) -> None:
    """verify of the set against its own calibration: no change, the note in verify.yaml; a stored
    joint covariance that is not one: exit 2 naming the file and the key."""
    data = _data(simulated)
    code = main(["verify", str(range_calibration), str(data), "--out", str(tmp_path / "v"), "--jobs", "1"])
    doc = yaml.safe_load((tmp_path / "v" / "verify.yaml").read_text(encoding="utf-8"))
    assert code in (0, 4), doc["sensors"]["camera"]["reason"]
    assert any("net of the LiDAR's own range terms" in n for n in doc["notes"]), doc["notes"]
    assert doc["sensors"]["camera"]["translation_mm"] < 1e-6
    broken = yaml.safe_load(range_calibration.read_text(encoding="utf-8"))
    C = np.array(broken["sensor_errors"]["extrinsic_with_lidar_terms"]["covariance"])
    C[6, 6] = -C[6, 6]
    broken["sensor_errors"]["extrinsic_with_lidar_terms"]["covariance"] = C.tolist()
    bad = tmp_path / "broken.yaml"
    bad.write_text(yaml.safe_dump(broken), encoding="utf-8")
    with pytest.raises(InputError, match="broken.yaml: sensor_errors.extrinsic_with_lidar_terms.covariance"):
        read_stored(bad)
    assert main(["verify", str(bad), str(data), "--out", str(tmp_path / "v2"), "--jobs", "1"]) == 2
