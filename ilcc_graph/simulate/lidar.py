"""LiDAR scans by ray casting every beam of a spinning multi-beam model, or a scanline-free pattern.

One scan: the head turns clockwise seen from above (azimuth ``atan2(y, x)`` decreasing), firing all
beams at each of ``round(360 / horizontal_resolution_deg)`` steps from a random start phase. Points
are in scan order (firing after firing, beams ascending within a firing); lost returns are
omitted, as a driver does. Ranges 0.4-100 m. A scanline-free model (``LidarModel.ringless``, e.g.
``livox-mid70``) fires along its rosette (simulate/rosette.py) for ``spec.integration_time_s`` from a
random start time, one laser (beam 0 for the per-beam systematics); its scans have no ring field.

Measurement model (all geometric sigmas times ``spec.noise_scale``):

- on the board's printed face: the paper's baseline, Gaussian offsets with sigmas
  ``board_noise_sigma_m`` (1.6, 1.6, 10 mm) along the board's x, y and normal;
- elsewhere: range noise along the beam with the model's ``range_sigma_m``;
- or, with ``spec.range_noise_m``, range noise of that sigma along the beam on every surface (the
  board too; not scaled by ``noise_scale``);
- intensity: the printed colour averaged over the beam's footprint (``lidars.footprint.FOOTPRINT``,
  an even cover of a disc of diameter ``beam_aperture_m + beam_divergence_rad * range``) projected onto the
  board, so returns straddling a colour edge blend smoothly, mapped linearly between
  ``intensity_black`` and ``intensity_white``, times ``0.85 + 0.15 cos(incidence)``, plus Gaussian
  noise whose sigma goes from ``intensity_sigma_black`` to ``intensity_sigma_white``; rounded to
  integers in [0, 255].
  Other surfaces have fixed reflectivities (wall 40, floor 20, ceiling 45, person 25, pole 8,
  board back 15) with the same incidence factor and the white-level noise;
- systematics (:class:`~ilcc_graph.simulate.spec.Systematics`), each along the beam: a constant
  bias per beam, an extra range on black print ``dark_range_offset_m * (1 - colour)``, a global
  ``range_offset_m``; dropped returns with probability ``dropout`` (``dropout_black`` on black print);
  a relative intensity gain per beam (``beam_intensity_gain_sigma``); the board's returns from a
  random plane off its print, per frame (``board_plane_sigma``, off by default).

The intensity field (``spec.intensity_field``): ``"print"`` as above; ``"invisible"``: the board's
print reads as white everywhere (a print the LiDAR cannot see; no dark range offset, no extra
dropout on black); ``"zero"``: every value 0; ``"none"``: no intensity field (x y z only, as
Open3D's legacy clouds write); ``"ring"``: the ring value as the file writes it
(0 = lowest beam for ``"plain"``, the hardware laser id for ``"velodyne-csv"``, the row, 0 = top,
for ``"ouster"``). ``spec.ring_field = False`` leaves the ring field out.

Sensor formats (``spec.sensor_format``), how a real driver writes the same returns:

- ``"plain"``: as above (ring 0 = lowest beam, intensity 0-255, lost returns omitted).
- ``"ouster"``: an Ouster-like organised scan: ``HEIGHT = n_beams`` rows, ring 0 = the TOP beam,
  ``WIDTH = 360 / horizontal_resolution_deg`` columns (1024 or 2048), row-major, (0, 0, 0) with
  intensity 0 where a pixel has no return (``Scan.columns`` = WIDTH); intensity is a raw signal
  count: reflectivity level / 255 * 6000 * min(1, (2 m / range)^2) plus noise of sigma
  ``2 sqrt(signal) + 5``, so the board's black/white step depends on range (~100-1000 at 3 m).
- ``"velodyne-csv"``: ring is the hardware ``laser_id`` of VeloView's numbering (interleaved on
  the HDL-32E and VLP-16, ``lidars.LASER_ID_ELEVATIONS_DEG``); written as ILCC's CSV.

Returns where a footprint straddles the board's outline: the centre ray decides (a sharp edge), or
with ``Systematics.edge_returns`` the board, what lies behind or a mixed return between the two
(simulate/edges.py). Not modelled: multiple returns, the board's thickness, motion during the sweep.

Every random draw has its own stream and is drawn for every beam whatever the switches, so
turning one effect on or off leaves the others' numbers unchanged.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..lidars import LASER_ID_ELEVATIONS_DEG, LidarModel
from ..types import Scan
from .edges import SURF_EDGE, edge_returns, footprint_points
from .placements import PURPOSE_FRAME, PURPOSE_UNIT, frame_rng
from .rosette import rosette_directions, rosette_for
from .scene import (
    SURF_BOARD,
    SURF_BOARD_BACK,
    SURF_CEILING,
    SURF_GROUND,
    SURF_PERSON,
    SURF_POLE,
    SURF_WALL,
    Scene,
    cast_rays,
)
from .spec import SimulationSpec

__all__ = ["simulate_scan", "beam_biases", "beam_gains", "MIN_RANGE_M", "MAX_RANGE_M"]

MIN_RANGE_M, MAX_RANGE_M = 0.4, 100.0
_REFLECTIVITY = {
    SURF_WALL: 40.0,
    SURF_GROUND: 20.0,
    SURF_CEILING: 45.0,
    SURF_PERSON: 25.0,
    SURF_POLE: 8.0,
    SURF_BOARD_BACK: 15.0,
    SURF_EDGE: 30.0,
}


def beam_biases(spec: SimulationSpec) -> np.ndarray:
    """(n_beams,) constant range bias of each beam, metres (one draw per data set)."""
    z = frame_rng(spec.units_seed, PURPOSE_UNIT, 0).standard_normal(spec.lidar_model.n_beams)
    return spec.systematics.beam_bias_sigma_m * z


def beam_gains(spec: SimulationSpec) -> np.ndarray:
    """(n_beams,) relative intensity gain of each beam, around 1 (one draw per data set)."""
    z = frame_rng(spec.units_seed, PURPOSE_UNIT, 2).standard_normal(spec.lidar_model.n_beams)
    return np.maximum(1.0 + spec.systematics.beam_intensity_gain_sigma * z, 0.1)


def _beam_directions(model: LidarModel, phase: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (n_az * n_beams, 3) in firing order and their rings."""
    n_az = int(round(360.0 / model.horizontal_resolution_deg))
    az = phase - np.arange(n_az) * (2 * np.pi / n_az)
    el = model.vertical_angles_rad
    ce, se = np.cos(el), np.sin(el)
    d = np.empty((n_az, el.size, 3))
    d[..., 0] = np.cos(az)[:, None] * ce
    d[..., 1] = np.sin(az)[:, None] * ce
    d[..., 2] = se
    ring = np.tile(np.arange(el.size, dtype=np.int32), n_az)
    return d.reshape(-1, 3), ring


def _footprint_colour(scene: Scene, d: np.ndarray, xy: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Mean printed colour over each beam's footprint (radius (N,), m) on the board (NaN-free where
    ``xy`` is on it)."""
    board, T = scene.placed_board()
    q = footprint_points(d @ T[:3, :3], xy, radius)
    c = board.colour_at(q.reshape(-1, 2)).reshape(q.shape[:2])
    ok = np.isfinite(c)
    total, count = np.where(ok, c, 0.0).sum(axis=0), ok.sum(axis=0)
    return total / np.maximum(count, 1)


def simulate_scan(
    spec: SimulationSpec,
    scene: Scene,
    frame: int,
    biases: np.ndarray | None = None,
    T_scene_lidar: np.ndarray | None = None,
) -> Scan:
    """One scan of ``scene`` from the LiDAR origin; random streams keyed by (seed, frame).

    T_scene_lidar: (4, 4) the LiDAR's pose in the scene's frame (a rig's second LiDAR); None: the
    scene is in the LiDAR's frame. Returns a :class:`Scan` with points (N, 3) LiDAR frame,
    intensity (N,), ring (N,) int32.
    """
    model, sy = spec.lidar_model, spec.systematics
    streams = [frame_rng(spec.seed, PURPOSE_FRAME, frame, 1, k) for k in range(4)]
    phase = streams[0].uniform(0.0, 2 * np.pi)
    if model.ringless:  # the start time from the same draw: 0 .. 1000 s into the pattern
        d = rosette_directions(rosette_for(model), 1000.0 * phase / (2 * np.pi), spec.integration_time_s)
        ring = np.zeros(len(d), np.int32)
    else:
        d, ring = _beam_directions(model, phase)
    n = len(d)
    if T_scene_lidar is not None:  # cast in the scene's frame from the LiDAR's origin
        d = d @ T_scene_lidar[:3, :3].T
    origin = np.zeros(3) if T_scene_lidar is None else T_scene_lidar[:3, 3]
    hits = cast_rays(scene, origin, d)
    if sy.edge_returns:
        hits = edge_returns(scene, origin, d, hits, (spec.beam_aperture_m, model.beam_divergence_rad))
    t = hits.t
    board = hits.surface == SURF_BOARD
    # draw everything for every beam so the switches do not shift each other's numbers
    z_geo = streams[1].standard_normal((n, 3))
    z_int = streams[2].standard_normal(n)
    u_drop = streams[3].random(n)

    colour = np.ones(n)
    if board.any() and spec.intensity_field != "invisible":  # an invisible print reads as white
        radius = 0.5 * (spec.beam_aperture_m + model.beam_divergence_rad * t[board])
        colour[board] = _footprint_colour(scene, d[board], hits.board_xy[board], radius)
    cos_inc = np.abs(np.einsum("ij,ij->i", d, hits.normal))

    # geometry: true point plus noise
    p = d * np.where(np.isfinite(t), t, 0.0)[:, None]
    s = spec.noise_scale
    if spec.range_noise_m is not None:  # every return along its beam, as a real LiDAR's
        p += d * (spec.range_noise_m * z_geo[:, 2])[:, None]
    else:
        if board.any():
            R = scene.placed_board()[1][:3, :3]
            p[board] += (z_geo[board] * (s * np.asarray(spec.board_noise_sigma_m))) @ R.T
        other = ~board
        p[other] += d[other] * (s * model.range_sigma_m * z_geo[other, 2])[:, None]
    # systematics along the beam
    b = beam_biases(spec) if biases is None else biases
    extra = b[ring] + sy.range_offset_m + np.where(board, sy.dark_range_offset_m * (1.0 - colour), 0.0)
    so, st = sy.board_plane_sigma
    if board.any() and (so > 0 or st > 0):  # the board's returns from a face off its print
        z = frame_rng(spec.seed, PURPOSE_FRAME, frame, 1, 5).standard_normal(3)
        delta, alpha, beta = z * np.array([so, st, st])
        extent = scene.placed_board()[0].extent()
        xy = hits.board_xy[board] - np.array([np.mean(extent[:2]), np.mean(extent[2:])])
        height = delta + alpha * xy[:, 0] + beta * xy[:, 1]
        extra[board] -= height / np.maximum(cos_inc[board], 0.05)
    p += d * extra[:, None]
    if T_scene_lidar is not None:  # offsets from the origin, back into the LiDAR's frame
        p = p @ T_scene_lidar[:3, :3]

    # intensity
    level = np.zeros(n)
    sig = np.full(n, spec.intensity_sigma_white)
    for surf, refl in _REFLECTIVITY.items():
        level[hits.surface == surf] = refl
    level[board] = spec.intensity_black + colour[board] * (spec.intensity_white - spec.intensity_black)
    sig[board] = spec.intensity_sigma_black + colour[board] * (
        spec.intensity_sigma_white - spec.intensity_sigma_black
    )
    gain = beam_gains(spec)[ring]
    intensity = np.clip(np.rint(gain * level * (0.85 + 0.15 * cos_inc) + sig * z_int), 0, 255)

    p_drop = np.where(board, sy.dropout + (sy.dropout_black - sy.dropout) * (1.0 - colour), sy.dropout)
    keep = np.isfinite(t) & (t >= MIN_RANGE_M) & (t <= MAX_RANGE_M) & (u_drop >= p_drop)
    if spec.sensor_format == "ouster":
        scan = _ouster_scan(spec, frame, p, gain * level * (0.85 + 0.15 * cos_inc), ring, keep)
    else:
        scan = _written_scan(spec, p, intensity, ring, keep)
    return replace(scan, has_intensity=False) if spec.intensity_field == "none" else scan


def _ouster_scan(
    spec: SimulationSpec, frame: int, p: np.ndarray, lit: np.ndarray, ring: np.ndarray, keep: np.ndarray
) -> Scan:
    """An Ouster's organised scan: its signal field from each return's lit level ``lit`` (gain x
    reflectivity x incidence) falling with range, with shot noise; ``keep``: the returns it gives."""
    model, n = spec.lidar_model, len(p)
    r = np.linalg.norm(p, axis=1)
    signal = lit / 255.0 * 6000.0 * np.minimum(1.0, (2.0 / np.maximum(r, 1e-3)) ** 2)
    z_sig = frame_rng(spec.seed, PURPOSE_FRAME, frame, 1, 4).standard_normal(n)
    raw = np.clip(np.rint(signal + (2.0 * np.sqrt(signal) + 5.0) * z_sig), 0, 65535)
    rows = model.n_beams - 1 - ring  # the organised row: 0 = top beam
    scan = _organised(model, p, _field(spec, raw, rows), keep)
    return scan if spec.ring_field else replace(scan, ring=None)


def _written_scan(
    spec: SimulationSpec, p: np.ndarray, intensity: np.ndarray, ring: np.ndarray, keep: np.ndarray
) -> Scan:
    """The returns ``keep`` as the sensor's file gives them: its intensity field, and its ring
    numbers (a Velodyne CSV's laser ids) where it has any."""
    model = spec.lidar_model
    if model.ringless:
        return Scan(
            points=p[keep], intensity=_field(spec, intensity, ring)[keep], ring=None, source="simulated"
        )
    out_ring = ring
    if spec.sensor_format == "velodyne-csv":
        out_ring = laser_ids(model)[ring]
    return Scan(
        points=p[keep],
        intensity=_field(spec, intensity, out_ring)[keep],
        ring=out_ring[keep].astype(np.int32) if spec.ring_field else None,
        source="simulated",
    )


def _field(spec: SimulationSpec, intensity: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """The intensity field as ``spec.intensity_field`` says: the intensity, zeros or the file's ring value."""
    if spec.intensity_field in ("zero", "none"):
        return np.zeros_like(intensity)
    if spec.intensity_field == "ring":
        return np.asarray(ring, dtype=intensity.dtype)
    return intensity


def laser_ids(model: LidarModel) -> np.ndarray:
    """(n_beams,) the hardware laser id (VeloView numbering) of each beam, lowest beam first."""
    ids = LASER_ID_ELEVATIONS_DEG.get(model.name)
    if ids is None or ids.size != model.n_beams:
        raise ValueError(
            f"no hardware laser numbering known for lidar {model.name!r} ({model.n_beams} beams)"
        )
    # beam k (ascending table) is the laser whose nominal elevation is nearest table[k]
    return np.argmin(np.abs(model.vertical_angles_deg[:, None] - ids[None, :]), axis=1).astype(np.int32)


def _organised(model: LidarModel, p: np.ndarray, intensity: np.ndarray, keep: np.ndarray) -> Scan:
    """Firing-order returns as an Ouster-like organised cloud: rows top beam first, (0, 0, 0) where lost."""
    n_b = model.n_beams
    n_az = p.shape[0] // n_b
    pts = np.where(keep[:, None], p, 0.0).reshape(n_az, n_b, 3).transpose(1, 0, 2)[::-1].reshape(-1, 3)
    inten = np.where(keep, intensity, 0.0).reshape(n_az, n_b).T[::-1].reshape(-1)
    ring = np.repeat(np.arange(n_b, dtype=np.int32), n_az)  # row index: 0 = top beam
    return Scan(points=pts, intensity=inten, ring=ring, source="simulated", columns=n_az)
