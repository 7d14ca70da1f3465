"""Reading images and depth maps with one clear error per bad file.

Every source reads pixels through these functions, so a corrupt, empty or missing file
always ends the same way: a :class:`~slamfront.errors.DataError` naming the file.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from slamfront.errors import DataError
from slamfront.lazy import lazy_module

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm", ".tif", ".tiff", ".webp")


def read_image(path: Path, mode: Literal["rgb", "gray"] = "rgb") -> np.ndarray:
    """An image as uint8 RGB ``(H, W, 3)`` or grey ``(H, W)``.

    16-bit images are scaled to 8 bits. :raises DataError: missing, empty or undecodable.
    """
    data = _read_bytes(path)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise DataError(f"{path}: not a readable image (corrupt or unsupported format)")
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    if image.dtype != np.uint8:
        raise DataError(f"{path}: unsupported pixel type {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    if mode == "gray":
        return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return cv2.cvtColor(image, cv2.COLOR_GRAY2RGB) if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def read_depth(path: Path, scale: float, shape: Sequence[int] | None = None) -> np.ndarray:
    """A depth image as float32 metres (0 where the sensor gave no return).

    :param scale: raw units per metre (1000 for millimetres, 5000 for TUM/ICL).
    :param shape: the expected ``(H, W)``; a mismatch is a :class:`DataError`.
    """
    data = _read_bytes(path)
    raw = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_ANYDEPTH)
    if raw is None or raw.size == 0:
        raise DataError(f"{path}: not a readable depth image")
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
