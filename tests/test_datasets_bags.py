"""ROS bags through the data-source seam, on bags the simulator writes.

One simulated data set as a folder, a ROS 1 bag, a ROS 2 sqlite3 bag and a ROS 2 mcap bag (PNG
CompressedImage) calibrates to the same result; a walk-and-pause bag gives one frame per still pause
(camera cue, and LiDAR cue without images); a static bag keeps every scan up to the cap; pairing
respects the tolerance and falls back to bag time for unsynchronised clocks; CameraInfo reaches the
camera model; bad input names the bag and the problem; ``ilcc-graph calibrate BAG`` works.
"""

from __future__ import annotations

import logging
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from accuracy import NEES_BOUND, pose_nees

from ilcc_graph.app import main
from ilcc_graph.datasets import BagSource, FolderSource, open_source
from ilcc_graph.errors import InputError
from ilcc_graph.io import read_yaml
from ilcc_graph.run.pipeline import run
from ilcc_graph.simulate import RenderOptions, simulate_dataset, simulate_frames, standard_spec, write_bag
from ilcc_graph.simulate.bag import RosMessages, WalkAndPause, simulate_walk

INFO = "sensor_msgs/msg/CameraInfo"


@pytest.fixture(scope="module")
def sets(tmp_path_factory) -> dict:
    """The same six frames as a folder and as three bags."""
    d = tmp_path_factory.mktemp("bags")
    spec = standard_spec(lidar="hdl32", camera="pinhole", width=800, frames=6, seed=5)
    frames = list(simulate_frames(spec))
    return {
        "spec": spec,
        "frames": frames,
        "folder": simulate_dataset(d / "folder", spec),
        "ros1": write_bag(d / "run.bag", spec, frames=frames),
        "sqlite3": write_bag(d / "run_db3", spec, frames=frames, storage="sqlite3"),
        "mcap": write_bag(d / "run_mcap", spec, frames=frames, storage="mcap", image_format="png"),
    }


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> dict:
    """A walk-and-pause recording (three pauses of 1.2 s, moves of 0.6 s, 10 Hz) with and without images."""
    d = tmp_path_factory.mktemp("walk")
    spec = standard_spec(lidar="hdl32", camera="pinhole", width=480, frames=3, seed=2,
                         image=RenderOptions(supersample=1))  # fmt: skip
    timeline = WalkAndPause(pause_s=1.2, move_s=0.6)
    frames = simulate_walk(spec, timeline)
    jpeg = write_bag(d / "walk.bag", spec, timeline=timeline, frames=frames, image_format="jpeg")
    lidar_only = write_bag(d / "lidar.bag", spec, timeline=timeline, frames=frames, image_format="none")
    return {"jpeg": jpeg, "lidar": lidar_only, "truth": read_yaml(d / "walk.ground_truth.yaml")}


def test_folder_and_bags_give_the_same_frames_scans_and_images(sets) -> None:
    folder = FolderSource(sets["folder"])
    ref = folder.frames()
    db3 = sets["sqlite3"] / "run_db3.db3"
    sources = [open_source(sets[k]) for k in ("ros1", "sqlite3", "mcap")]
    sources.append(open_source(db3, config=sets["sqlite3"].parent / "run_db3.yaml"))  # the storage file alone
    sources.append(
        open_source(next(sets["mcap"].glob("*.mcap")), config=sets["mcap"].parent / "run_mcap.yaml")
    )
    for src in sources:
        assert isinstance(src, BagSource)
        refs = src.frames()
        assert [r.name for r in refs] == ["t000000.000", "t000000.100", "t000000.200", "t000000.300",
                                          "t000000.400", "t000000.500"]  # fmt: skip
        assert src.skipped() == []
        src = pickle.loads(pickle.dumps(src))  # as a worker process gets it
        for a, b in zip(ref, refs, strict=True):
            sa, sb = folder.read_scan(a, folder.config()), src.read_scan(b, src.config())
            np.testing.assert_array_equal(sa.points, sb.points)
            np.testing.assert_array_equal(sa.intensity, sb.intensity)
            np.testing.assert_array_equal(sa.ring, sb.ring)
            np.testing.assert_array_equal(folder.read_image(a), src.read_image(b))


def test_folder_and_bags_calibrate_to_the_same_result(sets) -> None:
    results = {k: run([open_source(sets[k])]).calibration for k in ("folder", "ros1", "sqlite3", "mcap")}
    base = results.pop("folder")
    assert sum(f.used for f in base.frames) == 6
    for kind, cal in results.items():
        assert [f.used for f in cal.frames] == [f.used for f in base.frames], kind
        # float32 points and lossless images in both: the same numbers, not just close ones
        np.testing.assert_allclose(cal.T_cam_lidar, base.T_cam_lidar, rtol=0, atol=1e-9, err_msg=kind)
        np.testing.assert_allclose(cal.covariance, base.covariance, rtol=1e-9, atol=1e-15, err_msg=kind)
        assert cal.camera == base.camera


def test_camera_info_reaches_the_camera_model(sets) -> None:
    for kind in ("ros1", "mcap"):
        stem = sets[kind].with_suffix("") if kind == "ros1" else sets[kind]
        assert "camera" not in read_yaml(stem.parent / f"{stem.name}.yaml")  # only CameraInfo has it
        cfg = open_source(sets[kind]).config()
        assert cfg.camera.to_dict() == sets["spec"].camera.to_dict()
        assert cfg.source.endswith(f"{stem.name}.yaml")


def test_walk_and_pause_gives_one_frame_per_pause(walk) -> None:
    truth = walk["truth"]
    for src, kwargs in (
        (open_source(walk["jpeg"]), {}),
        (open_source(walk["lidar"]), {"require_image": False}),
    ):
        refs = src.frames(**kwargs)
        assert len(refs) == len(truth["pauses"]) == 3
        for ref, (first, last) in zip(refs, truth["pauses"], strict=True):
            t, t0, t1 = (float(n[1:]) for n in (ref.name, first, last))
            assert t0 <= t <= t1 and abs(t - 0.5 * (t0 + t1)) <= 0.1, (ref.name, first, last)
            # the frame shows the board where it was held still
            np.testing.assert_array_equal(truth["T_lidar_board"][ref.name], truth["T_lidar_board"][first])
        assert (ref.image is None) == ("require_image" in kwargs)
    # with a longer minimum pause than the recording holds: no pause, every scan up to the cap
    many = open_source(walk["jpeg"], min_pause=2.0, max_frames=7).frames()
    assert len(many) == 7 and many[0].name == "t000000.000"


def test_a_static_recording_keeps_every_scan_up_to_the_cap(tmp_path) -> None:
    spec = standard_spec(lidar="hdl32", camera="pinhole", width=320, frames=1, seed=4,
                         image=RenderOptions(supersample=1))  # fmt: skip
    bag = write_bag(tmp_path / "static.bag", spec, timeline=WalkAndPause(pause_s=1.5), rate_hz=10.0)
    assert len(open_source(bag).frames()) == 15  # no motion: not one pause, every scan
    capped = open_source(bag, max_frames=4).frames()
    assert [r.name for r in capped] == ["t000000.000", "t000000.500", "t000000.900", "t000001.400"]
    assert len(open_source(bag, select="pauses").frames()) == 1


def test_pairing_respects_the_tolerance(sets, tmp_path) -> None:
    spec, frames = sets["spec"], sets["frames"][:5]
    # image stamp minus scan stamp; bag (receive) times would pair frame 1 (latencies 80 / 0 ms)
    delays = [0.01, 0.08, 0.049, 0.051, -0.03]
    bag = write_bag(tmp_path / "sync.bag", spec, frames=frames, rate_hz=2.0, image_delay_s=delays,
                    latency_s=(0.08, 0.0))  # fmt: skip
    src = open_source(bag)  # the bag starts with the first image, 10 ms after the first scan's stamp
    assert [r.name for r in src.frames()] == ["t000000.070", "t000001.070", "t000002.070"]
    assert [n for n, _ in src.skipped()] == ["t000000.570", "t000001.570"]
    assert all("no image within 0.05 s of the scan" in why for _, why in src.skipped())
    assert len(open_source(bag, sync_tolerance=0.1).frames()) == 5


def test_unsynchronised_clocks_fall_back_to_bag_time(sets, tmp_path, caplog) -> None:
    # the camera's clock runs 100 s ahead; receive times are 2 ms apart
    bag = write_bag(tmp_path / "clocks.bag", sets["spec"], frames=sets["frames"][:3], image_delay_s=100.012,
                    latency_s=(0.03, -99.98))  # fmt: skip
    with caplog.at_level(logging.WARNING):
        refs = open_source(bag).frames()
    assert len(refs) == 3 and "pair by bag (receive) time" in caplog.text
    with pytest.raises(
        InputError, match=r"clocks\.bag: no scan has an image within 0\.001 s .*99\.812 s apart"
    ):
        open_source(bag, sync_tolerance=0.001).frames()  # neither clock pairs: say how far apart they are


def _tiny_bag(path: Path, topics: dict[str, list]) -> Path:
    """A ROS 1 bag with the given messages (topic -> [(type, message)]) and a config beside it."""
    from rosbags.rosbag1 import Writer

    m = RosMessages(ros1=True)
    with Writer(path) as w:
        for topic, msgs in topics.items():
            conn = w.add_connection(topic, msgs[0][0], typestore=m.ts)
            for k, (msgtype, msg) in enumerate(msgs):
                w.write(conn, 10**9 * (k + 1), m.serialize(msg, msgtype))
    camera = {"model": "pinhole", "width": 4, "height": 2, "K": [[2, 0, 2], [0, 2, 1], [0, 0, 1]]}
    cfg = {"board": {"squares": [6, 8], "square_size": 0.075}, "lidar": {"model": "hdl32"}, "camera": camera}
    (path.with_suffix(".yaml")).write_text(yaml.safe_dump(cfg))
    return path


def test_bad_input_names_the_bag_and_the_problem(sets, tmp_path) -> None:
    bag = sets["ros1"]
    with pytest.raises(
        InputError, match=r"run\.bag: lidar topic /nope: no such topic; topics: .*/lidar/points"
    ):
        open_source(bag, lidar_topic="/nope").frames()
    with pytest.raises(
        InputError, match=r"image topic /lidar/points: its type is sensor_msgs/msg/PointCloud2"
    ):
        open_source(bag, image_topic="/lidar/points").frames()
    with pytest.raises(InputError, match=r"options of a ROS bag"):
        open_source(sets["folder"], lidar_topic="/x")
    with pytest.raises(InputError, match="sync_tolerance must be > 0"):
        open_source(bag, sync_tolerance=0.0)

    m = RosMessages(ros1=True)
    frame = sets["frames"][0]
    cloud = ("sensor_msgs/msg/PointCloud2", m.cloud(frame, 10**9))
    image = m.image(frame.image[:2, :4].copy(), 10**9, "bgr8")
    two = _tiny_bag(tmp_path / "two.bag", {"/a/points": [cloud], "/b/points": [cloud]})
    with pytest.raises(
        InputError, match=r"two\.bag: several sensor_msgs/msg/PointCloud2 topic .*--lidar-topic"
    ):
        open_source(two).frames()
    assert open_source(two, lidar_topic="/b/points", select="all").frames(require_image=False)
    image.encoding = "yuv422"
    odd = _tiny_bag(
        tmp_path / "odd.bag", {"/points": [cloud], "/cam/image": [("sensor_msgs/msg/Image", image)]}
    )
    with pytest.raises(InputError, match=r"odd\.bag:/cam/image: image encoding 'yuv422' is not supported"):
        open_source(odd).frames()

    info = m.camera_info(standard_spec(camera="pinhole", width=320, frames=1), 10**9)
    info.K[:] = 0.0  # an uncalibrated camera
    uncal = _tiny_bag(tmp_path / "uncal.bag", {"/points": [cloud], "/cam/camera_info": [(INFO, info)]})
    cfg = read_yaml(uncal.with_suffix(".yaml"))
    del cfg["camera"]
    (tmp_path / "uncal.yaml").write_text(yaml.safe_dump(cfg))
    with pytest.raises(
        InputError, match=r"uncal\.yaml: camera\.K = .*comes from .*uncal\.bag:/cam/camera_info"
    ):
        open_source(uncal).config()

    nowhere = tmp_path / "alone"
    nowhere.mkdir()
    shutil.copy(bag, nowhere / "x.bag")
    with pytest.raises(InputError, match=r"x\.bag: no config for this bag \(looked for .*x\.yaml"):
        open_source(nowhere / "x.bag").config()

    for kind, target in (("ros1", bag), ("sqlite3", sets["sqlite3"]), ("mcap", sets["mcap"])):
        broken = tmp_path / f"broken-{kind}"
        if target.is_dir():
            shutil.copytree(target, broken)
            store = next(p for p in broken.iterdir() if p.suffix in (".db3", ".mcap"))
        else:
            broken = broken.with_suffix(".bag")
            store = Path(shutil.copy(target, broken))
        store.write_bytes(store.read_bytes()[: store.stat().st_size // 3])
        with pytest.raises(InputError, match=rf"broken-{kind}.*not a readable ROS bag"):
            open_source(broken, config=sets["folder"] / "config.yaml").frames()


def _copy_bag(src: Path, dst: Path, change: dict[int, object], topic: str = "/camera/image_raw") -> Path:
    """A copy of the ROS 1 bag ``src`` (and its config) with the k-th message (0-based) of the topics
    starting with ``topic`` altered by ``change[k](message)``; every other message as it was."""
    from rosbags.rosbag1 import Reader, Writer

    m = RosMessages(ros1=True)
    with Reader(src) as r, Writer(dst) as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, typestore=m.ts) for c in r.connections}
        k = 0
        for c, t, raw in r.messages():
            if c.topic.startswith(topic):
                if k in change:
                    msg = m.ts.deserialize_ros1(raw, c.msgtype)
                    change[k](msg)  # type: ignore[operator]
                    raw = m.serialize(msg, c.msgtype)
                k += 1
            w.write(conns[c.id], t, raw)
    shutil.copy(src.with_suffix(".yaml"), dst.with_suffix(".yaml"))
    return dst


def test_a_damaged_bag_image_costs_its_frame_unread(sets, tmp_path) -> None:
    """As an image file's: a bag's image message is checked before it is decoded, against its own data
    (truncated) and the camera's size; the frame is skipped with the bag, topic and time named (strict:
    InputError), the others are used; the still-pause survey leaves the damaged message out."""
    from ilcc_graph.run.observe import observe
    from ilcc_graph.run.stages import StageOptions
    from ilcc_graph.simulate.frames import SimFrame

    frames = list(sets["frames"])
    f2 = frames[2]
    frames[2] = SimFrame(f2.name, f2.scan, np.ascontiguousarray(f2.image[:300, :400]), f2.T_lidar_board)
    odd = write_bag(tmp_path / "odd.bag", sets["spec"], frames=frames)  # the simulator's, image 2 smaller

    def truncate(msg) -> None:  # noqa: ANN001 - a sensor_msgs/Image
        msg.data = msg.data[: len(msg.data) // 2].copy()

    bag = _copy_bag(odd, tmp_path / "damaged.bag", {4: truncate})
    src = open_source(bag)
    assert len(src.frames()) == 6  # the survey did not stop at the damaged message
    obs = observe(src, StageOptions(jobs=1))
    why = {f.name: f.reason or "" for f in obs.frames if not f.used}
    assert set(why) == {"t000000.200", "t000000.400"}, why
    w, h = sets["spec"].camera.width, sets["spec"].camera.height
    t2, t4 = (src.frames()[i].image[1] for i in (2, 4))
    assert (
        f"damaged file: {bag}:/camera/image_raw@t000000.200 (bag time {t2} ns): image is 400x300 px, "
        f"but the camera in" in why["t000000.200"]
    )
    assert (
        f"damaged file: {bag}:/camera/image_raw@t000000.400 (bag time {t4} ns): {w * h * 3 // 2} data "
        f"bytes do not hold a {w} x {h} bgr8 image"
        in why["t000000.400"]
        and "damaged or truncated message" in why["t000000.400"]
    )
    with pytest.raises(InputError, match=r"damaged\.bag:/camera/image_raw@t000000\.200 .*image is 400x300"):
        observe(open_source(bag), StageOptions(jobs=1, strict=True))
    # a compressed image whose header declares an absurd size is refused before it is decoded
    png = write_bag(tmp_path / "png.bag", sets["spec"], frames=sets["frames"], image_format="png")

    def forge(msg) -> None:  # noqa: ANN001 - a sensor_msgs/CompressedImage (PNG)
        data = msg.data.copy()
        data[16:24] = np.frombuffer((60000).to_bytes(4, "big") * 2, np.uint8)
        msg.data = data

    forged = open_source(_copy_bag(png, tmp_path / "forged.bag", {1: forge}))
    ref = forged.frames()[1]
    for read in (forged.header_size, forged.read_image, forged.image_size):
        with pytest.raises(InputError, match=r"forged\.bag:/camera/image_raw/compressed@t000000\.100 "
                           r"\(bag time \d+ ns\): the image's header declares 60000x60000 px"):  # fmt: skip
            read(ref)
    assert forged.header_size(forged.frames()[0]) == (w, h)


def test_a_truncated_cloud_costs_its_frame_not_the_bag(sets, walk, tmp_path) -> None:
    """A PointCloud2 whose data are cut short (a recording stopped mid-write) is left out of the survey
    (its sweep time, the LiDAR's motion measure) and costs only its own frame, skipped with the bag,
    topic, time and the problem named; the other frames are used."""
    from ilcc_graph.run.observe import observe
    from ilcc_graph.run.stages import StageOptions

    def cut(msg) -> None:  # noqa: ANN001 - a sensor_msgs/PointCloud2
        msg.data = msg.data[: len(msg.data) // 2].copy()

    def timed_and_cut(msg) -> None:  # noqa: ANN001 - a per-point time field (Ouster, Hesai), then cut
        msg.fields = [*msg.fields, type(msg.fields[0])(name="t", offset=24, datatype=6, count=1)]
        cut(msg)

    bag = _copy_bag(sets["ros1"], tmp_path / "cut.bag", {3: timed_and_cut}, topic="/lidar/points")
    src = open_source(bag)
    assert len(src.frames()) == 6  # the survey did not stop at the damaged cloud
    obs = observe(src, StageOptions(jobs=1))
    why = {f.name: f.reason or "" for f in obs.frames if not f.used}
    assert set(why) == {"t000000.300"}, why
    t3 = src.frames()[3].scan[1]
    assert f"damaged file: {bag}:/lidar/points@t000000.300 (bag time {t3} ns): " in why["t000000.300"]
    assert "data bytes do not hold 1 x" in why["t000000.300"]
    # a LiDAR-only bag measures motion on the clouds: a cut one is no motion sample, the pauses still found
    whole = open_source(walk["lidar"]).frames(require_image=False)
    cuts = {k: cut for k in (4, 5)}
    lidar = open_source(_copy_bag(walk["lidar"], tmp_path / "cut-walk.bag", cuts, topic="/lidar/points"))
    assert [f.name for f in lidar.frames(require_image=False)] == [f.name for f in whole]


def test_cli_calibrates_a_bag(sets, tmp_path) -> None:
    out = tmp_path / "out"
    argv = ["calibrate", str(sets["ros1"]), "--out", str(out), "--no-report", "--jobs", "1",
            "--sync-tolerance", "0.03", "--lidar-topic", "/lidar/points"]  # fmt: skip
    assert main(argv) == 0
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    assert [f["name"] for f in cal["frames"]][:2] == ["t000000.000", "t000000.100"]
    assert all(f["used"] for f in cal["frames"]) and cal["camera"]["model"] == "pinhole"
    # as accurate as it says: within its covariance of the truth the folder of the same frames holds
    truth = yaml.safe_load((sets["folder"] / "ground_truth.yaml").read_text())["T_cam_lidar"]
    assert pose_nees(cal["T_cam_lidar"], cal["covariance"], truth) < NEES_BOUND
    assert main(["calibrate", str(sets["ros1"]), "--out", str(tmp_path / "o2"), "--image-topic", "/no"]) == 2
