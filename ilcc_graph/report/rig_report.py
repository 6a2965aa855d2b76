"""The rig's report: ``index.html`` with its pictures in ``figures/`` (docs/rig.md, "The rig's report").

In this order: the verdict (``rig_verdict``) with a row per sensor; every sensor's pose in the
reference's frame and every pair's relative pose, each with its 1-sigma; a table of moments x
sensors with each observation's fate; per moment and camera, every LiDAR's board points on the
image with the detected corners and the share of the points on the detected board
(``rig_pictures``). Offline and self-contained like the pair's report (inline CSS, no scripts, the
pictures as WebP files beside the page). The images are read through the rig source once each;
without a source the pictures are left out and the page says so. The run's types are named for
the type checker only (``report`` does not import the run or the data sets).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import CalibrationError, InputError
from ..io.rig_results import RigCalibration
from .figures import FIGURES_DIR, encode_image
from .rig_pictures import BoardPicture, board_picture
from .rig_verdict import fate_kind, rig_sensors, rig_verdict, sensor_standings
from .sections import CSS, esc, figure, page, pm, table
from .summary import _propagate, lidar_in_camera
from .text import short_reason

if TYPE_CHECKING:
    from ..config import RigConfig
    from ..types import MomentResult


class RigSeen(Protocol):
    """What the rig's stages found (``run.rig_observe.RigObservation`` is one): the rig, and each
    moment's boards and corners."""

    @property
    def rig(self) -> RigConfig: ...

    @property
    def moments(self) -> Sequence[MomentResult]: ...


class _Moment(Protocol):
    def has(self, sensor: str) -> bool: ...


class RigImages(Protocol):
    """Where the rig's images are read (``datasets.RigSource`` is one)."""

    def moment(self, name: str) -> _Moment: ...

    def read_image(self, moment: str, camera: str) -> np.ndarray: ...

__all__ = ["SHARE_LOW", "RigImages", "RigSeen", "pose_cells", "rig_report_files"]

#: below this share of a LiDAR's board points on the detected board a picture is marked: on a right
#: calibration nearly every point lands on it (98-100 % on simulated rigs and on recorded data)
SHARE_LOW = 0.9

_CSS = CSS + ".dim{color:#888} td span[title]{cursor:help}\n"


def _rpy(T: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(roll, pitch, yaw) deg of ``T``'s rotation (about the parent's fixed x, y, z: ``R = Rz Ry Rx``)
    and their 1-sigma, propagated from the right-tangent rotation covariance ``C`` (3, 3)."""
    R = np.asarray(T, dtype=np.float64)[:3, :3]
    rpy = Rotation.from_matrix(R).as_euler("xyz", degrees=True)
    if not np.all(np.isfinite(C)):
        return rpy, np.full(3, np.nan)

    def turned(w: np.ndarray) -> np.ndarray:  # a turn w about the parent's axes: Exp(w) R
        a = (Rotation.from_rotvec(w) * Rotation.from_matrix(R)).as_euler("xyz", degrees=True)
        return rpy + (a - rpy + 180.0) % 360.0 - 180.0

    return rpy, _propagate(turned, R @ C @ R.T, 3)


def pose_cells(T: np.ndarray, C: np.ndarray) -> list[str]:
    """Table cells of a child's pose in its parent's frame (``T`` (4, 4), ``C`` (6, 6) right-tangent):
    x, y, z in mm and roll, pitch, yaw in deg (about the parent's x, y, z), each ± its 1-sigma in the
    parent's axes (``summary.lidar_in_camera`` for the position)."""
    p, ps, _, _, _ = lidar_in_camera(T, C)
    rpy, rs = _rpy(T, np.asarray(C, dtype=np.float64)[:3, :3])
    return [pm(v, s, "+.1f") for v, s in zip(p, ps, strict=True)] + [
        pm(v, s, "+.3f") for v, s in zip(rpy, rs, strict=True)
    ]


_POSE_HEAD = ["x (mm)", "y (mm)", "z (mm)", "roll (deg)", "pitch (deg)", "yaw (deg)"]


def _kind(cal: RigCalibration, s: str) -> str:
    d = ((cal.rig or {}).get("sensors") or {}).get(s) or {}
    return "camera" if "camera" in d else "LiDAR" if "lidar" in d else ""


def _verdict_html(cal: RigCalibration, need: tuple[float, float] | None) -> list[str]:
    """The verdict box and the row of every sensor but the reference."""
    level, text = rig_verdict(cal, need)
    box = esc(text).replace("\n", "<br>")
    rows = [
        [
            esc(s.name),
            esc(_kind(cal, s.name)),
            f'<span class="{"ok" if s.level == "GOOD" else "bad"}">{s.level}</span>',
            str(s.used),
            str(s.disagree),
            "–" if not math.isfinite(s.rot_deg) else f"{s.rot_deg:.3g}",
            "–" if not math.isfinite(s.mm) else f"{s.mm:.2g}",
            esc("; ".join(s.problems)),
        ]
        for s in sensor_standings(cal, need)
    ]
    head = [
        "sensor",
        "kind",
        "verdict",
        "moments used",
        "dropped (disagree)",
        "1-sigma (deg)",
        "1-sigma (mm)",
        "what is wrong",
    ]
    return [
        f'<div class="verdict {"ok" if level == "GOOD" else "bad"}">{box}</div>',
        table(head, rows, left=2, left_last=1),
        '<p class="note"><b>1-sigma</b>: the largest in any direction of the sensor\'s pose (the 6x6 block '
        "of the joint covariance); <b>dropped</b>: moments it saw the board but its observation disagreed "
        "with the others' (the start's corner-order check or the chi-square gate).</p>",
    ]


def _poses_html(cal: RigCalibration) -> list[str]:
    """Every sensor's pose in the reference's frame, then every pair's relative pose."""
    used = cal.extra.get("used") or {}
    rows = []
    for s in rig_sensors(cal):
        name = esc(s) + (" (the reference)" if s == cal.reference else "")
        if s in cal.sensors:
            rows.append(
                [
                    name,
                    esc(_kind(cal, s)),
                    *pose_cells(cal.T_ref_sensor[s], cal.block(s)),
                    str(used.get(s, "–")),
                ]
            )
        else:
            why = (cal.extra.get("unsolved") or {}).get(s, "not solved")
            no_pose = f'<span class="bad" title="{esc(why)}">no pose</span>'
            rows.append([name, esc(_kind(cal, s)), no_pose, *["–"] * 5, str(used.get(s, "–"))])
    out = [
        f"<h2>Every sensor in the frame of {esc(cal.reference)}</h2>",
        "<p><code>T_ref_sensor</code> maps a sensor's points into the reference's frame: "
        "<code>p_ref = R p_sensor + t</code>. Position: the sensor's origin in the reference's axes; "
        "roll, pitch, yaw: its rotation about the reference's fixed x, y, z (<code>R = Rz(yaw) Ry(pitch) "
        "Rx(roll)</code>); ± 1 sigma from the joint covariance (a camera's axes are its model's).</p>",
        table(["sensor", "kind", *_POSE_HEAD, "moments used"], rows, left=2),
    ]
    pair_rows = [
        [f"{esc(b)} in {esc(a)}'s frame", *pose_cells(T, C)] for (a, b), (T, C) in sorted(cal.pairs.items())
    ]
    if pair_rows:
        out += [
            "<h3>Every pair</h3>",
            "<p><code>T_a_b</code> (<code>p_a = T_a_b p_b</code>), b's pose in a's frame, its covariance "
            "propagated from the joint one (calibration.yaml: <code>pairs</code>).</p>",
            table(["pair (b in a's frame)", *_POSE_HEAD], pair_rows),
        ]
    return out


def _fate_cell(reason: str) -> str:
    kind = fate_kind(reason)
    if kind == "used":
        return '<span class="ok">used</span>'
    if kind == "no data":
        return f'<span class="dim" title="{esc(reason)}">–</span>'
    cls = "bad" if kind == "disagrees" else "dim"
    return f'<span class="{cls}" title="{esc(reason)}">{esc(short_reason(reason, 48))}</span>'


def _moments_html(cal: RigCalibration, pictured: set[str]) -> list[str]:
    """The table moments x sensors: used, dropped for disagreeing (red), not used (gray, the reason)."""
    names = rig_sensors(cal)
    moments = cal.extra.get("moments") or {}
    rows = [
        [
            f'<a href="#m{esc(m)}">{esc(m)}</a>' if m in pictured else esc(m),
            *(_fate_cell(d.get(s, "")) for s in names),
        ]
        for m, d in moments.items()
    ]
    out = [
        "<h2>Moments</h2>",
        '<p class="note">Each sensor at each moment: <span class="ok">used</span> (in the graph), '
        '<span class="bad">red</span>: it saw the board but disagreed with the other sensors, gray: not '
        "used, with the reason (the whole reason when the pointer rests on it; every reason in "
        "calibration.yaml, <code>moments</code>); –: no file of it at this moment.</p>",
        table(["moment", *(esc(s) for s in names)], rows, left=len(names) + 1),
    ]
    skipped = cal.extra.get("skipped") or []
    if skipped:
        out.append(
            '<p class="note">Moments not used at all: '
            + "; ".join(f"{esc(n)} ({esc(r)})" for n, r in skipped)
            + "</p>"
        )
    return out


_PICTURES_NOTE = (
    "<p class=\"note\">Each LiDAR's board points (the LiDAR stage's, its own frame) projected into each "
    "camera with the calibrated poses (<code>T_cam_lidar = T_ref_cam^-1 T_ref_lidar</code>) and the "
    "camera's model, coloured by intensity, with the corners the camera detected (0 green, last blue). "
    "On a right calibration the points cover the detected board and their dark and bright stripes follow "
    "its squares. <b>on the board</b>: the share of the points inside the detected corners' hull grown by "
    f"a square and the board's margin; below {SHARE_LOW:.0%} it is marked.</p>"
)


def _moment_pictures(
    m: MomentResult, cal: RigCalibration, rig: RigConfig, source: RigImages
) -> list[tuple[str, str, BoardPicture | None, str]]:
    """(camera, LiDAR, its picture, a note) for every camera with a pose and a file at moment ``m``
    (``rig``'s cameras as solved) and every LiDAR with a pose whose board was found there (the picture
    None when the image could not be read, with the reason; pairs whose board is neither imaged nor
    detected are left out)."""
    out: list[tuple[str, str, BoardPicture | None, str]] = []
    lidars = [lid for lid in m.boards if lid in cal.T_ref_sensor]
    for cam in rig.cameras:
        model = rig.sensor(cam).camera
        if not lidars or model is None or cam not in cal.T_ref_sensor:
            continue
        try:
            if not source.moment(m.name).has(cam):
                continue
            image = source.read_image(m.name, cam)
        except (KeyError, InputError, CalibrationError) as err:
            out.append((cam, lidars[0], None, f"the image could not be read: {err}"))
            continue
        T_cam_ref = np.linalg.inv(cal.T_ref_sensor[cam])
        for lid in lidars:
            pic = board_picture(
                image, model, rig.board, T_cam_ref @ cal.T_ref_sensor[lid], m.boards[lid], m.corners.get(cam)
            )
            if pic is not None:
                out.append((cam, lid, pic, "" if cam in m.corners else f"{cam} found no corners here"))
        del image
    return out


def _caption(cam: str, lid: str, pic: BoardPicture, note: str) -> str:
    text = f"{lid}'s board points on {cam}'s image (scaled by {pic.zoom:.2g}), coloured by intensity"
    if math.isfinite(pic.share):
        return (
            text
            + f", and {cam}'s corners: {pic.share:.0%} of the {pic.n_points} points on the detected board."
        )
    return text + f": {note}; {pic.n_imaged} of the {pic.n_points} points imaged."


def _share_cell(share: float) -> str:
    if not math.isfinite(share):
        return "–"
    return f'<span class="bad">{share:.0%}</span>' if share < SHARE_LOW else f"{share:.0%}"


def _pictures_html(
    cal: RigCalibration, observation: RigSeen, source: RigImages | None
) -> tuple[list[str], dict[str, bytes], set[str]]:
    """(the section "LiDAR boards in the images", its files {relative path: WebP bytes}, the moments
    pictured); without a source a note only."""
    body = ["<h2>LiDAR boards in the images</h2>", _PICTURES_NOTE]
    if source is None:
        return body + ['<p class="note"><b>No pictures</b>: this report was written without the data set '
                       "(no rig source was given), so no image was read.</p>"], {}, set()  # fmt: skip
    files: dict[str, bytes] = {}
    rows: list[list[str]] = []
    groups: list[str] = []
    pictured: set[str] = set()
    rig = observation.rig.with_intrinsics(cal.refined_intrinsics())[0]  # the cameras as solved
    for m in observation.moments:
        figs, low = [], False
        for cam, lid, pic, note in _moment_pictures(m, cal, rig, source):
            if pic is None:
                figs.append(f'<p class="note">{esc(cam)}: {esc(note)}</p>')
                continue
            path = f"{FIGURES_DIR}/{m.name}_{cam}_{lid}.webp"
            files[path] = encode_image(pic.image)
            figs.append(figure(path, _caption(cam, lid, pic, note)))
            low |= pic.share < SHARE_LOW
            link = f'<a href="#m{esc(m.name)}">{esc(m.name)}</a>'
            rows.append(
                [link, esc(cam), esc(lid), str(pic.n_points), str(pic.n_imaged), _share_cell(pic.share)]
            )
        if figs:
            pictured.add(m.name)
            is_open = " open" if len(groups) < 2 or low else ""
            groups.append(f'<details id="m{esc(m.name)}"{is_open}><summary>Moment {esc(m.name)}</summary>'
                          f'<div class="gallery">{"".join(figs)}</div></details>')  # fmt: skip
    if not groups:
        return body + ['<p class="note">No picture: no LiDAR\'s board was found where a camera with a pose '
                       "sees it.</p>"], files, set()  # fmt: skip
    head = ["moment", "camera", "LiDAR", "board points", "imaged", "on the board"]
    return body + [table(head, rows, left=3), *groups], files, pictured


def rig_report_files(
    cal: RigCalibration,
    observation: RigSeen,
    source: RigImages | None,
    info: Mapping[str, str],
    *,
    need: tuple[float, float] | None = None,
    title: str = "Rig calibration report",
) -> dict[str, bytes]:
    """Every file of the rig's report, ``{"index.html": ..., "figures/<moment>_<camera>_<lidar>.webp":
    ...}``: ``cal`` the result (``run.rig_calibrate.to_calibration``), ``observation`` what the stages
    found (``RigResult.observation``: the boards' points and the corners), ``source`` the rig source
    the images are read from (None: no pictures), ``info`` extra header lines (data, command, ...)."""
    rig = observation.rig
    board = rig.board
    meta = {
        "reference": cal.reference,
        "sensors": ", ".join(f"{s} ({_kind(cal, s)})" for s in rig_sensors(cal)),
        "board": f"{board.rows} x {board.cols} squares of {1000 * board.square_size:.1f} mm",
        "moments": str(len(cal.extra.get("moments") or {})),
        **dict(info),
    }
    body = [
        f"<h1>{esc(title)}</h1>",
        "<p>" + " · ".join(f"<b>{esc(k)}</b>: {esc(v)}" for k, v in meta.items()) + "</p>",
    ]
    body += _verdict_html(cal, need) + _poses_html(cal)
    pictures, files, pictured = _pictures_html(cal, observation, source)
    body += _moments_html(cal, pictured) + pictures
    files["index.html"] = page(title, body, _CSS)
    return files
