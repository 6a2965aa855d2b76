"""A rig's outputs (issue 24): calibration.yaml, its exports loaded back (ROS launch file, URDF,
Kalibr camchain, JSON), and the prior on every sensor pose in a real GTSAM graph.

The rig is solved from observation-level simulated data (``simulate.rig_observations``): the
outputs' content is what is checked, not the solve (tests/test_rig_solve.py)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import gtsam
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from ilcc_graph.cameras import make_camera
from ilcc_graph.errors import InputError
from ilcc_graph.estimation.selection import AUTO, Selection
from ilcc_graph.exports_rig import export_rig, tf_frames
from ilcc_graph.handoff_rig import add_rig_prior, rig_prior
from ilcc_graph.io.rig_results import is_rig_calibration, read_rig_calibration, write_rig_calibration
from ilcc_graph.run.rig_calibrate import RigResult, solve_observed, to_calibration
from ilcc_graph.run.rig_observe import RigObservation
from ilcc_graph.simulate.rig_observations import observe_spec
from ilcc_graph.simulate.rig_spec import ring_rig


@pytest.fixture(scope="module")
def result() -> RigResult:
    spec = ring_rig("fisheye", width=480, n_moments=12, seed=5)
    return solve_observed(RigObservation(spec.rig_config(), observe_spec(spec)))


def _T(xyz: list[float], R: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, xyz
    return T


def test_calibration_yaml_round_trip(result: RigResult, tmp_path) -> None:  # noqa: ANN001
    cal = to_calibration(result)
    p = write_rig_calibration(tmp_path / "calibration.yaml", cal)
    assert is_rig_calibration(p)
    back = read_rig_calibration(p)
    assert back.sensors == result.sensors == ("lidar", "front", "left", "back", "right")
    assert back.reference == "lidar" and np.array_equal(back.covariance, result.covariance)
    for s in result.sensors:
        assert np.array_equal(back.T_ref_sensor[s], result.T_ref_sensor[s])
    # every pair's relative pose and covariance, as the joint covariance propagates them
    assert len(back.pairs) == 10
    e = result.relative("front", "left")
    T, C = back.pairs[("front", "left")]
    assert np.array_equal(T, e.T) and np.array_equal(C, e.covariance)
    used = back.extra["used"]
    assert used["lidar"] == 12 and all(used[c] >= 2 for c in ("front", "left", "back", "right"))
    assert back.extra["moments"]["0001"]["lidar"] == "used"
    model = Selection.from_dict(back.extra["sensor_model"])  # the base LiDAR's, chosen as the pair's
    assert model == result.solution.selection and model.chosen in AUTO and not model.forced
    assert "T_ref_sensor" not in back.rig["sensors"]["front"]  # the rig file's guesses left out
    bad = tmp_path / "bad.yaml"
    bad.write_text(p.read_text().replace("reference: lidar", "reference: nobody"))
    with pytest.raises(InputError, match="bad.yaml: sensors must"):
        read_rig_calibration(bad)


def test_exports_load_back(result: RigResult) -> None:
    cal = to_calibration(result)
    frames = {(p, c): T for p, c, T in tf_frames(cal)}
    # the tree: root -> body frames, body -> optical; chained, it gives back every T_ref_sensor
    for s in ("front", "left"):
        T = frames[("lidar", s)] @ frames[(s, f"{s}_optical")]
        assert np.allclose(T, result.T_ref_sensor[s], atol=1e-12)

    # ROS launch file: static_transform_publisher args x y z qx qy qz qw parent child
    root = ET.fromstring(export_rig(cal, "ros-tf"))
    nodes = root.findall("node")
    assert len(nodes) == 8
    for n in nodes:
        a = n.attrib["args"].split()
        T = _T([float(v) for v in a[:3]], Rotation.from_quat([float(v) for v in a[3:7]]).as_matrix())
        assert np.allclose(T, frames[(a[7], a[8])], atol=1e-12)

    # URDF: fixed joints, origin xyz and rpy (fixed axes x, y, z)
    urdf = ET.fromstring(export_rig(cal, "urdf"))
    assert {link.attrib["name"] for link in urdf.findall("link")} >= {"lidar", "front", "front_optical"}
    for j in urdf.findall("joint"):
        o = j.find("origin").attrib
        R = Rotation.from_euler("xyz", [float(v) for v in o["rpy"].split()]).as_matrix()
        T = _T([float(v) for v in o["xyz"].split()], R)
        key = (j.find("parent").attrib["link"], j.find("child").attrib["link"])
        assert np.allclose(T, frames[key], atol=1e-12)

    # Kalibr camchain: chained camera-camera transforms and the intrinsics
    chain = yaml.safe_load(export_rig(cal, "kalibr"))
    assert list(chain) == ["cam0", "cam1", "cam2", "cam3"]
    names = ["front", "left", "back", "right"]
    for n in range(1, 4):
        T = np.asarray(chain[f"cam{n}"]["T_cn_cnm1"])
        assert np.allclose(T, result.relative(names[n], names[n - 1]).T, atol=1e-12)
    T = np.asarray(chain["cam0"]["T_cam_lidar"])
    assert np.allclose(T, result.relative("front", "lidar").T, atol=1e-12)
    cam = result.rig.sensor("left").camera
    assert chain["cam1"]["camera_model"] == "pinhole" and chain["cam1"]["distortion_model"] == "equidistant"
    assert np.allclose(chain["cam1"]["intrinsics"], cam.K[[0, 1, 0, 1], [0, 1, 2, 2]])
    assert chain["cam1"]["resolution"] == [cam.width, cam.height]

    # JSON: the joint covariance and the pairs
    doc = json.loads(export_rig(cal, "json"))
    assert np.array_equal(np.asarray(doc["covariance"]), result.covariance)
    assert doc["covariance_order"][6] == "front.rx"
    assert np.allclose(doc["pairs"]["left/back"]["covariance"], result.relative("left", "back").covariance)
    assert make_camera(doc["cameras"]["back"]).to_dict() == result.rig.sensor("back").camera.to_dict()
    with pytest.raises(ValueError, match="unknown rig export format"):
        export_rig(cal, "kitti")


def test_prior_on_every_sensor_in_a_gtsam_graph(result: RigResult, tmp_path) -> None:  # noqa: ANN001
    """One factor with the joint covariance: alone in a graph, the optimum is the stored poses and
    the graph's joint marginal is the stored joint covariance (so its Jacobians are right)."""
    cal = to_calibration(result)
    path = write_rig_calibration(tmp_path / "calibration.yaml", cal)
    keys = {s: gtsam.symbol("S", k) for k, s in enumerate(["front", "left", "back", "right"])}
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    rng = np.random.default_rng(3)
    for s, k in keys.items():  # a start 2 deg / 5 cm away
        initial.insert(
            k, gtsam.Pose3(result.T_ref_sensor[s]).compose(gtsam.Pose3.Expmap(rng.normal(0, 0.03, 6)))
        )
    add_rig_prior(graph, keys, path, initial)
    values = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    for s, k in keys.items():
        assert np.allclose(values.atPose3(k).matrix(), result.T_ref_sensor[s], atol=1e-9)
    m = gtsam.Marginals(graph, values)
    kv = gtsam.KeyVector()
    for k in keys.values():
        kv.append(k)
    J = m.jointMarginalCovariance(kv).fullMatrix()
    assert np.allclose(J, result.joint(list(keys)), rtol=1e-6, atol=1e-16)
    # one sensor: GTSAM's own PriorFactorPose3 with its block
    one = rig_prior({"left": 7}, cal)
    ref = gtsam.PriorFactorPose3(
        7,
        gtsam.Pose3(result.T_ref_sensor["left"]),
        gtsam.noiseModel.Gaussian.Covariance(result.pose("left").covariance),
    )
    v = gtsam.Values()
    v.insert(7, gtsam.Pose3(result.T_ref_sensor["left"]).compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))))
    assert np.isclose(one.error(v), ref.error(v), rtol=1e-9)
    with pytest.raises(ValueError, match="reference"):
        rig_prior({"lidar": 1}, cal)
