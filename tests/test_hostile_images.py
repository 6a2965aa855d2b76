"""Hostile frame files through the command line: an image whose header declares an absurd size (a PNG
with a forged IHDR and a valid CRC, a JPEG with a forged SOF), an image of another size than the
camera's, a broken link in place of an image or a scan. Each costs its frame, named with the file
and the problem, and no such image is decoded; ``--strict`` stops at the first (exit 2).
"""

from __future__ import annotations

import shutil
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

import ilcc_graph.datasets.folder
from ilcc_graph.app import main
from ilcc_graph.errors import InputError
from ilcc_graph.io import read_image
from ilcc_graph.io.images import MAX_PIXELS, image_size


def forged_png(width: int, height: int) -> bytes:
    """A real 8 x 8 PNG whose IHDR declares ``width`` x ``height`` (CRC recomputed: a valid header)."""
    ok, enc = cv2.imencode(".png", np.full((8, 8, 3), 128, np.uint8))
    b = bytearray(enc.tobytes())
    assert ok and b[12:16] == b"IHDR"
    b[16:24] = struct.pack(">II", width, height)
    b[29:33] = struct.pack(">I", zlib.crc32(bytes(b[12:29])))
    return bytes(b)


def forged_jpeg(width: int, height: int) -> bytes:
    """A real 16 x 16 JPEG whose SOF0 segment declares ``width`` x ``height``."""
    ok, enc = cv2.imencode(".jpg", np.full((16, 16, 3), 128, np.uint8))
    b = bytearray(enc.tobytes())
    at = b.index(b"\xff\xc0")  # SOF0: marker, length (2), precision (1), height (2), width (2)
    b[at + 5 : at + 9] = struct.pack(">HH", height, width)
    return bytes(b)


def test_the_forged_headers_are_read_as_declared(tmp_path):
    png, jpg = tmp_path / "a.png", tmp_path / "a.jpg"
    png.write_bytes(forged_png(1234, 567))
    jpg.write_bytes(forged_jpeg(2345, 678))
    assert image_size(png) == (1234, 567) and image_size(jpg) == (2345, 678)
    from PIL import Image

    with Image.open(png) as a, Image.open(jpg) as b:  # an independent reader agrees
        assert a.size == (1234, 567) and b.size == (2345, 678)
    png.write_bytes(forged_png(60000, 60000))
    jpg.write_bytes(forged_jpeg(65000, 65000))
    for p in (png, jpg):
        with pytest.raises(InputError, match=f"{p.name}: the image's header declares") as exc:
            read_image(p)
        assert f"{MAX_PIXELS / 1e6:.0f} Mpx" in str(exc.value)


def test_size_and_read_say_the_same_of_a_bad_file(tmp_path):
    """``image_size`` and ``read_image`` read the header through one function: the same message,
    naming the file, for each problem the header shows."""
    (tmp_path / "dir.png").mkdir()
    (tmp_path / "link.png").symlink_to(tmp_path / "gone.png")
    (tmp_path / "zero.png").write_bytes(forged_png(0, 10))
    (tmp_path / "huge.jpg").write_bytes(forged_jpeg(60000, 60000))
    problems = {
        "missing.png": "image file not found",
        "dir.png": "cannot read image (Is a directory)",
        "link.png": "broken link",
        "zero.png": "the image's header declares 0x10 px (corrupt)",
        "huge.jpg": "the image's header declares 60000x60000 px",
    }
    for name, problem in problems.items():
        said = []
        for fn in (image_size, read_image):
            with pytest.raises(InputError) as exc:
                fn(tmp_path / name)
            said.append(str(exc.value))
        assert said[0] == said[1] and name in said[0] and problem in said[0], said


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """A small simulated panoramic set (7 frames, 1200 x 600 px)."""
    out = tmp_path_factory.mktemp("hostile") / "sim"
    assert main(["simulate", str(out), "--frames", "7", "--seed", "1", "--width", "1200"]) == 0
    return out


@pytest.fixture
def hostile(sim, tmp_path) -> Path:
    """The set with frames 0002-0005 made hostile (0001, 0006, 0007 stay good)."""
    data = tmp_path / "data"
    shutil.copytree(sim, data)
    img = data / "img"
    (img / "0002.png").write_bytes(forged_png(60000, 60000))  # was: DecompressionBombError, exit 1
    (img / "0003.png").write_bytes(forged_png(32000, 32000))  # was: decoded in full, 4 GB
    (img / "0004.png").unlink()
    (img / "0004.jpg").write_bytes(forged_jpeg(16000, 8000))  # under the cap, not the camera's size
    (img / "0005.png").unlink()
    (img / "0005.png").symlink_to(tmp_path / "gone" / "0005.png")  # was: "has no image"
    return data


@pytest.fixture
def decoded(monkeypatch) -> list[str]:
    """The images the folder source decodes (in this process: the runs below use --jobs 1)."""
    seen: list[str] = []
    real = ilcc_graph.datasets.folder.read_image

    def read(path):  # noqa: ANN001, ANN202
        seen.append(Path(path).name)
        return real(path)

    monkeypatch.setattr(ilcc_graph.datasets.folder, "read_image", read)
    return seen


REASONS = {
    "0002": ["img/0002.png", "declares 60000x60000 px", "not decoded"],
    "0003": ["img/0003.png", "declares 32000x32000 px", "not decoded"],
    "0004": ["img/0004.jpg", "16000x8000 px", "camera.width x camera.height"],
    "0005": ["img/0005.png", "a broken link", "gone/0005.png"],
}


def test_hostile_images_cost_their_frames_and_are_never_decoded(hostile, decoded, capsys, caplog):
    out = hostile.parent / "corners"
    with caplog.at_level("WARNING"):
        assert main(["image-corners", str(hostile), "--out", str(out), "--jobs", "1"]) == 0
    # the table wraps its reason column at 80 columns, inside a long path too (where depends on the
    # temporary folder's name): the file's name is looked for with the wrapping taken out
    printed = "".join(capsys.readouterr().out.split())
    for name, said in REASONS.items():
        doc = yaml.safe_load((out / f"{name}.yaml").read_text())
        assert doc["found"] is False and all(s in doc["reason"] for s in said), (name, doc["reason"])
        assert said[0] in printed
    assert {"0002.png", "0003.png", "0004.jpg", "0005.png"}.isdisjoint(decoded)
    assert {"0001.png", "0006.png", "0007.png"} <= set(decoded)
    assert "Traceback" not in capsys.readouterr().err


def test_a_calibration_skips_hostile_frames_with_a_warning(hostile, decoded, capsys, caplog):
    pcd = hostile / "pcd"
    (pcd / "0006.pcd").unlink()
    (pcd / "0006.pcd").symlink_to(hostile / "nowhere.pcd")  # a scan that is a broken link
    out = hostile.parent / "run"
    with caplog.at_level("WARNING"):
        code = main(["calibrate", str(hostile), "--out", str(out), "--jobs", "1", "--no-report"])
    err = capsys.readouterr().err
    assert "internal error" not in err and "Traceback" not in err
    warned = " ".join(r.getMessage() for r in caplog.records)
    for name, said in {**REASONS, "0006": ["pcd/0006.pcd", "a broken link", "nowhere.pcd"]}.items():
        assert said[0] in warned, name
    # 2 good frames are too few to calibrate: exit 3, and failure.yaml gives every frame's reason
    assert code == 3
    frames = {f["frame"]: f["reason"] for f in yaml.safe_load((out / "failure.yaml").read_text())["frames"]}
    assert "declares 60000x60000 px" in frames["0002"] and "a broken link" in frames["0006"]
    assert {"0002.png", "0003.png", "0004.jpg", "0005.png"}.isdisjoint(decoded)


def test_a_calibration_with_one_hostile_frame_uses_the_others(sim, tmp_path, capsys):
    data = tmp_path / "data"
    shutil.copytree(sim, data)
    (data / "img" / "0003.png").write_bytes(forged_png(60000, 60000))
    out = tmp_path / "run"
    assert main(["calibrate", str(data), "--out", str(out), "--jobs", "1", "--no-report"]) == 0
    capsys.readouterr()
    cal = {f["name"]: f for f in yaml.safe_load((out / "calibration.yaml").read_text())["frames"]}
    assert cal["0003"]["damaged"] is True and "declares 60000x60000 px" in cal["0003"]["reason"]
    assert not any(f.get("damaged") for n, f in cal.items() if n != "0003")  # it cost that frame only
    assert sum(f["used"] for f in cal.values()) >= 4
    # --strict stops at it: exit 2 naming the file, nothing written
    strict = tmp_path / "strict"
    assert main(["calibrate", str(data), "--out", str(strict), "--jobs", "1", "--strict"]) == 2
    err = capsys.readouterr().err
    assert "img/0003.png: the image's header declares 60000x60000 px" in err and not strict.exists()


def test_the_size_check_of_the_first_images_reads_headers_only(sim, tmp_path, capsys):
    """Every image forged: the check of the first three images' size names one, exit 2, no bug."""
    data = tmp_path / "data"
    shutil.copytree(sim, data)
    for p in (data / "img").iterdir():
        p.write_bytes(forged_png(9000, 4500))
    assert main(["calibrate", str(data), "--out", str(tmp_path / "run"), "--jobs", "1"]) == 2
    err = capsys.readouterr().err
    assert "img/0001.png: image is 9000x4500 px" in err and "Traceback" not in err
