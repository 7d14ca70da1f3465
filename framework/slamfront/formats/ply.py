"""Writing point clouds as binary PLY (read by Open3D, MeshLab, CloudCompare, PCL)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamfront.errors import DataError
from slamfront.outputs import write_atomically


def write_ply(path: Path, points: np.ndarray, colors: np.ndarray | None = None) -> Path:
    """Write ``(N, 3)`` points (float32) and optional ``(N, 3)`` uint8 RGB colours.

    Written to a temporary file and renamed, so a crash never leaves half a model.

    :raises DataError: the arrays have the wrong shape, or the file cannot be written.
    """
    path = Path(path)
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise DataError(f"{path}: points must be (N, 3), got {points.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != points.shape:
            raise DataError(f"{path}: colours must be (N, 3) like the points, got {colors.shape}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rows = np.empty(len(points), dtype=fields)
    for axis, name in enumerate("xyz"):
        rows[name] = points[:, axis]
    if colors is not None:
        for channel, name in enumerate(("red", "green", "blue")):
            rows[name] = colors[:, channel]
    types = {"<f4": "float", "u1": "uchar"}
    header = "\n".join([
        "ply",
        "format binary_little_endian 1.0",
        "comment written by slamfront",
        f"element vertex {len(points)}",
        *(f"property {types[kind]} {name}" for name, kind in fields),
        "end_header",
    ]) + "\n"
    try:
        write_atomically(path, header.encode("ascii") + rows.tobytes())
    except OSError as exc:
        raise DataError(f"{path}: cannot write: {exc.strerror or exc}") from exc
    return path
