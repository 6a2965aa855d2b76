"""Image reading and atomic writing with OpenCV (BGR, uint8); image sizes from file headers.

``image_size`` reads width and height from the header alone (PNG IHDR, JPEG SOF, BMP; Pillow's lazy
open for the rest), so a file that declares an absurd size is refused before a byte of it is
decoded: ``read_image`` checks it first (``MAX_PIXELS``). ``encoded_image_size`` does the same for
an encoded image held in memory (a bag's CompressedImage).
"""

from __future__ import annotations

import io
import struct
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..errors import InputError
from .files import atomic_write, broken_link

__all__ = ["IMAGE_SUFFIXES", "MAX_PIXELS", "encoded_image_size", "image_size", "read_image", "write_image"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

#: the most pixels an image may declare (2^28, e.g. 23000 x 11500: 805 MB as BGR); more is refused
#: unread (a forged header would make the decoder allocate it; OpenCV's own limit is 2^30)
MAX_PIXELS = 1 << 28

_PNG = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic; not DHT C4, JPG C8, DAC CC)
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg_size(f: BinaryIO) -> tuple[int, int] | None:
    """(width, height) from the first SOF segment of ``f`` (positioned after SOI), walking the marker
    segments; None if none."""
    while True:
        b = f.read(1)
        if b != b"\xff":
            return None
        while b == b"\xff":  # fill bytes before a marker
            b = f.read(1)
        if not b:
            return None
        marker = b[0]
        if marker == 0x01 or 0xD0 <= marker <= 0xD8:  # no length field
            continue
        n = f.read(2)
        if len(n) < 2 or marker == 0xD9:
            return None
        length = struct.unpack(">H", n)[0]
        if marker in _SOF:
            seg = f.read(5)
            if len(seg) < 5:
                return None
            h, w = struct.unpack(">HH", seg[1:5])
            return w, h
        if length < 2:
            return None
        f.seek(length - 2, 1)


def _header_size(f: BinaryIO) -> tuple[int, int] | None:
    """(width, height) declared by the header of a PNG, JPEG or BMP image read from ``f`` (at its
    start); None for other formats."""
    head = f.read(26)
    if head.startswith(_PNG) and head[12:16] == b"IHDR" and len(head) >= 24:
        return struct.unpack(">II", head[16:24])
    if head.startswith(b"\xff\xd8"):
        f.seek(2)
        return _jpeg_size(f)
    if head.startswith(b"BM") and len(head) >= 26:
        w, h = struct.unpack("<ii", head[18:26])
        return abs(w), abs(h)
    return None


def _declared(p: Path | BinaryIO, where: str) -> tuple[int, int] | None:
    """(width, height) the header of the image file ``p`` (or in the stream ``p``) declares (our
    parsers, else Pillow's lazy open); None when neither can tell (the decoder then says what is
    wrong); ``InputError`` starting with ``where`` when Pillow refuses a size over its
    decompression-bomb limit. Raises OSError (with its errno) when the file cannot be opened."""
    try:
        if isinstance(p, Path):
            with open(p, "rb") as f:
                size = _header_size(f)
        else:
            size = _header_size(p)
            p.seek(0)
    except struct.error:
        size = None
    if size is not None:
        return int(size[0]), int(size[1])
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(p) as im:
                return int(im.width), int(im.height)
    except Image.DecompressionBombError:
        limit = Image.MAX_IMAGE_PIXELS
        assert limit is not None  # Pillow refuses a size only while it has a limit
        raise InputError(
            f"{where}: the image's header declares more than {2 * limit / 1e6:.0f} Mpx; "
            "not decoded (a damaged or forged file)"
        ) from None
    except (UnidentifiedImageError, ValueError, SyntaxError, struct.error, EOFError):
        return None
    except OSError as e:
        if e.errno is None:  # a plugin's parse error (truncated header...), not the file's
            return None
        raise


def _checked_header(p: Path) -> tuple[int, int] | None:
    """(width, height) the header of image file ``p`` declares, checked, or None when the header does
    not tell; ``InputError`` naming the file when it is a broken link, missing or unreadable, or its
    header declares a size of zero or more than ``MAX_PIXELS``. The one reader of the header for
    ``image_size`` and ``read_image``."""
    if why := broken_link(p):
        raise InputError(why)
    try:
        size = _declared(p, str(p))
    except OSError as e:
        raise _unreadable(p, e) from None
    return None if size is None else _checked(size, str(p), "file")


def _checked(size: tuple[int, int], where: str, what: str) -> tuple[int, int]:
    """``size`` (width, height) as declared, or ``InputError`` starting with ``where`` when it is zero
    or over ``MAX_PIXELS`` (``what``: "file" or "message", for the message)."""
    w, h = size
    if w <= 0 or h <= 0:
        raise InputError(f"{where}: the image's header declares {w}x{h} px (corrupt)")
    if w * h > MAX_PIXELS:
        raise InputError(
            f"{where}: the image's header declares {w}x{h} px ({w * h / 1e6:.0f} Mpx), more than the "
            f"{MAX_PIXELS / 1e6:.0f} Mpx an image may have; not decoded (a damaged or forged {what})"
        )
    return size


def encoded_image_size(data: bytes | np.ndarray, where: str) -> tuple[int, int] | None:
    """(width, height) the header of an encoded image in memory (PNG, JPEG, ...) declares, checked as a
    file's, or None when the header does not tell; ``InputError`` starting with ``where`` when it
    declares a size of zero or more than ``MAX_PIXELS``."""
    raw = data.tobytes() if isinstance(data, np.ndarray) else bytes(data)
    size = _declared(io.BytesIO(raw), where)
    return None if size is None else _checked(size, where, "message")


def _unreadable(p: Path, e: OSError) -> InputError:
    """The error of an image file that cannot be opened or read."""
    if isinstance(e, FileNotFoundError):
        return InputError(f"{p}: image file not found")
    return InputError(f"{p}: cannot read image ({e.strerror or e})")


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) in pixels from the image file's header, nothing decoded; ``InputError`` naming
    the file when it is missing, a broken link, not an image, or declares more than ``MAX_PIXELS``."""
    p = Path(path)
    if (size := _checked_header(p)) is None:
        raise InputError(f"{p}: cannot read the image's size (corrupt or not an image)")
    return size


def _decode(buf: np.ndarray) -> np.ndarray | None:
    """cv2.imdecode without OpenCV's own log lines on a damaged file (we say what is wrong)."""
    import cv2

    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is None:
        return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    level = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)
    try:
        return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    finally:
        log.setLogLevel(level)


def eight_bits(px: np.ndarray) -> np.ndarray:
    """uint16 pixels as uint8 by the bits they use: the depth is the fewest bits (at least 8) that
    hold the largest value, and its full scale maps to 255. A 16-bit image is value / 257; a 10- or
    12-bit camera's (values to 1023 or 4095, stored in a 16-bit PNG or TIFF or a mono16 message) fills
    0..255 too, instead of the bottom 4 or 16 levels that dividing by 257 would leave it."""
    bits = max(8, int(px.max()).bit_length()) if px.size else 16
    return np.round(px.astype(np.float64) * (255.0 / (2**bits - 1))).astype(np.uint8)


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as (H, W, 3) uint8 BGR.

    Gray images are promoted to three channels, an alpha channel is dropped, 16-bit images are
    scaled to 8 bits by the bits they use (``eight_bits``). Missing, empty or undecodable files,
    broken links and files whose header declares more than ``MAX_PIXELS`` (checked before decoding)
    raise ``InputError``.
    """
    import cv2

    p = Path(path)
    _checked_header(p)  # a size it cannot tell: the decoder says what is wrong
    try:
        buf = np.fromfile(p, dtype=np.uint8)
    except OSError as e:
        raise _unreadable(p, e) from None
    if buf.size == 0:
        raise InputError(f"{p}: empty image file")
    img = _decode(buf)
    if img is None:
        raise InputError(f"{p}: cannot decode image (corrupt or not an image)")
    if img.dtype == np.uint16:
        img = eight_bits(img)
    elif img.dtype in (np.float32, np.float64):
        img = np.clip(np.round(img * 255.0 if img.max() <= 1.0 else img), 0, 255).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError(f"{p}: unsupported image pixel type {img.dtype}")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    elif img.shape[2] == 1:
        img = cv2.cvtColor(img[:, :, 0], cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(img)


def write_image(path: str | Path, img: np.ndarray) -> Path:
    """Encode ``img`` (BGR or gray, uint8/uint16) by the path's suffix and write it atomically."""
    import cv2

    p = Path(path)
    ext = p.suffix.lower() or ".png"
    cannot = f"{p}: OpenCV cannot encode an image as {ext!r}"
    try:
        ok, enc = cv2.imencode(ext, np.asarray(img))
    except cv2.error:
        raise ValueError(cannot) from None
    if not ok:
        raise ValueError(cannot)
    return atomic_write(p, enc.tobytes())
