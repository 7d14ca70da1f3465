"""Messages as .npz files: data only (no pickle), bit for bit, bad files as one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slamfront.errors import DataError
from slamfront.formats.npz import read_message_npz, write_message_npz
from slamfront_plugins.localizers.messages import KeyframeMap, PoseEstimate


def _map() -> KeyframeMap:
    rng = np.random.default_rng(1)
    return KeyframeMap(
        frames=np.array([3, 9], np.int64), poses=rng.normal(size=(2, 4, 4)), scenes=["", "elsewhere"],
        edges=np.array([[0, 1]], np.int64), descriptor="orb", metric="hamming",
        offsets=np.array([0, 2, 5], np.int64), keypoints=rng.normal(size=(5, 2)).astype(np.float32),
        descriptors=rng.integers(0, 256, (5, 32), dtype=np.uint8),
        points=np.where(rng.random((5, 3)) < 0.2, np.nan, rng.normal(size=(5, 3))).astype(np.float32),
    )


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    message = _map()
    back = read_message_npz(write_message_npz(tmp_path / "map.npz", message), KeyframeMap)
    assert back.same_as(message) and back.vectors is None and back.scenes == ["", "elsewhere"]
    with np.load(tmp_path / "map.npz", allow_pickle=False) as archive:  # any numpy program can read it
        assert archive["descriptor"] == "orb" and archive["descriptors"].dtype == np.uint8


def test_bad_files_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="missing.npz: no such file"):
        read_message_npz(tmp_path / "missing.npz", KeyframeMap)
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(DataError, match="junk.npz: not a readable .npz archive"):
        read_message_npz(tmp_path / "junk.npz", KeyframeMap)
    write_message_npz(tmp_path / "other.npz", PoseEstimate(frame=1, keyframe=-1))
    with pytest.raises(DataError, match="holds a slamfront.PoseEstimate message, expected slamfront.KeyframeMap"):
        read_message_npz(tmp_path / "other.npz", KeyframeMap)
    np.savez(tmp_path / "pickled.npz", __schema__=np.array("slamfront.KeyframeMap"),
             frames=np.array([{"a": 1}], dtype=object))
    with pytest.raises(DataError, match="pickled.npz"):  # object arrays are refused, never unpickled
        read_message_npz(tmp_path / "pickled.npz", KeyframeMap)
    np.savez(tmp_path / "field.npz", __schema__=np.array("slamfront.KeyframeMap"), frames=np.arange(2),
             descriptor=np.arange(3))
    with pytest.raises(DataError, match="field.npz: descriptor: expected one value"):
        read_message_npz(tmp_path / "field.npz", KeyframeMap)
