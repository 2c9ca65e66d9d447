"""Reading image files (depth and part-label PNGs) with one-line errors naming the file.

Depth PNGs hold millimetres in 16 bits, 0 = no measurement. Two things a PNG can hold that
are not millimetres are handled here, for every data set read from PNGs:

- an 8-bit image (``L``, ``P``, RGB, ...) cannot hold a hand's depth (at most 255 mm): it is
  refused, naming the file;
- 65535, the largest 16-bit value, is what sensors and tools write for a saturated or
  invalid pixel (65.5 m is no hand's depth): it is read as 0, no measurement.

An image whose header claims far more pixels than a frame (a "decompression bomb", or just the
wrong file) is refused from its header, before any pixel is decoded.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ..errors import HybridfitError, ResourceError

#: the value sensors write for a saturated or invalid depth pixel: read as 0 (no measurement)
SATURATED = 65535
_PNG = b"\x89PNG\r\n\x1a\n"


def png_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from a PNG file's header, without decoding it (None if not a PNG)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(24)
    except OSError:
        return None
    if len(head) < 24 or not head.startswith(_PNG) or head[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", head[16:24])


def read_image(path: Path, shape: tuple[int, int] | None = None, convert: str | None = None,
               what: str = "image") -> np.ndarray:
    """An image file as an array; ``shape`` (H, W): the size it must have, checked from a PNG's
    header before decoding; ``convert``: a PIL mode to convert to; ``what`` it should be, for
    messages. Errors are one line naming the file (missing, unreadable, of another size, too
    large to decode, out of memory)."""
    from PIL import Image, UnidentifiedImageError

    size = png_size(path)
    if shape is not None and size is not None and size != (shape[1], shape[0]):
        raise HybridfitError(f"{path}: expected a {shape[1]}x{shape[0]} {what}, got a {size[0]}x{size[1]} one "
                             "(refused before decoding it)")
    try:
        with Image.open(path) as im:
            if convert is not None:
                im = im.convert(convert)
            return np.asarray(im)
    except FileNotFoundError:
        raise HybridfitError(f"{path}: missing frame file") from None
    except Image.DecompressionBombError as err:
        claimed = f" ({size[0]}x{size[1]})" if size else ""
        raise HybridfitError(f"{path}: an image too large to decode{claimed}, far larger than a depth frame: the "
                             f"wrong file, or a damaged one ({err})") from None
    except MemoryError:
        raise ResourceError(f"{path}: out of memory decoding the image") from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, struct.error) as err:
        raise HybridfitError(f"{path}: not a readable PNG ({type(err).__name__}: {err})") from None


def depth_mm(arr: np.ndarray, path: Path) -> np.ndarray:
    """A decoded depth image -> (H, W) uint16 mm: 8-bit images refused, saturated pixels
    (65535) read as 0 (no measurement); see the module docstring."""
    if arr.ndim != 2:
        raise HybridfitError(f"{path}: expected a single-channel 16-bit depth PNG, got shape {arr.shape}")
    if arr.dtype.itemsize == 1 or arr.dtype == bool:
        raise HybridfitError(f"{path}: an 8-bit image; depth frames are 16-bit PNGs in millimetres (8 bits hold at "
                             "most 255 mm): convert the depth without scaling it to 8 bits")
    if arr.dtype.kind not in "iu":
        raise HybridfitError(f"{path}: a {arr.dtype} image; depth frames are 16-bit integer PNGs in millimetres")
    if arr.min(initial=0) < 0 or arr.max(initial=0) > SATURATED:
        raise HybridfitError(f"{path}: values outside the 16-bit range (0-65535 mm)")
    arr = arr.astype(np.uint16, copy=False)
    saturated = arr == SATURATED
    if saturated.any():
        arr = np.where(saturated, np.uint16(0), arr)
    return arr
