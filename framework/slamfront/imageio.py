"""Reading images and depth maps with one clear error per bad file.

Every source reads pixels through these functions (files through :func:`read_image`
and :func:`read_depth`; encoded bytes from a log or a recording through
:func:`decode_image`), so a corrupt, empty or missing file always ends the same way: a
:class:`~slamfront.errors.DataError` naming the file. Before anything is decoded, the
width and height the file declares in its header are checked against the limit
``image_pixels`` (:mod:`slamfront.limits`): a 1 MB PNG may declare 20000x20000 pixels and
ask for gigabytes.
"""

from __future__ import annotations

import io
import re
import struct
import warnings
from collections.abc import Sequence
from pathlib import Path
from struct import error as struct_error
from typing import Literal

import numpy as np

from slamfront.errors import DataError
from slamfront.lazy import lazy_module
from slamfront.limits import over_limit

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm", ".tif", ".tiff", ".webp")


def declared_size(data: bytes, what: str) -> tuple[int, int]:
    """``(width, height)`` an encoded image declares in its header, read without decoding it.

    Pillow's format readers parse the header (Pillow's own size cap is not applied: the
    limit here decides, and can be raised).

    :raises DataError: no reader understands the header, or it declares more pixels than
        the limit ``image_pixels`` allows (naming ``what`` and the size).
    """
    size = _png_size(data)
    if size is not None:
        return _checked_size(size, what)
    from PIL import Image

    Image.init()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in Image.ID:  # as Image.open tries them, without its decompression-bomb cap
            factory, accept = Image.OPEN[name]
            if accept is not None and accept(data[:16]) is not True:
                continue
            try:
                size = factory(io.BytesIO(data), "").size  # the format's header parser only
                break
            except (SyntaxError, IndexError, TypeError, ValueError, OSError, struct_error):
                continue
    if size is None:
        raise DataError(f"{what}: not a readable image (no image format recognises its header)")
    return _checked_size(size, what)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_size(data: bytes) -> tuple[int, int] | None:
    """A PNG's ``(width, height)`` from its IHDR chunk, which the format puts first
    (read as Pillow's PNG reader reads it, without its ~0.3 ms of format probing per
    image); None when ``data`` does not start as a well-formed PNG (Pillow then decides)."""
    if len(data) < 24 or data[:8] != _PNG_SIGNATURE or data[8:16] != b"\x00\x00\x00\rIHDR":
        return None
    width, height = struct.unpack(">II", data[16:24])
    return (width, height) if width > 0 and height > 0 else None


def _checked_size(size: tuple[int, int], what: str) -> tuple[int, int]:
    """``size`` if its pixel count is within the ``image_pixels`` limit, else a DataError naming ``what``."""
    width, height = size
    problem = over_limit(
        "image_pixels", width * height, f"the pixel count of the {width}x{height} image it declares"
    )
    if problem:
        raise DataError(f"{what}: {problem}")
    return width, height


def decode_image(data: bytes, what: str, mode: Literal["rgb", "gray", "unchanged"] = "rgb") -> np.ndarray:
    """Decode an encoded image (PNG, JPEG, ...), its declared size checked first.

    :param what: the file or message the bytes come from, named in the error.
    :param mode: ``rgb``: uint8 ``(H, W, 3)``; ``gray``: uint8 ``(H, W)`` (16-bit images
        scaled to 8 bits, alpha dropped); ``unchanged``: bit depth and channels as stored
        (grey ``(H, W)``, colour ``(H, W, 3)`` RGB or ``(H, W, 4)`` RGBA).
    :raises DataError: empty, undecodable, or larger than the ``image_pixels`` limit.
    """
    if not data:
        raise DataError(f"{what}: empty image (0 bytes)")
    declared_size(data, what)
    image = _decode(data, what, cv2.IMREAD_UNCHANGED)
    if mode == "unchanged":
        if image.ndim == 3 and image.shape[2] in (3, 4):
            return cv2.cvtColor(image, cv2.COLOR_BGR2RGB if image.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)
        return image
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    if image.dtype != np.uint8:
        raise DataError(f"{what}: unsupported pixel type {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    if mode == "gray":
        return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return cv2.cvtColor(image, cv2.COLOR_GRAY2RGB) if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _decode(data: bytes, what: str, flags: int) -> np.ndarray:
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error as exc:  # e.g. a size beyond OpenCV's own pixel cap, when the limit allows it
        text = " ".join(str(exc).split())
        if "CV_IO_MAX_IMAGE_PIXELS" in text:
            reason = "its size is beyond OpenCV's cap of 2^30 pixels (the environment variable CV_IO_MAX_IMAGE_PIXELS)"
        else:
            reason = re.sub(r"^.*?error: \(-?\d+:[^)]*\)\s*", "", text) or "OpenCV refused it"
        raise DataError(f"{what}: cannot decode the image: {reason}") from None
    if image is None or image.size == 0:
        raise DataError(f"{what}: not a readable image (corrupt or unsupported format)")
    return image


def read_image(path: Path, mode: Literal["rgb", "gray"] = "rgb") -> np.ndarray:
    """An image as uint8 RGB ``(H, W, 3)`` or grey ``(H, W)``.

    16-bit images are scaled to 8 bits. :raises DataError: missing, empty, undecodable or
    over the ``image_pixels`` limit.
    """
    return decode_image(_read_bytes(path), str(path), mode)


def read_depth(path: Path, scale: float, shape: Sequence[int] | None = None) -> np.ndarray:
    """A depth image as float32 metres (0 where the sensor gave no return).

    :param scale: raw units per metre (1000 for millimetres, 5000 for TUM/ICL).
    :param shape: the expected ``(H, W)``; a mismatch is a :class:`DataError`.
    """
    data = _read_bytes(path)
    declared_size(data, str(path))
    raw = _decode(data, f"{path} (a depth image)", cv2.IMREAD_ANYDEPTH)
    if raw.ndim != 2:
        raise DataError(f"{path}: a depth image must have one channel, this one has {raw.shape[2]}")
    if shape is not None and tuple(raw.shape) != tuple(shape[:2]):
        raise DataError(
            f"{path}: depth is {raw.shape[1]}x{raw.shape[0]} but the colour image is {shape[1]}x{shape[0]}"
        )
    if scale <= 0:
        raise DataError(f"{path}: depth scale must be positive, got {scale}")
    return (raw.astype(np.float32) / np.float32(scale)).astype(np.float32)


def natural_key(path: Path) -> list[object]:
    """Sort key that orders ``2.png`` before ``10.png`` (numbers compared as numbers)."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", Path(path).name)]


def list_images(folder: Path, pattern: str = "*") -> list[Path]:
    """Image files in ``folder`` matching ``pattern``, in natural name order (2 before 10).

    :raises DataError: the folder is missing or holds no images.
    """
    if not folder.is_dir():
        raise DataError(f"{folder}: no such image folder")
    files = sorted(
        (p for p in folder.glob(pattern) if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()), key=natural_key
    )
    if not files:
        raise DataError(f"{folder}: no images matching {pattern!r}")
    return files


def _read_bytes(path: Path) -> bytes:
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if not data:
        raise DataError(f"{path}: empty file (0 bytes)")
    return data
