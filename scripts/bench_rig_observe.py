"""The rig benchmark's observations (issue 24), made once and cached: simulated rigs through the
rig's stages (``rig_observe.observe_moment``), so that ``scripts/bench_rig.py`` can solve variants
cheaply.

Per rig kind (``KINDS``) and seed: ``cal-<seed>`` a calibration capture (``n_moments`` boards);
for ``verify`` seeds: ``ver-<seed>`` a 5-board capture of the unchanged rig, ``rot-<seed>`` the same
capture with one sensor (not the reference; cycled by seed) turned by 0.25 deg about a random axis,
``trans-<seed>`` shifted by 10 mm in a random direction. A moved capture has the same boards and,
for every other sensor, the same bytes as the unchanged one (``simulate.rig_spec``), so only the moved
sensor is observed again. Each cache file holds the moments' results, the true ``T_ref_sensor``, the
moved mount and the rig's config. Cache: ``~/.cache/ilcc_graph/bench_rig/<kind>/`` (deletable).

Run: ``nice -n 10 python3 scripts/bench_rig_observe.py [--runs 50] [--verify 50] [--kinds ...]``
(one process; about 2 h for the defaults on the shared machine).
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ilcc_graph.run.rig_observe import observe_moment  # noqa: E402
from ilcc_graph.simulate.rig_spec import Mount, RigSpec, backpack_rig, ring_rig, simulate_moments  # noqa: E402

CACHE = Path.home() / ".cache" / "ilcc_graph" / "bench_rig"
VERIFY_MOMENTS = 5
ROTATION_DEG, TRANSLATION_MM = 0.25, 10.0


def _ring(camera: str, verify_views: tuple[tuple[str, ...], ...]):  # noqa: ANN202
    def make(seed: int, verify: bool = False) -> RigSpec:
        spec = ring_rig(camera, width=480, n_moments=VERIFY_MOMENTS if verify else 12, seed=seed)
        if verify:  # every camera sees a board of the short capture
            spec = spec.with_(views=tuple((*v, "lidar") for v in verify_views))
        return spec

    return make


def _backpack(seed: int, verify: bool = False) -> RigSpec:
    return backpack_rig(width=2400, n_moments=VERIFY_MOMENTS if verify else 12, seed=seed)


KINDS = {
    "ring-pinhole": _ring("pinhole", (("front",), ("left",), ("back",), ("right",), ("front",))),
    "ring-fisheye": _ring(
        "fisheye", (("front", "left"), ("left", "back"), ("back",), ("right",), ("front",))
    ),
    "backpack": _backpack,
}


def path(kind: str, what: str, seed: int) -> Path:
    return CACHE / kind / f"{what}-{seed:04d}.pkl"


def _observe(spec: RigSpec, only: str | None = None) -> list:
    rig = spec.rig_config()
    out = []
    for m in simulate_moments(spec):
        scans = {k: v for k, v in m.scans.items() if only in (None, k)}
        images = {k: v for k, v in m.images.items() if only in (None, k)}
        out.append(observe_moment(m.name, scans, images, rig))
    return out


def _save(p: Path, spec: RigSpec, moments: list) -> None:
    p.parent.mkdir(parents=True, exist_ok=True)
    data = {"moments": moments, "truth": spec.T_ref_sensor(), "moved": spec.moved, "rig": spec.rig_config()}
    tmp = p.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps(data))
    tmp.replace(p)


def moved_mount(spec: RigSpec, seed: int, what: str) -> Mount:
    """The moved sensor (the non-reference sensors in turn) and a random direction of the change."""
    others = [n for n in spec.names if n != spec.reference]
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(3)
    u /= np.linalg.norm(u)
    sensor = others[seed % len(others)]
    if what == "rot":
        return Mount(sensor, rotation_deg=tuple(float(x) for x in ROTATION_DEG * u))
    return Mount(sensor, translation_mm=tuple(float(x) for x in TRANSLATION_MM * u))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--verify", type=int, default=50)
    ap.add_argument("--kinds", nargs="*", default=list(KINDS))
    a = ap.parse_args()
    for kind in a.kinds:
        make = KINDS[kind]
        jobs = [("cal", s) for s in range(1, a.runs + 1)] + [
            ("ver", 1000 + s) for s in range(1, a.verify + 1)
        ]
        for what, seed in jobs:
            t0 = time.perf_counter()
            if what == "cal":
                if not path(kind, "cal", seed).exists():
                    spec = make(seed)
                    _save(path(kind, "cal", seed), spec, _observe(spec))
            else:
                spec = make(seed, verify=True)
                if not path(kind, "ver", seed).exists():
                    _save(path(kind, "ver", seed), spec, _observe(spec))
                base = pickle.loads(path(kind, "ver", seed).read_bytes())["moments"]
                for var in ("rot", "trans"):
                    p = path(kind, var, seed)
                    if p.exists():
                        continue
                    moved = spec.with_(moved=moved_mount(spec, seed, var))
                    own = _observe(moved, only=moved.moved.sensor)  # type: ignore[union-attr]
                    _save(
                        p, moved, [_merge(b, o, moved.moved.sensor) for b, o in zip(base, own, strict=True)]
                    )  # type: ignore[union-attr]
            print(f"{kind} {what}-{seed}: {time.perf_counter() - t0:.1f} s", flush=True)


def _merge(base, own, sensor: str):  # noqa: ANN001, ANN202 - MomentResult
    """The unchanged capture's results with ``sensor``'s replaced by the moved capture's."""
    from ilcc_graph.types import MomentResult

    def keep(d: dict) -> dict:
        return {k: v for k, v in d.items() if k != sensor}

    return MomentResult(
        base.name,
        {**keep(base.boards), **own.boards},
        {**keep(base.corners), **own.corners},
        {**keep(base.failures), **own.failures},
    )


if __name__ == "__main__":
    main()
