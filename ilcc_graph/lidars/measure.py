"""Beam tables measured from a scan, rings renumbered onto a table, and tables compared.

A spinning LiDAR's returns carry their beam's elevation ``atan2(z, hypot(x, y))`` (LiDAR frame,
x forward, y left, z up), so a scan describes its sensor:

- with a ring field (any numbering: Ouster's ring 0 at the top, Velodyne's interleaved hardware
  ``laser_id``), each distinct ring value is one beam at the median elevation of its returns;
- an organised cloud (PCD ``HEIGHT > 1``) is read with ring = row (io/pcd.py), the same case;
- otherwise the elevations cluster around the beams: sorted elevations of the farther returns
  are cut where two neighbours are more than a gap apart; the gap is the smallest of 0.04 ..
  0.15 deg from which on the number of clusters stays the same over three steps. The elevations
  are taken from the height ``h`` (-8 .. +8 cm) that makes their histogram sharpest (least
  entropy in 0.02 deg bins), in every case: the beams' origin need not be the points' origin
  (Ouster: ~36 mm), and the table is then the one a calibration file would list.

A scan without ring field whose elevations form no clusters at all (``scanline_free``: the sorted
elevations' gaps are those of a continuum, not a few wide gaps between beams) comes from a
scanline-free pattern (Livox): it is described by a ``pattern="non-repetitive"`` model (method
``"no scanlines"``) holding its elevation range and the mean angular spacing of its returns.

The azimuth step is the median step between successive returns of one beam (single steps only),
snapped to 360 / WIDTH for an organised cloud. Medians use returns beyond 1 m where there are
enough: an Ouster's beams leave from ~15.8 mm off the axis, which biases the elevation seen from
the sensor origin by ``elevation * 0.0158 / range`` (0.1 deg for a +20 deg beam at 3 m).

Cropped scans (a region cut out of each scan, organised or not): ``coverage_deg`` is the azimuth
window the returns cover (360 less the widest empty sector; below ``CROPPED_BELOW_DEG``: cropped).
An organised cloud cut to a window holds WIDTH columns of the window, not of a turn: its step is not
snapped to 360 / WIDTH. A cropped scan's ring field shows only the beams that cross its region, all
at about one range (where the beams' origin height and an elevation offset look alike): a named
table with at least as many beams is kept with its azimuth step (``choose_model``), and the stage
maps each cropped scan's rings onto that scan's own beams (``cropped_table``). An ``intensity``
field that is the ring number (``intensity_ring``: whole numbers, each value one beam, beams in the
order of their values) is the ring field of a scan that has none.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError
from ..types import Scan
from .scan_rings import CROPPED_BELOW_DEG, azimuth_coverage_deg, with_intensity_ring
from .scan_rings import elevation_deg as _elevation_deg
from .scan_rings import far_mask as _far
from .scan_rings import group_medians as _group_medians
from .scan_rings import sharpest_origin_height as _sharpest_origin_height
from .tables import LidarModel

__all__ = [
    "MeasuredBeams", "measure_beams", "beam_index", "table_difference", "choose_model", "scanline_free",
    "cropped_table",
]  # fmt: skip


@dataclass(frozen=True, eq=False)
class MeasuredBeams:
    """The beam table a scan shows.

    model: the measured :class:`LidarModel` (name ``measured``), elevations ascending.
    ring_values: (n,) the file's ring value of each beam (ascending elevation), or None when the
        beams were found by clustering elevations.
    method: ``"ring field"``, ``"organised rows"``, ``"intensity as ring"``, ``"elevation clusters"``
        or ``"no scanlines"``.
    coverage_deg: the azimuth window the returns cover (deg; < ``CROPPED_BELOW_DEG``: a cropped scan).
    """

    model: LidarModel
    ring_values: np.ndarray | None
    method: str
    coverage_deg: float = 360.0

    @property
    def cropped(self) -> bool:
        """The scan was cut to a region: its beams and azimuth step are those of a part of a turn."""
        return self.coverage_deg < CROPPED_BELOW_DEG


def _azimuth_step_deg(p: np.ndarray, beam: np.ndarray, columns: int | None) -> float | None:
    """Median azimuth step (deg) between successive returns of one beam; None with too few."""
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    order = np.lexsort((az, beam))
    a, b = az[order], beam[order]
    d = np.diff(a)
    d = d[(b[1:] == b[:-1]) & (d > 1e-6) & (d < 5.0)]
    if d.size < 20:
        return None
    step = float(np.median(d[d < 1.5 * np.median(d)]))
    if columns and abs(360.0 / columns - step) < 0.1 * step:
        step = 360.0 / columns
    elif abs(360.0 / round(360.0 / step) - step) < 1e-6 * step:
        # a whole number of firings per turn, read without its rows: the same step as the organised
        # scan's (the last digits were the points' storage, e.g. a bag's unorganised cloud)
        step = 360.0 / round(360.0 / step)
    return step


_GAPS_DEG = (0.04, 0.06, 0.08, 0.1, 0.12, 0.15)


def _stable_clusters(el: np.ndarray, min_points: int) -> np.ndarray:
    """Cluster medians at the smallest gap from which the count holds over three gap steps."""
    found = [_clusters(el, g, min_points) for g in _GAPS_DEG]
    counts = [a.size for a in found]
    for k in range(len(found) - 2):
        if counts[k] == counts[k + 1] == counts[k + 2]:
            return found[k]
    return found[-1]


def _clusters(el: np.ndarray, gap_deg: float, min_points: int) -> np.ndarray:
    """Median elevation (deg, ascending) of each cluster of sorted elevations cut at gaps > gap_deg."""
    e = np.sort(el)
    cuts = np.flatnonzero(np.diff(e) > gap_deg) + 1
    parts = [c for c in np.split(e, cuts) if c.size >= min_points]
    return np.array([np.median(c) for c in parts])


def scanline_free(points: np.ndarray) -> bool:
    """True when the elevations of points (N, 3) (LiDAR frame) lie on no beams.

    A spinning LiDAR's sorted elevations (the farther returns, from the sharpest beam origin height,
    as for the clusters) jump from beam to beam: gaps wider than 20 times the median gap make up
    most of the elevation span (every beam spacing is one). A scanline-free pattern's elevations
    are a continuum whose gaps are about exponentially distributed: gaps that wide cover nearly
    nothing. The threshold is half of the span: between-beam gaps cover > 99 % of it in simulated
    scans of every named table and 94-95 % in the recorded OS1-64 scans (their ring field removed),
    a simulated Livox rosette's wide gaps < 1 % (docs/lidar_ringless.md).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1) & (p != 0).any(axis=1)]
    if p.shape[0] < 200:
        return False
    far = p[_far(p)]
    h = _sharpest_origin_height(far[:: max(1, far.shape[0] // 20000)])
    return _continuous(_elevation_deg(far, h))


def _continuous(el: np.ndarray) -> bool:
    """The test of :func:`scanline_free` on elevations (deg)."""
    el = np.sort(el)
    if el.size < 200:
        return False
    lo, hi = np.quantile(el, [0.005, 0.995])
    el = el[(el >= lo) & (el <= hi)]
    gaps = np.diff(el)
    span = float(el[-1] - el[0])
    if span <= 0:
        return False
    wide = gaps[gaps > 20.0 * max(float(np.median(gaps)), 1e-9)].sum()
    return bool(wide < 0.5 * span)


def _ringless_model(p: np.ndarray, source: str) -> LidarModel:
    """A non-repetitive model of the returns p (N, 3): elevation range (1-99 %) and mean spacing."""
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    el = np.degrees(np.arcsin(np.clip(u[:, 2], -1, 1)))
    lo, hi = np.quantile(el, [0.01, 0.99])
    # the returns' solid angle: occupied cells of 1 x 1 deg in azimuth/elevation, each cos(el) deg^2
    az = np.degrees(np.arctan2(u[:, 1], u[:, 0]))
    cells = np.unique(np.floor(el).astype(np.int64) * 1000 + np.floor(az).astype(np.int64) + 500)
    cos_el = np.cos(np.deg2rad(cells // 1000 + 0.5))
    solid = float(cos_el.sum()) * np.deg2rad(1.0) ** 2
    spacing = float(np.degrees(np.sqrt(solid / p.shape[0])))
    return LidarModel(
        "measured",
        np.array([min(lo, hi - 0.1), hi]),
        min(max(spacing, 1e-3), 10.0),
        source=f"measured from {source or 'a scan'}",
        pattern="non-repetitive",
    )


def measure_beams(scan: Scan) -> MeasuredBeams | None:
    """The beam table of one scan (see the module's docstring); None when it shows none.

    Returns None for a scan with fewer than 2 beams found, or whose azimuth step cannot be
    measured (too few returns): the caller then keeps the named table.
    """
    read_ring = scan.ring is None
    scan = with_intensity_ring(scan)
    read_ring &= scan.ring is not None
    p = np.asarray(scan.points, dtype=np.float64).reshape(-1, 3)
    valid = np.isfinite(p).all(axis=1) & (p != 0).any(axis=1)  # (0, 0, 0): no return
    p = p[valid]
    if p.shape[0] < 50:
        return None
    coverage = azimuth_coverage_deg(p)
    far = _far(p)
    sub = p[far][:: max(1, int(far.sum()) // 20000)]  # the height search on at most ~20k returns
    h = _sharpest_origin_height(sub)
    el = _elevation_deg(p, h)
    columns = getattr(scan, "columns", None)
    if scan.ring is None and not columns and _continuous(el[far]):
        return MeasuredBeams(_ringless_model(p, scan.source), None, "no scanlines", coverage)
    ring_values: np.ndarray | None
    if scan.ring is not None:
        ring = np.asarray(scan.ring).astype(np.int64)[valid]
        ids, med, _ = _group_medians(el[far], ring[far])
        missing = np.setdiff1d(np.unique(ring), ids)
        if missing.size:  # beams with near returns only
            ids2, med2, _ = _group_medians(el, ring)
            keep = np.isin(ids2, missing)
            ids, med = np.concatenate([ids, ids2[keep]]), np.concatenate([med, med2[keep]])
            by_id = np.argsort(ids)
            ids, med = ids[by_id], med[by_id]
        order = np.argsort(med, kind="stable")
        rank = np.empty(ids.size, np.int64)
        rank[order] = np.arange(ids.size)
        angles, ring_values = med[order], ids[order]
        if angles.size >= 2 and np.any(np.diff(angles) <= 0):
            angles = angles + 1e-6 * np.arange(angles.size)  # two ring values at one elevation
        beam_of_point = rank[np.searchsorted(ids, ring)]
        method = "organised rows" if columns else ("intensity as ring" if read_ring else "ring field")
    else:
        angles = _stable_clusters(el[far], max(3, int(2e-4 * far.sum())))
        if angles.size < 2:
            return None
        ring_values = None
        method = "elevation clusters"
        mid = 0.5 * (angles[1:] + angles[:-1])
        beam_of_point = np.searchsorted(mid, el)
    if angles.size < 2 or np.any(np.abs(angles) >= 90):
        return None
    step = _azimuth_step_deg(p, beam_of_point, columns if coverage >= CROPPED_BELOW_DEG else None)
    if step is None:
        return None
    try:
        model = LidarModel(
            "measured",
            angles,
            min(step, 10.0),
            source=f"measured from {scan.source or 'a scan'}",
            beam_origin_z_m=h,
        )
    except ValueError:
        return None
    return MeasuredBeams(model, ring_values, method, coverage)


def cropped_table(scan: Scan, model: LidarModel) -> LidarModel:
    """``model`` with the beams a cropped scan (``MeasuredBeams.cropped``) shows through its ring
    field (or rows; ``with_intensity_ring`` first for an intensity that is the ring number): its own
    elevations and beams' origin height, the model's azimuth step. Each crop shows other beams (those
    that cross its region), and its returns lie at about one range: only the scan's own table maps
    its rings onto the elevations it shows. Any other scan (or model without beams): ``model`` itself."""
    p = np.asarray(scan.points, dtype=np.float64).reshape(-1, 3)
    if model.ringless or scan.ring is None or azimuth_coverage_deg(p) >= CROPPED_BELOW_DEG:
        return model
    measured = measure_beams(scan)
    if measured is None or not measured.cropped or measured.ring_values is None:
        return model
    m = measured.model
    return replace(model, vertical_angles_deg=m.vertical_angles_deg, beam_origin_z_m=m.beam_origin_z_m)


def beam_index(scan: Scan, model: LidarModel) -> np.ndarray:
    """(N,) int32 index into ``model``'s table (0 = lowest beam) of each return of ``scan``.

    With a ring field, each distinct ring value goes to the beam nearest the median elevation of
    its returns (so any numbering works: top-first, hardware ids); without one, each return goes
    to the beam nearest its own elevation. A scanline-free model has one pseudo-beam 0.
    """
    p = np.asarray(scan.points, dtype=np.float64).reshape(-1, 3)
    if scan.ring is None or model.ringless:
        return model.ring_from_points(p)
    ring = np.asarray(scan.ring).astype(np.int64)
    far = _far(p)
    el = _elevation_deg(p, model.beam_origin_z_m)
    ids, med, _ = _group_medians(el, ring)
    if far.any():
        ids_f, med_f, _ = _group_medians(el[far], ring[far])
        med[np.searchsorted(ids, ids_f)] = med_f
    a = model.vertical_angles_deg
    beam = (
        np.zeros(ids.size, np.int32)
        if a.size == 1
        else np.searchsorted(0.5 * (a[1:] + a[:-1]), med).astype(np.int32)
    )
    return beam[np.searchsorted(ids, ring)]


def _describe(model: LidarModel) -> str:
    a = model.vertical_angles_deg
    lo, hi = float(a[0]), float(a[-1])
    span = f"+-{hi:.1f}" if abs(hi + lo) < 0.05 else f"{hi:+.1f} .. {lo:+.1f}"
    return f"{model.n_beams} beams over {span} deg, {model.horizontal_resolution_deg:.3f} deg"


#: of the elevation clusters of a scan without a ring field, at least this share must sit on a named
#: beam; the others may be two neighbouring beams seen as one cluster (near their midpoint)
ON_BEAM_SHARE = 0.8


def _clusters_on_beams(m: np.ndarray, a: np.ndarray, spacing: float) -> bool:
    """Whether elevation clusters ``m`` (deg) are the named beams ``a``'s: every cluster within a third
    of the beam spacing of a beam, or (at most ``1 - ON_BEAM_SHARE`` of them) within a quarter of it
    of the midpoint of two neighbouring beams, which the clustering merges where their returns'
    elevations overlap (the 0.53 deg of an OS1-64 in a scan without its ring field)."""
    on = np.abs(m[:, None] - a[None, :]).min(axis=1) < spacing / 3
    if a.size < 2:
        return bool(np.all(on))
    mids = 0.5 * (a[1:] + a[:-1])
    merged = ~on & (np.abs(m[:, None] - mids[None, :]).min(axis=1) < spacing / 4)
    return bool(np.all(on | merged) and on.mean() >= ON_BEAM_SHARE)


def _beam_subset(m: np.ndarray, a: np.ndarray, spacing: float) -> np.ndarray | None:
    """(m.size,) the named beam (index into ``a``, deg ascending) each measured beam ``m`` (deg
    ascending) sits on, within a third of the spacing and each on its own; None when they do not."""
    j = np.abs(m[:, None] - a[None, :]).argmin(axis=1)
    if np.any(np.abs(m - a[j]) >= spacing / 3) or np.any(np.diff(j) <= 0):
        return None
    return j


def table_difference(measured: MeasuredBeams, named: LidarModel) -> str | None:
    """A sentence naming how the scan's table differs from ``named``, or None when they agree.

    They agree when the beam counts match (a clustered measurement may miss beams that saw
    nothing, or see two neighbours as one: then its clusters must sit on named beams as
    ``_clusters_on_beams`` says), every beam is within a third of the local beam spacing of the
    named one (ring from elevation stays right), and the azimuth steps are within 10 %. A ring field
    may show fewer beams than the table (beams that met nothing): each must then sit on its own named
    beam; a cropped scan's (those that cross its region) need not, since its returns lie at about one
    range, where the beams' origin height and a common elevation offset look the same. A cropped
    scan's step (from a window, often of a near board, whose azimuths are noisy) need only be within
    25 %.
    """
    if measured.model.ringless or named.ringless:
        if measured.model.ringless and named.ringless:
            return None  # no table to compare: the stage measures the density from each scan
        what = (
            "shows no scanlines (a non-repetitive pattern)"
            if measured.model.ringless
            else (f"has {measured.model.n_beams} beams ({measured.method})")
        )
        kind = "scanline-free" if named.ringless else "spinning"
        return f"the scan {what}; {named.name} is a {kind} model; using the scan's"
    m, a = measured.model.vertical_angles_deg, named.vertical_angles_deg
    step_m, step_n = measured.model.horizontal_resolution_deg, named.horizontal_resolution_deg
    spacing = float(np.median(np.diff(a))) if a.size > 1 else 1.0
    if measured.ring_values is None and m.size <= a.size:
        same_beams = _clusters_on_beams(m, a, spacing)
    elif m.size < a.size:  # a cropped scan's beams are seen at one range: h and elevation are one
        same_beams = measured.cropped or _beam_subset(m, a, spacing) is not None
    else:
        same_beams = m.size == a.size and bool(np.all(np.abs(m - a) < spacing / 3))
    if same_beams and abs(step_m - step_n) <= (0.25 if measured.cropped else 0.1) * step_n:
        return None
    lo, hi = float(m[0]), float(m[-1])
    return (
        f"the scan's {m.size} beams span {hi:+.1f} .. {lo:+.1f} deg ({measured.method}), "
        f"{step_m:.3f} deg azimuth step; the {named.name} table says {_describe(named)}; using the scan's"
    )


def choose_model(
    measured: MeasuredBeams | None, given: LidarModel | None, source: str = ""
) -> tuple[LidarModel, str | None]:
    """The table to use, and a warning (or None) when the scan contradicts the given one.

    Without a given table the measured one is used (range sigma and divergence defaults of
    LidarModel). A given table that agrees with the scan is kept, with the scan's own elevations
    when they come from a ring field (the unit's real angles) and the scan's azimuth step. A given
    table that disagrees is replaced by the scan's (keeping its range sigma and divergence). A ring
    field with fewer beams than the given table (a cropped scan) replaces the elevations of the beams
    it shows only; a cropped scan's beams are used as they are (the stage measures each cropped scan's
    own, ``cropped_table``) with the given azimuth step (a turn's, not a window's).
    Raises InputError when there is neither.
    """
    if measured is None:
        if given is None:
            raise InputError(
                f"{source or 'scan'}: the scan shows no beam table (no ring field, too few returns) and "
                "config.yaml names no lidar.model; set lidar.model or lidar.calibration_file"
            )
        return given, None
    m = measured.model
    if given is None:
        return m, None
    diff = table_difference(measured, given)
    if diff is None and m.ringless:
        return given, None
    if diff is not None and m.ringless != given.ringless:  # another kind of sensor than the one named
        return m, f"{source}: {diff}" if source else diff
    if diff is None:
        if measured.ring_values is None:  # clusters may miss beams: keep the complete table
            used = replace(
                given,
                horizontal_resolution_deg=m.horizontal_resolution_deg,
                beam_origin_z_m=m.beam_origin_z_m,
            )
            return used, None
        angles = m.vertical_angles_deg
        a = given.vertical_angles_deg
        if angles.size < a.size and not measured.cropped:  # the beams the scan shows, on the others
            spacing = float(np.median(np.diff(a)))
            angles = a.copy()
            angles[_beam_subset(m.vertical_angles_deg, a, spacing)] = m.vertical_angles_deg
            angles = angles if np.all(np.diff(angles) > 0) else a
        step = given.horizontal_resolution_deg if measured.cropped else m.horizontal_resolution_deg
        used = replace(
            given,
            vertical_angles_deg=angles,
            horizontal_resolution_deg=step,
            beam_origin_z_m=m.beam_origin_z_m if measured.cropped else given.beam_origin_z_m,
            source=f"{given.source}, angles {m.source}",
        )
        return used, None
    used = replace(
        m, name=given.name, range_sigma_m=given.range_sigma_m, beam_divergence_rad=given.beam_divergence_rad
    )
    return used, f"{source}: {diff}" if source else diff
