"""Camera images by casting one ray per pixel (more at edges), uint8 BGR.

The room seen from the camera does not change between frames, so it is rendered once per data set
and cached: one ray through each pixel centre, in chunks of rows to bound memory; images over 4 Mpx
are traced at half resolution and scaled up bilinearly (the room is smooth). Each frame then
re-renders the pixels inside the projected bounding box of each moving object (board, its stand,
the person) with rays against the moving objects only (a ray that misses them shows the cached
room pixel): one ray per pixel centre, then S x S rays (``RenderOptions.supersample``) averaged on
every pixel whose 3 x 3 neighbourhood changes label (an object's outline or a colour edge of the
print), which anti-aliases all edges that matter. Then a Gaussian blur (``blur_sigma_px``) and
Gaussian pixel noise (``noise_sigma``, luminance noise, see :func:`_add_noise`).

Pixels follow the camera model's convention (pixel centres at integers); a sample at (u, v) looks
along ``camera.bearing((u, v))`` from the camera centre. Shading: flat colours times a little
Lambertian light from above; procedural value-noise texture on walls, floor and ceiling (smooth,
so it makes no chessboard-like corners). The board prints grey 22 (black) and 225 (white) before
the light factor (about 0.8 on a board facing the sensors).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.special import ndtri

from .placements import PURPOSE_FRAME, PURPOSE_UNIT, camera_centre_lidar, frame_rng, static_scene
from .scene import (
    SURF_BOARD,
    SURF_BOARD_BACK,
    SURF_CEILING,
    SURF_GROUND,
    SURF_NONE,
    SURF_PERSON,
    SURF_POLE,
    SURF_WALL,
    Hits,
    Scene,
    cast_rays,
)
from .spec import SimulationSpec

__all__ = ["ImageRenderer", "BOARD_BLACK", "BOARD_WHITE"]

BOARD_BLACK, BOARD_WHITE = 22.0, 225.0
_CHUNK_RAYS = 1 << 20
_LIGHT = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
_BGR = {
    SURF_NONE: (235.0, 205.0, 170.0),  # sky (open scene)
    SURF_GROUND: (95.0, 108.0, 120.0),
    SURF_CEILING: (215.0, 215.0, 210.0),
    SURF_WALL: (170.0, 186.0, 200.0),
    SURF_BOARD_BACK: (70.0, 70.0, 70.0),
    SURF_PERSON: (95.0, 55.0, 35.0),
    SURF_POLE: (50.0, 50.0, 55.0),
}
_PALETTE = np.zeros((8, 3), np.float32)
for _s, _c in _BGR.items():
    _PALETTE[_s] = _c


class _Texture:
    """Smooth periodic value noise on surface coordinates (metres), values about [-1, 1].

    Three octaves (random lattices of spacing 0.32 m, 0.08 m, 0.02 m; amplitudes 0.55, 0.30, 0.15)
    interpolated bicubically and summed once into a 2048 x 2048 float32 tile of 1 cm texels
    (period 20.48 m), then looked up bilinearly (``cv2.remap``, wrapping).
    """

    TEXEL_M, SIZE = 0.01, 2048

    def __init__(self, rng: np.random.Generator) -> None:
        tile = np.zeros((self.SIZE, self.SIZE), np.float32)
        for n, amp in ((64, 0.55), (256, 0.30), (1024, 0.15)):
            k = self.SIZE // n  # texels per lattice cell
            g = np.pad(rng.uniform(-1.0, 1.0, (n, n)).astype(np.float32), 2, mode="wrap")
            big = cv2.resize(g, ((n + 4) * k, (n + 4) * k), interpolation=cv2.INTER_CUBIC)
            tile += amp * big[2 * k : 2 * k + self.SIZE, 2 * k : 2 * k + self.SIZE]
        self.tile = tile

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        n = a.size
        w = 1024
        rows = -(-n // w)
        mx = np.zeros(rows * w, np.float32)
        my = np.zeros(rows * w, np.float32)
        mx[:n] = a / self.TEXEL_M
        my[:n] = b / self.TEXEL_M
        out = cv2.remap(self.tile, mx.reshape(rows, w), my.reshape(rows, w), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_WRAP)  # fmt: skip
        return out.reshape(-1)[:n]


class ImageRenderer:
    """Renders the frames of one :class:`SimulationSpec`; caches the static room."""

    def __init__(self, spec: SimulationSpec) -> None:
        self.spec = spec
        self.camera = spec.camera
        self.R_lidar_cam = spec.true_T_cam_lidar[:3, :3].T
        self.centre = camera_centre_lidar(spec.true_T_cam_lidar)
        self.texture = (
            _Texture(frame_rng(spec.seed, PURPOSE_UNIT, 1)) if spec.image.textured_background else None
        )
        self._background: np.ndarray | None = None

    # ------------------------------------------------------------------ shading
    def _shade(self, hits: Hits, d: np.ndarray) -> np.ndarray:
        """(N, 3) float32 BGR of each ray's hit."""
        col = _PALETTE[hits.surface]
        board = hits.surface == SURF_BOARD
        if board.any():
            c = self.spec.board.colour_at(hits.board_xy[board])
            col[board] = (BOARD_BLACK + np.nan_to_num(c, nan=1.0) * (BOARD_WHITE - BOARD_BLACK))[:, None]
        light = 0.75 + 0.25 * np.clip(hits.normal @ _LIGHT, 0.0, 1.0)
        if self.texture is not None:
            room = (
                (hits.surface == SURF_GROUND) | (hits.surface == SURF_CEILING) | (hits.surface == SURF_WALL)
            )
            if room.any():
                p = self.centre + d[room] * hits.t[room, None]
                nrm = np.abs(hits.normal[room])
                a = np.where(nrm[:, 0] > 0.5, p[:, 1], p[:, 0])
                b = np.where(nrm[:, 2] > 0.5, p[:, 1], p[:, 2])
                light[room] *= 1.0 + 0.12 * self.texture(a, b)
        light[hits.surface == SURF_NONE] = 1.0
        col *= light[:, None].astype(np.float32)
        return col

    def _trace(self, scene: Scene, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Colours (N, 3) float32 BGR and labels (N,) uint8 seen through pixel positions uv (N, 2).

        label: 0 where nothing is hit (or no ray maps to the pixel), else ``3 * surface + k`` with k
        the printed colour (0 black, 1 white) on the board and 2 elsewhere: a change of label between
        neighbouring pixels marks an edge worth anti-aliasing.
        """
        out = np.zeros((len(uv), 3), np.float32)
        lab = np.zeros(len(uv), np.uint8)
        for k in range(0, len(uv), _CHUNK_RAYS):
            b = self.camera.bearing(uv[k : k + _CHUNK_RAYS])
            ok = np.all(np.isfinite(b), axis=1)
            every = bool(ok.all())
            d = (b if every else b[ok]) @ self.R_lidar_cam.T
            hits = cast_rays(scene, self.centre, d)
            cls = np.full(len(d), 2, np.uint8)
            board = hits.surface == SURF_BOARD
            cls[board] = self.spec.board.colour_at(hits.board_xy[board]) > 0.5
            label = np.where(hits.surface == SURF_NONE, 0, 3 * hits.surface + cls)
            sl = slice(k, k + len(b))
            if every:
                out[sl], lab[sl] = self._shade(hits, d), label
            else:
                out[sl][ok], lab[sl][ok] = self._shade(hits, d), label
        return out, lab

    # --------------------------------------------------------------- background
    def background(self) -> np.ndarray:
        """(H, W, 3) uint8: the empty room, computed once.

        One ray per pixel centre; images over 4 Mpx are traced at half resolution (one ray per
        2 x 2 block, through its centre) and scaled up bilinearly: the room is smooth and the
        board is re-rendered at full resolution anyway.
        """
        if self._background is None:
            W, H = self.camera.width, self.camera.height
            f = 2 if W * H > 4_000_000 else 1
            w, h = -(-W // f), -(-H // f)
            scene = static_scene(self.spec)
            img = np.empty((h, w, 3), dtype=np.uint8)
            rows = max(1, _CHUNK_RAYS // w)
            u = np.arange(w, dtype=np.float64) * f + 0.5 * (f - 1)
            for r0 in range(0, h, rows):
                v = np.arange(r0, min(h, r0 + rows), dtype=np.float64) * f + 0.5 * (f - 1)
                uv = np.column_stack([np.tile(u, len(v)), np.repeat(v, w)])
                col = self._trace(scene, uv)[0]
                img[r0 : r0 + len(v)] = np.clip(np.rint(col), 0, 255).reshape(len(v), w, 3)
            if f > 1:
                img = cv2.resize(img, (w * f, h * f), interpolation=cv2.INTER_LINEAR)[:H, :W].copy()
            self._background = img
        return self._background

    # ------------------------------------------------------------------ regions
    def _region(
        self, pts_lidar: np.ndarray, pad: int = 3
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
        """Pixels that may show an object, from LiDAR-frame points along its edges.

        Returns rows (h,), columns (w,) (wrapped modulo W when the camera's columns wrap) of a box, and a
        (h, w) bool mask of the convex hull of the points' images grown by ``pad`` pixels (None:
        the whole box); None when the object cannot be seen.
        """
        cam = self.camera
        W, H = cam.width, cam.height
        T = self.spec.true_T_cam_lidar
        uv = cam.project(pts_lidar @ T[:3, :3].T + T[:3, 3])
        finite = np.all(np.isfinite(uv), axis=1)
        if not finite.any():
            return None
        if not cam.periodic_u and not finite.all():
            return np.arange(H), np.arange(W), None  # partly not imageable: be safe, take everything
        u, v = uv[finite, 0], uv[finite, 1]
        if cam.periodic_u:
            u = u[0] + cam.wrap_du(u - u[0])
            lo, hi = int(np.floor(u.min())) - pad, int(np.ceil(u.max())) + pad
            if hi - lo + 1 >= W // 2:
                return (
                    np.arange(max(0, int(v.min()) - pad), min(H, int(v.max()) + pad + 1)),
                    np.arange(W),
                    None,
                )
            cols = np.mod(np.arange(lo, hi + 1), W)
        else:
            lo, hi = max(0, int(np.floor(u.min())) - pad), min(W - 1, int(np.ceil(u.max())) + pad)
            if lo > hi:
                return None
            cols = np.arange(lo, hi + 1)
        r0, r1 = max(0, int(np.floor(v.min())) - pad), min(H - 1, int(np.ceil(v.max())) + pad)
        if r0 > r1:
            return None
        mask = np.zeros((r1 - r0 + 1, len(cols)), np.uint8)
        hull = cv2.convexHull(np.rint(np.column_stack([u - lo, v - r0])).astype(np.int32))
        cv2.fillConvexPoly(mask, hull, 1)
        mask = cv2.dilate(mask, np.ones((2 * pad + 1, 2 * pad + 1), np.uint8)).astype(bool)
        return np.arange(r0, r1 + 1), cols, mask

    def _render_region(
        self,
        img: np.ndarray,
        moving: Scene,
        rows: np.ndarray,
        cols: np.ndarray,
        mask: np.ndarray | None,
        s: int,
    ) -> None:
        """Re-render pixels (rows x cols, where ``mask``) with the moving objects over the room, in place.

        One ray per pixel centre; pixels whose 3 x 3 neighbourhood changes label (object outline,
        colour edge of the print) get S x S rays. Rays that miss every moving object show the room
        (the cached background pixel).
        """
        h, w = len(rows), len(cols)
        uu, vv = np.meshgrid(cols.astype(np.float64), rows.astype(np.float64), indexing="xy")
        px = np.column_stack([uu.ravel(), vv.ravel()])
        room = self.background()[np.ix_(rows, cols)].reshape(-1, 3).astype(np.float32)
        col = room.copy()
        lab = np.zeros(h * w, np.uint8)
        sel = np.arange(h * w) if mask is None else np.flatnonzero(mask.ravel())
        c1, l1 = self._trace(moving, px[sel])
        hit = l1 != 0
        col[sel[hit]], lab[sel] = c1[hit], l1
        L = lab.reshape(h, w)
        k3 = np.ones((3, 3), np.uint8)
        edge = cv2.dilate(L, k3) != cv2.erode(L, k3)
        if mask is not None:
            edge &= mask
        edge = np.flatnonzero(edge)
        if s > 1 and edge.size:
            off = (np.arange(s) + 0.5) / s - 0.5
            sub = np.stack(np.meshgrid(off, off, indexing="xy"), axis=-1).reshape(-1, 2)  # (s*s, 2)
            step = max(1, _CHUNK_RAYS // (s * s))
            for k in range(0, edge.size, step):
                e = edge[k : k + step]
                c2, l2 = self._trace(moving, (px[e][:, None, :] + sub[None]).reshape(-1, 2))
                c2 = c2.reshape(len(e), s * s, 3)
                c2 = np.where((l2 == 0).reshape(len(e), s * s, 1), room[e][:, None, :], c2)
                col[e] = c2.mean(axis=1)
        out = np.clip(np.rint(col[sel]), 0, 255).astype(np.uint8)
        img[rows[sel // w], cols[sel % w]] = out  # only the traced pixels: others may show other objects

    # -------------------------------------------------------------------- frame
    def render(self, scene: Scene, frame: int) -> np.ndarray:
        """(H, W, 3) uint8 BGR image of ``scene`` (the room plus this frame's objects)."""
        img = self.background().copy()
        moving = scene.moving_parts()
        s = int(self.spec.image.supersample)
        for pts in [box.edge_samples(12) for box in scene.boxes] + [scene.board_outline_samples(32)]:
            reg = self._region(pts)
            if reg is not None:
                self._render_region(img, moving, *reg, s)
        opt = self.spec.image
        if opt.blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), opt.blur_sigma_px)
        if opt.noise_sigma > 0:
            _add_noise(img, opt.noise_sigma, frame_rng(self.spec.seed, PURPOSE_FRAME, frame, 2))
        return img


def _add_noise(img: np.ndarray, sigma: float, rng: np.random.Generator) -> None:
    """Add rounded Gaussian noise N(0, sigma^2) to every pixel, in place, saturating at 0 and 255.

    The noise is luminance noise (the same value on the three channels), drawn as 16-bit uniform
    integers mapped through the normal quantile function (tails cut at 4.3 sigma). As the image is
    integer, this equals rounding ``img + n`` for a continuous Gaussian ``n``.
    """
    q = (np.arange(65536) + 0.5) / 65536.0
    n = np.rint(sigma * ndtri(q))
    pos = np.clip(n, 0, 255).astype(np.uint8)
    neg = np.clip(-n, 0, 255).astype(np.uint8)
    H = img.shape[0]
    rows = max(1, (8 << 20) // (img.shape[1] * 3))
    for r0 in range(0, H, rows):
        chunk = img[r0 : r0 + rows]
        k = rng.integers(0, 65536, chunk.shape[:2], dtype=np.uint16)
        p, m = pos[k], neg[k]
        cv2.subtract(cv2.add(chunk, cv2.merge([p, p, p])), cv2.merge([m, m, m]), dst=chunk)
