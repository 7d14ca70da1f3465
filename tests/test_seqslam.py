"""SeqSLAM step by step against hand-computed cases and a literal port of OpenSeqSLAM's loops."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slamfront.core.errors import CoreError
from slamfront.core.seqslam import (
    best_match,
    difference_columns,
    enhance_contrast,
    enhanced_lower_bound,
    matlab_round,
    patch_normalise,
    sequence_scores,
    sequence_scores_block,
    trajectory_offsets,
)
from slamfront.errors import PluginError
from slamfront.frame import Frame
from slamfront.messages import Features, LoopResult
from slamfront.plugin import StageInputs
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.runtime import run_pipeline
from slamfront_plugins.loop_detectors.seqslam import SeqSlam, SeqSlamFast


def test_matlab_rounding_is_half_away_from_zero() -> None:
    assert matlab_round(np.array([0.5, 1.5, 2.5, -0.5, -1.5, 0.49])).tolist() == [1, 2, 3, -1, -2, 0]


def test_patch_normalisation_by_hand() -> None:
    patch = np.arange(64, dtype=np.uint8).reshape(8, 8)
    image = np.hstack([patch, np.full((8, 8), 200, np.uint8)])
    out = patch_normalise(image, side=8)
    # mean 31.5, sample std sqrt(21840 / 63) = 18.619: 0 -> 127 + round(-1.692) = 125
    std = np.sqrt(np.sum((np.arange(64) - 31.5) ** 2) / 63)
    expected = 127 + matlab_round((np.arange(64) - 31.5) / std)
    assert out[:, :8].ravel().tolist() == expected.astype(int).tolist()
    assert out[0, 0] == 125 and out[7, 7] == 129
    assert np.all(out[:, 8:] == 0)  # a flat patch: MATLAB's uint8(NaN) is 0


def test_patch_normalisation_leaves_a_partial_border() -> None:
    image = np.random.default_rng(0).integers(0, 255, (10, 12), dtype=np.uint8)
    out = patch_normalise(image, side=8)
    assert np.array_equal(out[8:, :], image[8:, :]) and np.array_equal(out[:, 8:], image[:, 8:])


def test_difference_is_mean_absolute_difference_and_chunk_independent() -> None:
    rng = np.random.default_rng(1)
    refs, queries = rng.random((30, 16), np.float32) * 255, rng.random((7, 16), np.float32) * 255
    d = difference_columns(refs, queries, threads=3)
    assert d.shape == (30, 7)
    assert d[4, 5] == pytest.approx(np.abs(refs[4] - queries[5]).mean(), rel=1e-6)
    assert np.array_equal(d, difference_columns(refs, queries))
    assert np.array_equal(d[:, 2:3], difference_columns(refs, queries[2:3]))
    # the uint8 (OpenCV) path gives the same bits as the float path on integer images
    small_refs, small_queries = refs.astype(np.uint8), queries.astype(np.uint8)
    assert np.array_equal(
        difference_columns(small_refs, small_queries),
        difference_columns(small_refs.astype(np.float32), small_queries.astype(np.float32)),
    )


def test_contrast_enhancement_by_hand() -> None:
    d = np.array([[1.0], [2.0], [3.0]])
    # window 2 -> rows i-1..i+1; sample std: row 0 over [1, 2] -> (1 - 1.5) / 0.7071
    out = enhance_contrast(d, window=2)[:, 0]
    assert out.tolist() == pytest.approx([-1 / np.sqrt(2), 0.0, 1 / np.sqrt(2)], rel=1e-6)
    flat = enhance_contrast(np.ones((5, 2)), window=2)
    assert np.all(flat == 0)


def test_contrast_enhancement_matches_the_matlab_loop() -> None:
    d = np.random.default_rng(2).random((40, 6)) * 10
    window = 10
    expected = np.empty_like(d)
    for i in range(len(d)):  # enhanceContrast.m, 0-based
        v = d[max(0, i - window // 2) : min(len(d), i + window // 2 + 1)]
        expected[i] = (d[i] - v.mean(axis=0)) / v.std(axis=0, ddof=1)
    np.testing.assert_allclose(enhance_contrast(d, window), expected, rtol=1e-5, atol=1e-6)
    assert enhance_contrast(d, window).min() >= enhanced_lower_bound(window)


def test_trajectory_offsets() -> None:
    offsets = trajectory_offsets(10, 0.8, 1.2)
    assert offsets.shape == (5, 11)
    assert offsets[0].tolist() == [0, 0, 1, 2, 3, 4, 4, 5, 6, 7, 8]
    assert offsets[2].tolist() == list(range(11))
    assert trajectory_offsets(40, 1.0, 1.5).shape == (21, 41)  # Rodrigues 2019's setting
    with pytest.raises(CoreError, match="even"):
        trajectory_offsets(9, 1.0, 1.0)


def _literal_scores(dd: np.ndarray, ds: int, vmin: float, vmax: float) -> np.ndarray:
    """findSingleMatch's score loop, written out as in the MATLAB file (0-based)."""
    v = np.arange(vmin * ds, vmax * ds + 1e-9) / ds
    idx_add = np.floor(np.arange(ds + 1)[None, :] * v[:, None] + 1e-9).astype(int)
    padded = np.vstack([dd, np.full((1, dd.shape[1]), np.inf)])
    y_max = len(padded) - 1
    scores = np.empty(len(dd))
    for s in range(len(dd)):
        y = np.minimum(idx_add + s, y_max)
        scores[s] = min(padded[y[i], np.arange(ds + 1)].sum() for i in range(len(v)))
    return scores


@pytest.mark.parametrize(("ds", "vmin", "vmax"), [(10, 0.8, 1.2), (6, 1.0, 1.5), (4, 1.0, 1.0)])
def test_vectorised_search_equals_the_literal_loop(ds: int, vmin: float, vmax: float) -> None:
    window = np.random.default_rng(ds).random((50, ds + 1))
    got = sequence_scores(window, trajectory_offsets(ds, vmin, vmax))
    np.testing.assert_allclose(got, _literal_scores(window, ds, vmin, vmax), rtol=1e-12)
    rows = np.array([3, 17, 40])
    partial = sequence_scores(window, trajectory_offsets(ds, vmin, vmax), rows)
    np.testing.assert_allclose(partial[rows], got[rows], rtol=1e-12)
    assert np.isinf(np.delete(partial, rows)).all()


def test_a_known_best_line_is_found() -> None:
    ds = 10
    window = np.ones((60, ds + 1))
    window[20 + np.arange(ds + 1), np.arange(ds + 1)] = 0.0  # a velocity-1 line from row 20
    window[45, :] = 0.5  # a decoy: cheaper than 1 but not 0
    found = best_match(sequence_scores(window, trajectory_offsets(ds, 0.8, 1.2)), ds, rwindow=10)
    assert found is not None and found.start == 20 and found.reference == 25
    assert found.ratio == 0.0


def test_no_trajectory_fits_in_a_tiny_reference() -> None:
    scores = sequence_scores(np.ones((5, 11)), trajectory_offsets(10, 0.8, 1.2))
    assert np.isinf(scores).all()
    assert best_match(scores, 10) is None


# --- the plugins ------------------------------------------------------------------------



def _feed(detector, references: np.ndarray, queries: np.ndarray) -> list[LoopResult]:
    """Run a detector over reference then query vectors, as the runtime would."""
    results: list[LoopResult] = []
    traversal = ["reference"] * len(references) + ["query"] * len(queries)
    for index, (vector, kind) in enumerate(zip([*references, *queries], traversal)):
        frame = Frame(index=index, timestamp=float(index), image=np.zeros((2, 2), np.uint8), traversal=kind)
        inputs = StageInputs(frame=frame, outputs={"descriptor": [Features(frame=index, vector=vector)]})
        results += [m for m in detector.process(inputs) if isinstance(m, LoopResult)]
    return results + [m for m in detector.finish() if isinstance(m, LoopResult)]


def _route(n: int, noise: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A random reference route and a noisy, slightly slower re-traversal of it."""
    rng = np.random.default_rng(seed)
    places = rng.random((n, 64)) * 255
    # the query drives at 0.9x speed: query q sees place floor(q * 0.9) with noise
    q_places = np.floor(np.arange(int(n / 0.9) - 2) * 0.9).astype(int)
    queries = places[q_places] + rng.normal(0, noise, (len(q_places), 64))
    return np.clip(places, 0, 255).astype(np.uint8), np.clip(queries, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("cls", [SeqSlam, SeqSlamFast])
def test_batch_and_online_give_identical_answers(cls) -> None:
    references, queries = _route(120, noise=60.0, seed=3)
    common = dict(ds=10, score_offset="bound")
    batch = _feed(cls(cls.Config(mode="batch", **common)), references, queries)
    online = _feed(cls(cls.Config(mode="online", **common)), references, queries)
    assert sorted(r.frame for r in batch) == sorted(r.frame for r in online)
    by_frame = {r.frame: r for r in online}
    for result in batch:
        assert result.same_as(by_frame[result.frame]), result.frame


def test_answers_follow_the_route_and_ends_get_no_answer() -> None:
    references, queries = _route(150, noise=40.0, seed=4)
    results = {r.frame: r for r in _feed(SeqSlam(), references, queries)}
    first_query = len(references)
    q = np.arange(len(queries))
    answered = [r for r in results.values() if r.match >= 0]
    assert len(results) == len(queries)
    assert all(results[first_query + k].match == -1 and "first ds/2" in results[first_query + k].reason for k in range(5))
    assert all(results[first_query + len(queries) - 1 - k].match == -1 for k in range(5))
    truth = np.floor(q * 0.9).astype(int)
    errors = [abs(r.match - truth[r.frame - first_query]) for r in answered]
    assert np.mean(np.array(errors) <= 3) > 0.95


def test_fast_variant_mostly_agrees_with_full_seqslam() -> None:
    references, queries = _route(200, noise=50.0, seed=5)
    full = {r.frame: r.match for r in _feed(SeqSlam(), references, queries)}
    fast = {r.frame: r.match for r in _feed(SeqSlamFast(SeqSlamFast.Config(k=10)), references, queries)}
    same = np.mean([abs(full[f] - fast[f]) <= 3 for f in full if full[f] >= 0])
    assert same > 0.9


def test_approximate_neighbours_agree_with_exact_ones() -> None:
    references, queries = _route(200, noise=50.0, seed=8)
    exact = {r.frame: r.match for r in _feed(SeqSlamFast(SeqSlamFast.Config(k=10)), references, queries)}
    hnsw = {r.frame: r.match for r in _feed(SeqSlamFast(SeqSlamFast.Config(k=10, knn="hnsw")), references, queries)}
    assert np.mean([abs(exact[f] - hnsw[f]) <= 3 for f in exact if exact[f] >= 0]) > 0.9


def test_too_few_queries_is_a_documented_no_answer() -> None:
    references, queries = _route(60, noise=10.0, seed=6)
    results = _feed(SeqSlam(), references, queries[:8])
    assert len(results) == 8 and all(r.match == -1 for r in results)
    assert "fewer than a sequence" in results[0].reason
    short = _feed(SeqSlam(SeqSlam.Config(mode="online", score_offset="bound")), references[:5], queries[:20])
    assert all(r.match == -1 and "the reference has 5 frames" in r.reason for r in short)


def test_mismatched_image_sizes_are_a_clear_error() -> None:
    detector = SeqSlam()
    references, queries = _route(20, noise=1.0, seed=7)
    with pytest.raises(PluginError, match="descriptor length 32 differs from the references' 64"):
        _feed(detector, references, queries[:, :32])


def test_online_mode_refuses_the_global_minimum() -> None:
    with pytest.raises(ValueError, match="online mode cannot know the global minimum"):
        SeqSlam.Config(mode="online")
    with pytest.raises(ValueError, match="ds must be even"):
        SeqSlam.Config(ds=9)


def test_a_single_stream_source_is_refused(tmp_path: Path) -> None:
    raw = {
        "name": "s",
        "source": {"plugin": "synthetic", "params": {"mode": "stream", "frames_per_traversal": 20,
                                                      "image_width": 64, "image_height": 32}},
        "descriptor": {"plugin": "seqslam_thumbnail"},
        "loop_detector": {"plugin": "seqslam"},
        "eval": {"plots": False},
    }
    pipeline = build_pipeline(parse_recipe(raw, "s.yaml"), "s.yaml")
    with pytest.raises(PluginError, match="yields one stream"):
        run_pipeline(pipeline, "s.yaml", tmp_path, progress=False)


def test_synthetic_world_end_to_end(tmp_path: Path) -> None:
    raw = {
        "name": "s",
        "source": {"plugin": "synthetic", "params": {"frames_per_traversal": 150, "route_length_m": 150,
                                                      "image_width": 128, "image_height": 64}},
        "descriptor": {"plugin": "seqslam_thumbnail"},
        "loop_detector": {"plugin": "seqslam"},
        "eval": {"plots": False},
    }
    result = run_pipeline(build_pipeline(parse_recipe(raw, "s.yaml"), "s.yaml"), "s.yaml", tmp_path, progress=False)
    assert result.metrics["n_queries"] == 150 and result.metrics["n_searches"] == 140
    assert result.metrics["recall_at_1"] > 0.6


# --- the compiled search and distance engine against the former NumPy code --------------


def _numpy_sequence_scores(columns: np.ndarray, offsets: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """The NumPy implementation the compiled kernels replaced, kept as the oracle."""
    n_ref, width = columns.shape
    reach = int(offsets.max())
    padded = np.concatenate([columns, np.full((reach + 1, width), np.inf, dtype=columns.dtype)])
    best = np.full(n_ref, np.inf, dtype=np.float64)
    if rows is None:
        for trajectory in offsets:
            cost = np.zeros(n_ref, dtype=np.float64)
            for k, offset in enumerate(trajectory):
                cost += padded[offset : offset + n_ref, k]
            np.minimum(best, cost, out=best)
        return best
    rows = np.asarray(rows, dtype=np.int64)
    if len(rows) * 8 > n_ref:
        every = _numpy_sequence_scores(columns, offsets)
        best[rows] = every[rows]
        return best
    picked = padded[rows[:, None, None] + offsets[None, :, :], np.arange(width)[None, None, :]]
    best[rows] = picked.sum(axis=2, dtype=np.float64).min(axis=1)
    return best


@pytest.mark.parametrize(("ds", "vmin", "vmax"), [(10, 0.8, 1.2), (40, 1.0, 1.5), (4, 0.5, 2.0)])
def test_compiled_trajectory_search_gives_the_numpy_bits(ds: int, vmin: float, vmax: float) -> None:
    rng = np.random.default_rng(ds)
    n_ref, n_queries = 300, 9
    offsets = trajectory_offsets(ds, vmin, vmax)
    block = rng.standard_normal((n_ref, n_queries + ds)).astype(np.float32).astype(np.float64) + 3.1
    rows = [None, np.sort(rng.choice(n_ref, 20, replace=False)), np.arange(0, n_ref, 2), np.array([0, n_ref - 1])]
    rows = [rows[n % len(rows)] for n in range(n_queries)]
    for threads in (1, 2):
        got = sequence_scores_block(block, offsets, rows, threads=threads)
        for n in range(n_queries):
            expected = _numpy_sequence_scores(block[:, n : n + ds + 1], offsets, rows[n])
            assert got[n].tobytes() == expected.tobytes()
            assert sequence_scores(block[:, n : n + ds + 1], offsets, rows[n]).tobytes() == expected.tobytes()


def test_difference_engine_gives_the_numpy_bits() -> None:
    rng = np.random.default_rng(5)
    for pixels in (7, 64, 288, 1024):
        refs = rng.integers(0, 256, (50, pixels), dtype=np.uint8)
        queries = rng.integers(0, 256, (6, pixels), dtype=np.uint8)
        expected = np.abs(refs[:, None, :].astype(np.int64) - queries[None]).sum(2).astype(np.float32)
        expected /= np.float32(pixels)
        assert difference_columns(refs, queries).tobytes() == expected.tobytes()
        floats_r, floats_q = refs.astype(np.float32) / 7, queries.astype(np.float32) / 7
        numpy_sums = np.abs(floats_r[:, None, :] - floats_q[None, :, :]).sum(axis=2, dtype=np.float32)
        assert difference_columns(floats_r, floats_q).tobytes() == (numpy_sums / np.float32(pixels)).tobytes()


def test_thumbnail_resize_low_passes_before_shrinking_as_matlab_imresize() -> None:

    from slamfront.core.thumbnail import imresize, resize_weights
    from slamfront_plugins.descriptors.seqslam_thumbnail import SeqSlamThumbnail

    stripes = np.tile(np.array([0, 255], dtype=np.uint8), (32, 32))  # 64 columns alternating black/white
    shrunk = imresize(stripes, 32, 32)
    assert shrunk.shape == (32, 32)
    assert np.all(np.abs(shrunk[:, 2:-2].astype(int) - 128) <= 1)  # averaged to grey, not aliased (edges: mirrored)
    weights = resize_weights(64, 32)
    assert np.allclose(weights.sum(axis=1), 1.0) and np.allclose(weights[6][2:], weights[5][:-2])
    assert np.unique(imresize(np.full((32, 64), 77, np.uint8), 32, 32)).tolist() == [77]
    stack = np.stack([stripes, 255 - stripes])
    assert np.array_equal(imresize(stack, 16, 20)[1], imresize(255 - stripes, 16, 20))  # batched = one by one
    thumbnail = SeqSlamThumbnail(SeqSlamThumbnail.Config(width=32, height=32))
    assert thumbnail.describe(np.dstack([stripes] * 3)).shape == (1024,)
