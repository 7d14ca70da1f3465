"""The ``onnx`` descriptor on models the tests build themselves (no download)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slamfront.errors import DataError, PluginError
from slamfront.mcaplog.diff import diff_logs
from slamfront.mcaplog.reader import read_messages
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.replay import replay_log
from slamfront.runtime import run_pipeline
from slamfront_plugins.descriptors.onnx_model import OnnxDescriptor, Preprocessing, file_sha256
from tests.helpers import small_synthetic_recipe
from tests.onnx_models import build_model, reference


def _descriptor(model: Path, **params) -> OnnxDescriptor:
    params.setdefault("preprocessing", {"width": 32, "height": 24})
    d = OnnxDescriptor(OnnxDescriptor.Config(model=model, **params))
    d.check({})
    return d


def _images(n: int, shape=(48, 64, 3), seed: int = 1) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(n)]


@pytest.mark.parametrize("aggregation", ["gem", "netvlad"])
def test_outputs_match_a_numpy_implementation_of_the_graph(tmp_path: Path, aggregation: str) -> None:
    d = _descriptor(build_model(tmp_path / "m.onnx", aggregation=aggregation), l2_normalise=False)
    images = _images(5)
    tensors = np.stack([d.config.preprocessing.tensor(i) for i in images])
    expected = reference(tensors, aggregation=aggregation)
    np.testing.assert_allclose(d.describe_many(images), expected, rtol=1e-4, atol=1e-4 * np.abs(expected).max())
    unit = _descriptor(tmp_path / "m.onnx").describe_many(images)
    np.testing.assert_allclose(np.linalg.norm(unit, axis=1), 1.0, rtol=1e-5)


def test_batch_size_does_not_change_the_vectors(tmp_path: Path) -> None:
    model = build_model(tmp_path / "m.onnx")
    images = _images(7)
    one = _descriptor(model, batch_size=1).describe_many(images)
    many = _descriptor(model, batch_size=3).describe_many(images)
    np.testing.assert_allclose(one, many, rtol=1e-5, atol=1e-6)
    assert _descriptor(model, batch_size=3)._max_batch == 3
    assert _descriptor(build_model(tmp_path / "fixed.onnx", batch=1))._max_batch == 1  # a fixed batch of 1 is kept


def test_preprocessing_colour_order_normalisation_and_layout(tmp_path: Path) -> None:
    image = _images(1, (24, 32, 3))[0]
    rgb = Preprocessing(width=32, height=24, mean=(0.5, 0.25, 0.0), std=(0.5, 0.25, 1.0))
    tensor = rgb.tensor(image)
    assert tensor.shape == (3, 24, 32)
    np.testing.assert_allclose(tensor[1], (image[:, :, 1] / 255 - 0.25) / 0.25, rtol=1e-5, atol=1e-5)
    bgr = Preprocessing(width=32, height=24, colour="bgr", mean=(0, 0, 0), std=(1, 1, 1), scale=1.0)
    np.testing.assert_array_equal(bgr.tensor(image)[0], image[:, :, 2])
    nhwc = Preprocessing(width=32, height=24, layout="nhwc")
    np.testing.assert_allclose(nhwc.tensor(image), Preprocessing(width=32, height=24).tensor(image).transpose(1, 2, 0))
    grey = Preprocessing(width=32, height=24, colour="grey", mean=(0.0,), std=(1.0,))
    assert grey.tensor(image).shape == (1, 24, 32)
    # a grey frame feeds an RGB model with its one channel three times
    flat = image[:, :, 0]
    same = Preprocessing(width=32, height=24, mean=(0.1, 0.1, 0.1), std=(0.3, 0.3, 0.3)).tensor(flat)
    assert np.array_equal(same[0], same[2]) and np.array_equal(same[0], same[1])


def test_keep_aspect_rounds_both_sides_to_the_multiple(tmp_path: Path) -> None:
    p = Preprocessing(size="keep_aspect", short_side=28, multiple_of=14)
    assert p.input_size(480, 640) == (28, 42)
    assert p.tensor(_images(1, (480, 640, 3))[0]).shape == (3, 28, 42)
    d = _descriptor(build_model(tmp_path / "m.onnx"), preprocessing=p.model_dump())
    assert d.describe(_images(1, (480, 640, 3))[0]).shape == (16,)


def test_nhwc_model(tmp_path: Path) -> None:
    model = build_model(tmp_path / "m.onnx", layout="nhwc")
    images = _images(3)
    nhwc = _descriptor(model, preprocessing={"width": 32, "height": 24, "layout": "nhwc"}).describe_many(images)
    nchw = _descriptor(build_model(tmp_path / "c.onnx")).describe_many(images)
    np.testing.assert_allclose(nhwc, nchw, rtol=1e-5, atol=1e-6)


def test_projection_from_npy(tmp_path: Path) -> None:
    model = build_model(tmp_path / "m.onnx")
    rng = np.random.default_rng(3)
    matrix, mean = rng.normal(size=(16, 4)), rng.normal(size=16)
    np.save(tmp_path / "p.npy", matrix)
    np.save(tmp_path / "mu.npy", mean)
    images = _images(3)
    raw = _descriptor(model, l2_normalise=False).describe_many(images).astype(np.float64)
    projected = _descriptor(model, projection=tmp_path / "p.npy", projection_mean=tmp_path / "mu.npy").describe_many(images)
    expected = (raw - mean) @ matrix
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(projected, expected, rtol=1e-4, atol=1e-5)
    np.save(tmp_path / "bad.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(DataError, match="not a readable .npy"):
        _descriptor(model, projection=tmp_path / "bad.npy")
    np.save(tmp_path / "wrong.npy", rng.normal(size=(5, 4)))
    with pytest.raises(PluginError, match="5 rows for a model output of 16"):
        _descriptor(model, projection=tmp_path / "wrong.npy").describe(images[0])


def test_refusals(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ValueError, match="does not exist"):
        OnnxDescriptor.Config(model=tmp_path / "none.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(DataError, match="not a readable ONNX model"):
        _descriptor(tmp_path / "junk.onnx")
    fixed = build_model(tmp_path / "fixed.onnx", height=24, width=32)
    _descriptor(fixed)  # fits 32 x 24
    with pytest.raises(PluginError, match="fixed at 32x24"):
        _descriptor(fixed, preprocessing={"width": 64, "height": 48})
    with pytest.raises(PluginError, match="3 channels"):
        _descriptor(fixed, preprocessing={"width": 32, "height": 24, "colour": "grey", "mean": [0], "std": [1]})
    with pytest.raises(PluginError, match="batch dimension is fixed at 4"):
        _descriptor(build_model(tmp_path / "b4.onnx", batch=4))
    with pytest.raises(PluginError, match="no output 'x'"):
        _descriptor(fixed, output="x")
    with pytest.raises(DataError, match="NaN or infinite"):
        _descriptor(build_model(tmp_path / "nan.onnx", nan=True)).describe(_images(1)[0])
    monkeypatch.setenv("SLAMFRONT_LIMITS", "model_bytes=100")
    with pytest.raises(ValueError, match="over the limit of 100"):
        OnnxDescriptor.Config(model=fixed)


def test_cli_refusals_are_one_line(tmp_path: Path, cli) -> None:
    model = build_model(tmp_path / "nan.onnx", nan=True)
    import yaml

    for name, params, expect in (("missing", {"model": str(tmp_path / "none.onnx")}, "does not exist"),
                                 ("nan", {"model": str(model), "preprocessing": {"width": 32, "height": 24}},
                                  "NaN or infinite")):
        raw = small_synthetic_recipe(frames_per_traversal=10)
        raw["descriptor"] = {"plugin": "onnx", "params": params}
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(raw))
        code, _, err = cli("run", path, "-o", tmp_path / name, "-q")
        assert code == 2 and err.strip().count("\n") == 0 and expect in err, err


@pytest.mark.parametrize("detector", ["hierarchical_sequence", "seqslam", "nearest_neighbour"])
def test_a_recipe_runs_logs_validates_and_replays(tmp_path: Path, detector: str, cli) -> None:
    model = build_model(tmp_path / "m.onnx")
    raw = small_synthetic_recipe()
    raw["descriptor"] = {"plugin": "onnx", "params": {"model": str(model), "preprocessing": {"width": 32, "height": 24}}}
    raw["loop_detector"] = {"plugin": detector, "params": {"ds": 6} if detector == "seqslam" else {}}
    if detector == "hierarchical_sequence":
        raw["place_map"] = {"plugin": "hierarchical"}
        raw["loop_detector"]["params"] = {"rho": 3, "sequence_frames": 12}
    recipe = parse_recipe(raw, "onnx.yaml")
    result = run_pipeline(build_pipeline(recipe, "onnx.yaml"), "onnx.yaml", tmp_path / "run", progress=False)
    assert result.metrics["onnx_model_sha256"] == file_sha256(model)
    assert "CPUExecutionProvider" in result.metrics["onnx_providers"]
    lines = [m.decoded.message for m in read_messages(result.log_path, ["/log"])]
    assert any(file_sha256(model) in line and "CPUExecutionProvider" in line for line in lines)
    code, out, err = cli("inspect", result.log_path, "--validate")
    assert code == 0, out + err
    # the log's recipe names a model file outside the data root: a replay needs the user's trust
    replay = replay_log(result.log_path, tmp_path / "replay", progress=False, trust_log=True)
    assert diff_logs(result.log_path, replay.log_path).identical
