"""Whole-image thumbnails: the simplest global descriptor (SeqSLAM-style patch normalisation)."""

from __future__ import annotations

import cv2
import numpy as np


def patch_normalise(image: np.ndarray, patch: int) -> np.ndarray:
    """Each ``patch`` x ``patch`` block of a float image to zero mean and unit std.

    Flat blocks (std 0) become 0. The image sides must be multiples of ``patch``.
    """
    h, w = image.shape
    blocks = image.reshape(h // patch, patch, w // patch, patch)
    mean = blocks.mean(axis=(1, 3), keepdims=True)
    std = blocks.std(axis=(1, 3), keepdims=True)
    normalised = np.where(std > 1e-6, (blocks - mean) / np.maximum(std, 1e-6), 0.0)
    return normalised.reshape(h, w)


def thumbnail(grey: np.ndarray, width: int, height: int, patch: int | None = 8) -> np.ndarray:
    """(width * height,) float32 zero-mean unit-norm thumbnail of a uint8 ``(H, W)`` image.

    :param patch: block side for patch normalisation (sides must be multiples of it);
        None equalises the histogram of the whole image instead.
    """
    if patch is None:
        grey = cv2.equalizeHist(grey)
    small = cv2.resize(grey, (width, height), interpolation=cv2.INTER_AREA).astype(np.float32)
    if patch is not None:
        small = patch_normalise(small, patch)
    vector = (small - small.mean()).ravel().astype(np.float32)
    norm = float(np.linalg.norm(vector))
    return vector / norm if norm > 0 else vector
