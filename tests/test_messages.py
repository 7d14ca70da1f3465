"""Messages round-trip bit-exactly through their JSON encoding."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from slamfront.message_types import shared_message_types
from slamfront.messages import Features, FrameInfo, LoopResult, RunMetrics, decode_any


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint8, np.int64, np.int16, ">f4"])
def test_arrays_round_trip_bit_exactly(dtype: str) -> None:
    rng = np.random.default_rng(1)
    array = (rng.normal(size=(7, 5)) * 100).astype(dtype)
    message = Features(frame=3, keypoints=array[:, :2].copy(), descriptors=array, metric="l2")
    back = Features.from_json(message.to_json())
    assert back.descriptors.dtype == array.dtype
    assert back.descriptors.shape == array.shape
    assert back.descriptors.tobytes() == array.tobytes()
    assert back.same_as(message)


def test_special_floats_and_none_round_trip() -> None:
    message = LoopResult(frame=1, match=-1, confidence=float("nan"), accepted=False, reason="no answer")
    text = message.to_json()
    json.loads(text)  # strict JSON: no bare NaN
    back = LoopResult.from_json(text)
    assert math.isnan(back.confidence) and back.candidates is None and back.reason == "no answer"
    inf = LoopResult.from_json(LoopResult(frame=1, match=2, confidence=float("-inf"), accepted=True).to_json())
    assert inf.confidence == float("-inf")


def test_nan_and_negative_zero_bits_survive_inside_arrays() -> None:
    array = np.array([np.nan, -0.0, np.inf, 1e-310], dtype=np.float64)
    back = Features.from_json(Features(frame=0, vector=array).to_json())
    assert back.vector.tobytes() == array.tobytes()


def test_decode_without_the_class_gives_arrays() -> None:
    pose = np.arange(16, dtype=np.float64).reshape(4, 4)
    info = FrameInfo(frame=0, timestamp=0.5, traversal="stream", sequence_index=0, name="a", width=2, height=2, pose=pose)
    raw = decode_any(info.to_json())
    assert np.array_equal(raw["pose"], pose)


def test_schema_lists_every_field_and_lookup_by_name() -> None:
    schema = LoopResult.json_schema()
    assert set(schema["properties"]) == {"frame", "match", "confidence", "accepted", "candidates", "reason",
                                          "match_frames", "searched"}
    assert schema["title"] == "slamfront.LoopResult"
    assert shared_message_types().get("slamfront.RunMetrics") is RunMetrics


def test_plotted_arrays_are_also_plain_numbers_and_still_round_trip() -> None:
    pose = np.eye(4)
    pose[:3, 3] = [1.5, -2.0, float("nan")]
    info = FrameInfo(frame=3, timestamp=0.5, traversal="stream", sequence_index=3, name="f", width=4, height=3,
                     pose=pose)
    raw = json.loads(info.to_json())
    assert raw["pose_values"][3] == 1.5 and raw["pose_values"][7] == -2.0 and raw["pose_values"][11] is None
    assert len(raw["pose_values"]) == 16 and raw["pose"]["dtype"] == "<f8"  # the exact copy is still there
    back = FrameInfo.from_json(info.to_json())
    assert back.to_json() == info.to_json() and np.array_equal(back.pose, pose, equal_nan=True)
    assert "pose_values" in FrameInfo.json_schema()["properties"]
    assert json.loads(FrameInfo(frame=0, timestamp=0.0, traversal="s", sequence_index=0, name="", width=1,
                                height=1).to_json())["pose_values"] is None
    assert "vector_values" not in json.loads(Features(frame=0, vector=np.ones(3)).to_json())  # not plotted


def test_encoding_is_the_bytes_json_dumps_writes() -> None:
    # to_json writes an array's base64 text without the JSON encoder; the bytes stay those
    # of json.dumps of the encoded fields
    import dataclasses

    from slamfront.message_codec import PLAIN_SUFFIX, encode_value, plain_values
    from slamfront.messages import Trajectory

    rng = np.random.default_rng(2)
    messages = [
        Features(frame=1, vector=rng.random(1152).astype(np.float32), metric="l1"),
        Features(frame=2, vector=np.zeros(0, dtype=np.uint8), descriptors=np.asfortranarray(rng.random((3, 4))),
                 keypoints=np.ones((2, 2), dtype=">f4")[:, ::-1], metric="hamming"),
        LoopResult(frame=1, match=-1, confidence=float("nan"), accepted=False, reason='"quoted" \u00e9 \\ \n',
                   candidates=np.array(5, dtype=np.int64)),
        RunMetrics(values={"a": [1.0, float("inf"), {"b": np.array([True, False])}], "\u00e9": -0.0}),
        FrameInfo(frame=4, timestamp=1e-300, traversal="query", sequence_index=0, name="x", width=1, height=1,
                  pose=np.eye(4)),
        Trajectory(label="\u00fc", frames=np.arange(3)[::-1], poses=np.full((3, 4, 4), np.nan)),
    ]
    for message in messages:
        payload = {f.name: encode_value(getattr(message, f.name)) for f in dataclasses.fields(message)}
        for name in message.plain_fields:
            payload[f"{name}{PLAIN_SUFFIX}"] = plain_values(getattr(message, name))
        assert message.to_json() == json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()
