"""Shared test fixtures: only what several test modules need."""

from __future__ import annotations

import fcntl
import hashlib
import os
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

# One BLAS thread in the test processes too, as ``ilcc-graph`` sets for itself before numpy loads
# (app.main): the tests that call ``main`` in-process would otherwise run OpenBLAS's threads, which
# spin against the other test worker on a two-core machine (the whole suite on two cores, with
# HEAVY_FIRST below: 40.7 CPU minutes and 24:20 before, 29.1 and 18:19 after, 2026-12-07). numpy is
# not loaded yet when pytest imports this file.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "acfr-vlp16-fisheye"


#: the heaviest test files first (their seconds in a run of 2026-12-07, session 58, with the stage
#: cache: 157 .. 17; test_types.py's mypy takes about 50 s without its cache, as on a fresh checkout):
#: pytest-xdist's ``--dist loadfile`` hands the files out in collection order, so a heavy file
#: collected last would run alone at the end while the other worker idles. Only the order changes; a
#: file not named keeps its place after these.
HEAVY_FIRST = (
    "test_doors_agree.py", "test_verify_capture.py", "test_live.py", "test_cli_rig_presets.py",
    "test_rig_strategy.py", "test_types.py", "test_cli_honesty.py", "test_cli_export.py",
    "test_selection.py", "test_doors_outline.py", "test_datasets_bags.py", "test_modes.py",
    "test_rig_commands.py", "test_cli_flags.py", "test_stage_cache.py", "test_image.py",
    "test_lidar_real_sensors.py", "test_cli_honesty_lidars.py", "test_cli_effects.py",
    "test_cli_disagreement.py", "test_moved_board.py", "test_rig_solve.py", "test_faults.py",
    "test_no_print.py", "test_image_whole.py", "test_lidars.py", "test_faults_signals.py",
    "test_incremental_stop.py", "test_wrong_margin.py", "test_demo.py", "test_cli_watch.py",
    "test_import_first.py", "test_output_folders.py", "test_cli.py", "test_observe_colour.py",
    "test_closed_stdout.py", "test_intrinsics_core.py", "test_lidar_detection.py", "test_summary.py",
    "test_lidar_ringless.py",
)  # fmt: skip


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Collect the files of ``HEAVY_FIRST`` first, in its order (a stable sort: each file's tests
    keep theirs)."""
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture(scope="session", autouse=True)
def stage_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One folder of stage results for the whole test run (``--stage-cache`` through
    ``$ILCC_GRAPH_STAGE_CACHE``, which the command line and the processes it starts read), shared by
    the pytest-xdist workers: a scan or image that several tests observe with the same settings is
    observed once (about a fifth of the suite's CPU time, 2026-12-07). Fresh for every test run, so
    every result in it was computed by the code under test. Tests of the stages themselves (a signal
    while the workers run) take it out of their environment."""
    from ilcc_graph.app.arguments import CACHE_VARIABLE

    base = tmp_path_factory.getbasetemp()
    folder = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "stage-cache"
    folder.mkdir(exist_ok=True)
    os.environ[CACHE_VARIABLE] = str(folder)
    return folder


@pytest.fixture(scope="session")
def acfr_data() -> Path:
    """The recorded VLP-16 + fisheye set that ships in ../shared; skip where it is absent."""
    if not (SHARED_DATA / "config.yaml").is_file():
        pytest.skip(f"recorded data set not found at {SHARED_DATA} (only in the project's own workspace)")
    return SHARED_DATA


def _shared_set(name: str) -> Path:
    path = SHARED_DATA.parent / name
    if not (path / "config.yaml").is_file():
        pytest.skip(f"recorded data set not found at {path} (only in the project's own workspace)")
    return path


@pytest.fixture(scope="session")
def acfr_os1_fisheye() -> Path:
    """The recorded Ouster OS1-64 + fisheye set (11 frames) in ../shared; skip where it is absent."""
    return _shared_set("acfr-os1-fisheye")


@pytest.fixture(scope="session")
def acfr_os1_pinhole() -> Path:
    """The recorded Ouster + pinhole set (6 frames) in ../shared; skip where it is absent."""
    return _shared_set("acfr-os1-pinhole")


@pytest.fixture
def readonly_dir(tmp_path) -> Path:
    """A folder nobody can write into: a read-only tmpfs as root (permission bits do not stop root)."""
    d = tmp_path / "ro"
    d.mkdir()
    if os.geteuid() != 0:
        d.chmod(0o555)
        yield d
        d.chmod(0o755)
        return
    if subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(d)], capture_output=True
    ).returncode:
        pytest.skip("cannot mount a read-only tmpfs here")
    yield d
    subprocess.run(["umount", str(d)], check=False)


def _made_once(tmp_path_factory: pytest.TempPathFactory, key: tuple, name: str,
               make: Callable[[Path], int]) -> Path:  # fmt: skip
    """``<folder>/name`` made by ``make(<folder>/name)`` (an exit code, 0 for success) once per test
    run and ``key``, whichever process asks first: under pytest-xdist the workers share the run's
    temporary root, and a worker that asks while another makes it waits on a lock and reuses it
    (a small simulated set and its calibration were made by both workers before)."""
    base = tmp_path_factory.getbasetemp()
    root = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "made-once"
    root.mkdir(exist_ok=True)
    tag = hashlib.sha1(repr(key).encode()).hexdigest()[:16]
    folder = root / tag
    with open(root / f"{tag}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not (folder / ".made").is_file():
            if folder.exists():
                shutil.rmtree(folder)  # ours: a making that failed part-way in another test
            folder.mkdir()
            assert make(folder / name) == 0, f"{key} was not made"
            (folder / ".made").touch()
    return folder / name


#: image width of the small simulated sets per camera kind (a panorama needs more pixels per board)
SMALL_WIDTH = {"equirectangular": 1200}


@pytest.fixture(scope="session")
def simulated(tmp_path_factory):  # noqa: ANN201 - a factory
    """``simulated(camera="equirectangular", *flags, frames=5, seed=1, width=None)``: a small data set
    written by ``ilcc-graph simulate`` (HDL-32E unless ``--lidar`` is among the flags; 640 px wide,
    1200 for a panorama), made once per test run and arguments (``_made_once``: one
    worker makes it, the other reuses it)."""
    from ilcc_graph.app import main

    made: dict[tuple, Path] = {}

    def make(camera: str = "equirectangular", *flags: str, frames: int = 5, seed: int = 1,
             width: int | None = None) -> Path:  # fmt: skip
        width = width or SMALL_WIDTH.get(camera, 640)
        key = (camera, flags, frames, seed, width)
        if key not in made:
            args = ["--camera", camera, "--frames", str(frames), "--seed", str(seed), "--width", str(width),
                    *flags]  # fmt: skip
            made[key] = _made_once(
                tmp_path_factory, ("simulated", key), f"{camera}-{seed}",
                lambda out: main(["simulate", str(out), *args]),
            )  # fmt: skip
        return made[key]

    return make


@pytest.fixture(scope="session")
def calibrated(tmp_path_factory):  # noqa: ANN201 - a factory
    """``calibrated(data, *flags, report=False)``: the output folder of ``ilcc-graph calibrate DATA
    --jobs 1 *flags`` (``--no-report`` unless ``report``; ``data`` a folder or a list of them), run
    once per test run and arguments (``_made_once``)."""
    from ilcc_graph.app import main

    made: dict[tuple, Path] = {}

    def run(data: Path | list[Path], *flags: str, report: bool = False) -> Path:
        datas = [str(d) for d in (data if isinstance(data, list) else [data])]
        key = (tuple(datas), flags, report)
        if key not in made:
            tail = ["--jobs", "1", *flags] + ([] if report else ["--no-report"])
            made[key] = _made_once(
                tmp_path_factory, ("calibrated", key), "out",
                lambda out: main(["calibrate", *datas, "--out", str(out), *tail]),
            )  # fmt: skip
        return made[key]

    return run
