"""A simulated rig through the rig's stages, start and joint solve (issue 24): in memory and from its
folders (``rig_observe.observe_rig`` over a ``RigSource``), with the same answers."""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np

from ilcc_graph.datasets import open_source
from ilcc_graph.estimation.rig_solve import solve_rig
from ilcc_graph.init.rig_start import rig_start
from ilcc_graph.run.rig_observe import observe_moment, observe_rig
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.simulate.rig_export import write_rig_set
from ilcc_graph.simulate.rig_spec import backpack_rig, simulate_moments
from ilcc_graph.types import Scan


def _float32(scan: Scan) -> Scan:
    def f(a: np.ndarray) -> np.ndarray:
        return a.astype(np.float32).astype(np.float64)

    return replace(scan, points=f(scan.points), intensity=f(scan.intensity))


def test_backpack_from_memory_and_folders(tmp_path) -> None:  # noqa: ANN001
    spec = backpack_rig(width=1600, n_moments=5, seed=4)
    rig = spec.rig_config()
    sim = list(simulate_moments(spec))
    # the files hold the scans' points and intensities as float32: observe the same values in memory
    f32 = {m.name: {n: _float32(s) for n, s in m.scans.items()} for m in sim}
    mem = [observe_moment(m.name, f32[m.name], m.images, rig) for m in sim]
    write_rig_set(tmp_path / "rig", spec, moments=sim)
    obs = observe_rig(open_source(tmp_path / "rig", rig=True), StageOptions())
    assert [m.name for m in obs.moments] == [m.name for m in mem]
    for a, b in zip(mem, obs.moments, strict=True):
        assert (
            set(a.boards) == set(b.boards) and set(a.corners) == set(b.corners) and a.failures == b.failures
        )
        for s in a.boards:
            assert np.allclose(a.boards[s].T_lidar_board, b.boards[s].T_lidar_board, atol=1e-9)
        for s in a.corners:
            assert np.allclose(a.corners[s].uv, b.corners[s].uv, atol=1e-6)
    assert obs.seen("pano") == [m.name for m in mem if "pano" in m.corners]
    cams = {c: obs.rig.sensor(c).camera for c in obs.rig.cameras}
    start = rig_start(obs.moments, obs.rig.board, obs.rig.lidars, obs.rig.cameras)
    assert not start.unplaced
    sol = solve_rig(
        obs.moments, start, obs.rig.board, obs.rig.lidars, cams, obs.rig.reference, order=rig.names
    )
    assert sol.sensors == ("vlp16", "os1", "pano") and sol.reference == "vlp16"
    truth = spec.T_ref_sensor()
    for a, b in (("vlp16", "os1"), ("vlp16", "pano"), ("os1", "pano")):
        est = sol.relative(a, b)
        xi = gtsam.Pose3(est.T).localCoordinates(gtsam.Pose3(np.linalg.solve(truth[a], truth[b])))
        assert np.degrees(np.linalg.norm(xi[:3])) < 0.1 and 1e3 * np.linalg.norm(xi[3:]) < 3.0, (a, b, xi)
        assert xi @ np.linalg.solve(est.covariance, xi) < 30.0, (a, b)


def test_a_sensor_without_board_and_a_damaged_image(tmp_path) -> None:  # noqa: ANN001
    spec = backpack_rig(width=1600, n_moments=2, seed=5)
    sim = list(simulate_moments(spec))
    out = write_rig_set(tmp_path / "rig", spec, moments=sim)
    bad = next((out / "pano").iterdir())
    bad.write_bytes(b"not an image")
    obs = observe_rig(open_source(out, rig=True))
    m = next(m for m in obs.moments if m.name == bad.stem)
    assert "pano" in m.failures and "pano" in m.damaged and str(bad.name) in m.failures["pano"]
    rig = spec.rig_config()
    blank = observe_moment(
        "x", {"vlp16": sim[0].scans["vlp16"]}, {"pano": np.zeros((800, 1600, 3), np.uint8)}, rig
    )
    assert "pano" in blank.failures and not blank.damaged and "vlp16" in blank.boards
    small = observe_moment("y", {}, {"pano": np.zeros((10, 20, 3), np.uint8)}, rig)
    assert "20x10" in small.failures["pano"] and small.damaged == ("pano",)
