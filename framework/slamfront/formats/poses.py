"""Trajectory files: TUM, KITTI, ``pose.txt`` lines and Redwood/Open3D ``.log`` files.

- TUM: ``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments.
- pose lines: ``tx ty tz qx qy qz qw`` per line (frame i on line i), as the slambook
  RGB-D samples store camera-to-world poses.
- KITTI: 12 numbers per line, the top three rows of a 4x4 transform, row-major.
- Redwood/Open3D log: a header line ``i j n`` then four lines of a 4x4 matrix.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np

from slamfront.core.errors import CoreError
from slamfront.core.geometry import pose_from_quaternion, poses_from_quaternions, quaternions_of
from slamfront.errors import DataError
from slamfront.outputs import write_atomically


@dataclass(frozen=True)
class Trajectory:
    """Poses with timestamps.

    :ivar timestamps: (N,) seconds (frame numbers for formats without time).
    :ivar poses: (N, 4, 4) camera-to-world transforms.
    """

    timestamps: np.ndarray
    poses: np.ndarray

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) translations."""
        return self.poses[:, :3, 3]


def numbered_fields(path: Path) -> Iterator[tuple[int, list[str]]]:
    """(line number, fields) of each non-empty, non-comment line."""
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read: {exc}") from exc
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.split("#", 1)[0].strip()
        if stripped:
            yield number, stripped.replace(",", " ").split()


def _floats(path: Path, number: int, fields: list[str], expected: int, what: str) -> np.ndarray:
    if len(fields) != expected:
        raise DataError(f"{path}:{number}: expected {expected} numbers ({what}), got {len(fields)}")
    try:
        values = np.array([float(f) for f in fields], dtype=np.float64)
    except ValueError:
        raise DataError(f"{path}:{number}: not a number in {' '.join(fields)!r}") from None
    if not np.all(np.isfinite(values)):
        raise DataError(f"{path}:{number}: non-finite value")
    return values


def _pose(path: Path, number: int, translation: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    try:
        return pose_from_quaternion(translation, quaternion)
    except CoreError as exc:
        raise DataError(f"{path}:{number}: {exc}") from None


def _finish(path: Path, stamps: list[float], poses: list[np.ndarray]) -> Trajectory:
    if not poses:
        raise DataError(f"{path}: no poses in the file")
    return Trajectory(np.array(stamps, dtype=np.float64), np.array(poses))


def read_tum(path: Path) -> Trajectory:
    """A TUM trajectory (``t tx ty tz qx qy qz qw``)."""
    numbers, rows = [], []
    for number, fields in numbered_fields(path):
        rows.append(_floats(path, number, fields, 8, "t tx ty tz qx qy qz qw"))
        numbers.append(number)
    if not rows:
        raise DataError(f"{path}: no poses in the file")
    table = np.array(rows)
    return Trajectory(table[:, 0].copy(), _poses(path, numbers, table[:, 1:4], table[:, 4:8]))


def _poses(path: Path, numbers: list[int], translations: np.ndarray, quaternions: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses of all lines at once, the same values :func:`_pose` gives line by line;
    a bad quaternion is reported with its line number."""
    norms = np.linalg.norm(quaternions, axis=1)
    bad = np.flatnonzero(~np.isfinite(norms) | (norms < 1e-12))
    if len(bad):
        _pose(path, numbers[bad[0]], translations[bad[0]], quaternions[bad[0]])  # raises, naming the line
    return poses_from_quaternions(translations, quaternions, as_single=True)


def read_pose_lines(path: Path) -> Trajectory:
    """``tx ty tz qx qy qz qw`` lines; timestamps are the line indices 0, 1, ..."""
    poses = []
    for number, fields in numbered_fields(path):
        values = _floats(path, number, fields, 7, "tx ty tz qx qy qz qw")
        poses.append(_pose(path, number, values[0:3], values[3:7]))
    return _finish(path, list(range(len(poses))), poses)


def read_kitti(path: Path) -> Trajectory:
    """KITTI poses (12 numbers per line); timestamps are the line indices."""
    poses = []
    for number, fields in numbered_fields(path):
        values = _floats(path, number, fields, 12, "a 3x4 matrix, row-major")
        pose = np.eye(4)
        pose[:3, :4] = values.reshape(3, 4)
        poses.append(pose)
    return _finish(path, list(range(len(poses))), poses)


def read_redwood_log(path: Path) -> Trajectory:
    """A Redwood/Open3D ``.log`` trajectory; timestamps are the frame ids of the headers."""
    rows = list(numbered_fields(path))
    if len(rows) % 5:
        raise DataError(f"{path}: {len(rows)} lines is not a whole number of 5-line entries (header + 4x4)")
    stamps, poses = [], []
    for k in range(0, len(rows), 5):
        number, header = rows[k]
        if len(header) != 3:
            raise DataError(f"{path}:{number}: expected a header 'i j n', got {' '.join(header)!r}")
        matrix = np.array([_floats(path, n, f, 4, "a matrix row") for n, f in rows[k + 1 : k + 5]])
        stamps.append(float(header[0]))
        poses.append(matrix)
    return _finish(path, stamps, poses)


def write_tum(path: Path, trajectory: Trajectory) -> Path:
    """Write ``t tx ty tz qx qy qz qw`` lines (full float precision), atomically and never
    through a link at ``path`` (:func:`slamfront.outputs.write_atomically`)."""
    table = np.column_stack([trajectory.timestamps, trajectory.poses[:, :3, 3], quaternions_of(trajectory.poses)])
    lines = (" ".join(map(repr, row)) for row in table.tolist())
    return write_atomically(Path(path), "\n".join(lines) + "\n")


TRAJECTORY_READERS: Mapping[str, Callable[[Path], Trajectory]] = MappingProxyType(
    {"tum": read_tum, "kitti": read_kitti, "pose_lines": read_pose_lines, "redwood_log": read_redwood_log}
)
"""Trajectory file readers by format name."""


def in_time_order(trajectory: Trajectory, path: Path, keep: str | None = None) -> Trajectory:
    """``trajectory`` with increasing timestamps, or a one-line error saying how many are not.

    A timed trajectory whose timestamps repeat or go back cannot be associated by time:
    an estimate written twice over (0-2.4 s, then 0-2.4 s again) would pair only one of
    each two poses and score the other half as if it were not there.

    :param keep: ``first`` or ``last``: keep that pose of each timestamp and sort by time,
        instead of refusing.
    :raises DataError: timestamps repeat or decrease and ``keep`` is None.
    """
    stamps = trajectory.timestamps
    repeated = len(stamps) - len(np.unique(stamps))
    backwards = int(np.count_nonzero(np.diff(stamps) < 0))
    if not repeated and not backwards:
        return trajectory
    if keep is None:
        raise DataError(
            f"{path}: {repeated} of its {len(stamps)} timestamps repeat an earlier one and {backwards} go back in "
            "time, so poses cannot be associated by time; pass --repeated first or --repeated last to keep one "
            "pose per timestamp, in time order"
        )
    if keep not in ("first", "last"):
        raise ValueError(f"keep must be 'first' or 'last', not {keep!r}")
    order = np.arange(len(stamps)) if keep == "first" else np.arange(len(stamps))[::-1]
    _, chosen = np.unique(stamps[order], return_index=True)  # sorted by time, first occurrence in `order`
    indices = order[chosen]
    return Trajectory(stamps[indices], trajectory.poses[indices])
