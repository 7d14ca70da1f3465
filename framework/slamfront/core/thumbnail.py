"""Whole-image thumbnails: the simplest global descriptor (SeqSLAM-style patch normalisation),
and MATLAB's ``imresize`` as OpenSeqSLAM shrinks its images."""

from __future__ import annotations

import functools

import numpy as np

from slamfront.lazy import lazy_module

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it


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


def lanczos3(x: np.ndarray) -> np.ndarray:
    """MATLAB ``imresize``'s Lanczos-3 kernel, with its ``eps`` guard against 0 / 0 at x = 0."""
    eps = np.finfo(np.float64).eps
    f = (np.sin(np.pi * x) * np.sin(np.pi * x / 3) + eps) / ((np.pi**2 * x**2 / 3) + eps)
    return f * (np.abs(x) < 3)


@functools.lru_cache(maxsize=32)
def resize_weights(in_length: int, out_length: int) -> np.ndarray:
    """(out_length, in_length) float64 matrix of MATLAB ``imresize``'s Lanczos-3 weights
    along one axis (its ``contributions``): the kernel is stretched by ``1 / scale`` when
    shrinking (antialiasing), each output's weights sum to 1, and taps beyond the image
    are mirrored back into it. Read-only."""
    scale = out_length / in_length
    width = 6.0
    kernel = lanczos3
    if scale < 1:  # antialiasing: a low-pass as wide as the pixels one output pixel covers

        def kernel(x: np.ndarray) -> np.ndarray:
            return scale * lanczos3(scale * x)

        width = width / scale
    u = np.arange(1, out_length + 1) / scale + 0.5 * (1 - 1 / scale)  # 1-based, as MATLAB
    left = np.floor(u - width / 2)
    taps = int(np.ceil(width)) + 2
    indices = left[:, None] + np.arange(taps)[None, :]
    weights = kernel(u[:, None] - indices)
    weights = weights / weights.sum(axis=1, keepdims=True)
    mirror = np.concatenate([np.arange(in_length), np.arange(in_length)[::-1]])  # MATLAB's symmetric aux
    columns = mirror[np.mod(indices.astype(np.int64) - 1, 2 * in_length)]
    matrix = np.zeros((out_length, in_length))
    np.add.at(matrix, (np.repeat(np.arange(out_length), taps), columns.ravel()), weights.ravel())
    matrix.flags.writeable = False
    return matrix


def imresize(images: np.ndarray, height: int, width: int) -> np.ndarray:
    """MATLAB ``imresize(I, [height width], 'lanczos3')`` of uint8 grey images (..., H, W).

    As MATLAB: separable, the axis that shrinks most first, each pass rounded (half away
    from zero) and saturated to uint8, antialiased when shrinking; an axis whose length
    does not change is left alone (MATLAB's pass there is the identity after rounding).
    A stack of images is resized in one product per axis.
    """
    images = np.asarray(images)
    h, w = images.shape[-2:]
    out = images
    for axis in sorted((0, 1), key=lambda a: (height / h, width / w)[a]):
        size_in, size_out = (h, w)[axis], (height, width)[axis]
        if size_in == size_out:
            continue
        weights = resize_weights(size_in, size_out)
        values = weights @ out if axis == 0 else out @ weights.T
        out = np.clip(np.sign(values) * np.floor(np.abs(values) + 0.5), 0, 255).astype(np.uint8)
    return out
