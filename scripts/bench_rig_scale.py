"""Cost that grows with the work, for a rig (issue 37): ``ilcc-graph calibrate`` of a simulated rig of
six sensors (two LiDARs, four fisheyes) over 12 and 50 moments: wall time, the machine's CPU time,
peak resident memory of the command and all its processes, and how right the answer is.

The rig is the ``ring-fisheye`` preset (an HDL-32E, the reference, and four 800 px fisheyes at 90 deg
steps) with a VLP-16 15 cm below the HDL-32E turned 45 deg (off its drawn mount by a known small
rotation); every board is seen by both LiDARs and by the cameras the preset's views name. Each set is
simulated once into ``--cache`` (``simulate.rig_export.write_rig_set``), then calibrated ``--repeats``
times in its own process: ``python -m ilcc_graph.app calibrate RIG --out OUT --jobs 2 --no-report``.

    nice python scripts/bench_rig_scale.py [--moments 12,50] [--repeats 1] [--write]  # docs/bench_speed.md
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
from bench_speed import ROOT, replace_section, run_measured

from ilcc_graph.io.rig_results import read_rig_calibration
from ilcc_graph.io.rig_truth import read_rig_ground_truth
from ilcc_graph.simulate.rig_export import write_rig_set
from ilcc_graph.simulate.rig_spec import RigSensorSpec, RigSpec, mount, ring_rig

HEADING = "\n## Cost that grows with the work: a rig of six sensors\n"


def six_sensors(n_moments: int, seed: int = 0) -> RigSpec:
    """The ring of four fisheyes around an HDL-32E, with a VLP-16 below it (module docstring)."""
    ring = ring_rig("fisheye", width=800, n_moments=n_moments, seed=seed)
    xyz, ypr = (0.0, 0.0, -0.15), (45.0, 0.0, 0.0)
    T, drawn = mount(xyz, ypr, np.eye(3), (0.5, -0.8, 1.0)), mount(xyz, ypr, np.eye(3))
    vlp16 = RigSensorSpec("vlp16", T, lidar="vlp16", nominal=drawn)
    views = tuple((*v, "vlp16") for v in ring.views)
    return dataclasses.replace(ring, sensors=(*ring.sensors, vlp16), views=views)


def make_set(n: int, cache: Path) -> Path:
    """The ``n``-moment set, simulated once into ``cache``."""
    data = cache / f"rig6-{n}"
    if not (data / "rig_ground_truth.yaml").is_file():
        shutil.rmtree(data, ignore_errors=True)
        write_rig_set(data, six_sensors(n))
    return data


def errors(out: Path, data: Path) -> tuple[float, float, int]:
    """(largest rotation error deg, largest translation error mm, sensors posed) of the answer."""
    cal = read_rig_calibration(out / "calibration.yaml")
    truth = read_rig_ground_truth(data / "rig_ground_truth.yaml")
    rot, trans = 0.0, 0.0
    for name, T in cal.T_ref_sensor.items():
        D = np.linalg.solve(truth.T_ref_sensor[name], T)
        angle = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
        rot, trans = max(rot, float(angle)), max(trans, 1e3 * float(np.linalg.norm(D[:3, 3])))
    return rot, trans, len(cal.T_ref_sensor)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--moments", default="12,50")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "ilcc_bench_rig_scale")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args(argv)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    rows = []
    for n in (int(x) for x in args.moments.split(",")):
        data = make_set(n, args.cache)
        for _ in range(args.repeats):
            out = args.cache / "out"
            shutil.rmtree(out, ignore_errors=True)
            cmd = [sys.executable, "-m", "ilcc_graph.app", "calibrate", str(data), "--out", str(out),
                   "--jobs", "2", "--no-report"]  # fmt: skip
            p, wall, cpu, peak = run_measured(cmd, args.cache, env)
            if p.returncode not in (0, 3):
                raise RuntimeError(f"{cmd} failed ({p.returncode}):\n{p.stderr[-2000:]}")
            rot, trans, posed = errors(out, data)
            rows.append((n, wall, cpu, peak, p.returncode, posed, rot, trans))
            print(rows[-1], flush=True)
    lines = [
        "| moments | wall s | wall s per moment | CPU s | peak MB | exit | sensors posed "
        "| largest error deg / mm |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for n, wall, cpu, peak, rc, posed, rot, trans in rows:
        lines.append(f"| {n} | {wall:.1f} | {wall / n:.2f} | {cpu:.1f} | {peak:.0f} | {rc} | {posed} / 6 | "
                     f"{rot:.3f} / {trans:.1f} |")  # fmt: skip
    load = os.getloadavg()
    text = (
        HEADING + "\n"
        f"`nice python scripts/bench_rig_scale.py --moments {args.moments} --repeats {args.repeats}` "
        "(issue 37). " + __doc__.split("\n\n")[1].replace("\n", " ") + "\n\n" + "\n".join(lines) + "\n\n"
        f"Machine: {os.cpu_count()} cores; load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} "
        "(1 / 5 / 15 min) at the end.\n"
    )
    print(text)
    if args.write:
        replace_section(HEADING, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
