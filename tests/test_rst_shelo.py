"""The RST-SHelo descriptor and Rodrigues 2019's preprocessing."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from slamfront import DataError, Frame, StageInputs
from slamfront.core.distances import k_nearest
from slamfront.errors import RecipeError
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront_plugins.descriptors.rst_shelo import (
    RstShelo,
    block_histograms,
    block_histograms_reference,
    cell_orientations,
    cell_orientations_reference,
    edge_strength,
    kernel_for,
    preprocess,
    square_root_normalise,
)


def _stripes(vertical: bool, size: tuple[int, int] = (64, 128), period: int = 8) -> np.ndarray:
    h, w = size
    ramp = np.arange(w if vertical else h) // (period // 2) % 2 * 200 + 20
    image = np.tile(ramp, (h, 1)) if vertical else np.tile(ramp[:, None], (1, w))
    return image.astype(np.uint8)


def test_cell_orientation_follows_the_gradient() -> None:
    theta, weight = cell_orientations(_stripes(vertical=True), cells_x=8, cells_y=4)
    # vertical stripes: horizontal gradients, orientation 0 (mod pi)
    assert np.allclose(np.minimum(theta, np.pi - theta)[weight > 0], 0.0, atol=1e-6)
    theta, weight = cell_orientations(_stripes(vertical=False), cells_x=8, cells_y=4)
    assert np.allclose(theta[weight > 0], np.pi / 2, atol=1e-6)
    assert weight.max() > 10


def test_votes_split_between_the_two_nearest_bins() -> None:
    # 2 bins over [0, pi): centres at pi/4 and 3 pi/4
    theta = np.full((2, 2), np.pi / 2)  # half way between the two centres
    histogram = block_histograms(theta, np.ones((2, 2)), block_x=2, block_y=2, bins=2, spatial_soft=False)
    assert histogram.shape == (1, 1, 2)
    assert histogram[0, 0].tolist() == pytest.approx([2.0, 2.0])
    theta[:] = np.pi / 4  # on a centre: one bin takes it all
    assert block_histograms(theta, np.ones((2, 2)), 2, 2, 2, False)[0, 0].tolist() == pytest.approx([4.0, 0.0])
    theta[:] = np.pi - 0.01  # wraps around: close to 0, shared between the last and the first bin
    wrapped = block_histograms(theta, np.ones((2, 2)), 2, 2, 4, spatial_soft=False)[0, 0]
    assert wrapped[0] > 0 and wrapped[3] > 0 and wrapped.sum() == pytest.approx(4.0)


def test_spatial_soft_voting_shares_votes_between_blocks_and_keeps_the_total() -> None:
    theta = np.zeros((4, 8))
    weight = np.zeros((4, 8))
    weight[1:3, 3:5] = 1.0  # cells around the border of the two blocks
    hard = block_histograms(theta, weight, 4, 4, 9, spatial_soft=False)
    soft = block_histograms(theta, weight, 4, 4, 9, spatial_soft=True)
    assert hard[0, :, :].sum() == pytest.approx(4.0)
    assert soft[0, 0].sum() == pytest.approx(soft[0, 1].sum())  # symmetric around the border


def test_square_root_normalisation() -> None:
    out = square_root_normalise(np.array([1.0, 3.0, 0.0, 12.0]))
    expected = np.sqrt(np.array([1, 3, 0, 12]) / 16)
    assert out.tolist() == pytest.approx((expected / expected.sum()).tolist())
    assert out.dtype == np.float32 and out.sum() == pytest.approx(1.0)
    assert not square_root_normalise(np.zeros(5)).any()


def test_descriptor_length_norm_and_l1_range() -> None:
    describe = RstShelo().describe
    rng = np.random.default_rng(0)
    a = describe(cv2.GaussianBlur(rng.integers(0, 256, (32, 64), dtype=np.uint8), (3, 3), 0))
    b = describe(_stripes(True, (32, 64)))
    assert a.shape == (1152,) and a.dtype == np.float32
    assert a.sum() == pytest.approx(1.0, abs=1e-5) and (a >= 0).all()
    assert 0 < np.abs(a - b).sum() <= 2.0


def test_featureless_images_describe_to_zeros() -> None:
    rng = np.random.default_rng(1)
    dark = rng.integers(0, 3, (32, 64), dtype=np.uint8)  # a tunnel: sensor noise only
    assert edge_strength(dark) < 5.0
    assert not RstShelo().describe(dark).any()
    assert not RstShelo().describe(np.zeros((32, 64), np.uint8)).any()
    # without the check, equalisation would have made strong random edges out of the noise
    assert edge_strength(preprocess(dark)) > 10 * edge_strength(dark)


def test_preprocessing_is_blur_then_equalisation() -> None:
    image = np.clip(np.random.default_rng(2).normal(60, 10, (40, 40)), 0, 255).astype(np.uint8)
    out = preprocess(image, 5, True)
    assert np.array_equal(out, cv2.equalizeHist(cv2.GaussianBlur(image, (5, 5), 0)))
    assert np.array_equal(preprocess(image, 0, False), image)
    assert out.min() == 0 and out.max() == 255


def _scene(seed: int, scale: int) -> np.ndarray:
    """Rectangles and lines drawn on a 32 x 64 canvas times ``scale``."""
    rng = np.random.default_rng(seed)
    image = np.full((32 * scale, 64 * scale), 90, np.uint8)
    for _ in range(6):
        x, y = rng.integers(0, 56), rng.integers(0, 26)
        w, h = rng.integers(4, 20), rng.integers(3, 12)
        cv2.rectangle(image, (x * scale, y * scale), ((x + w) * scale, (y + h) * scale), int(rng.integers(0, 255)), -1)
    for _ in range(4):
        a, b = rng.integers(0, 64, 2), rng.integers(0, 32, 2)
        cv2.line(image, (int(a[0]) * scale, int(b[0]) * scale), (int(a[1]) * scale, int(b[1]) * scale), 240, scale)
    return image


def test_fixed_cell_count_makes_it_nearly_scale_invariant() -> None:
    describe = RstShelo().describe
    small, large = describe(_scene(3, 1)), describe(_scene(3, 4))
    others = [np.abs(small - describe(_scene(seed, 1))).sum() for seed in range(4, 12)]
    # the same scene 4x larger is nearer than any other scene at the same size
    assert np.abs(large - small).sum() < 0.75 * min(others)


def test_the_blur_kernel_scales_with_the_image() -> None:
    # 5 x 5 at a 480-pixel short side, the nearest odd size elsewhere, no blur below 3
    assert [kernel_for((h, 2 * h)) for h in (32, 120, 191, 192, 240, 480, 1080)] == [0, 0, 0, 3, 3, 5, 11]
    image = _scene(5, 8)  # 256 x 512: a 3 x 3 kernel
    auto = RstShelo()
    assert np.array_equal(auto.describe(image), RstShelo(RstShelo.Config(gaussian_kernel=3)).describe(image))
    assert auto.statistics() == {"gaussian_kernel": 3}
    small = RstShelo()
    small.describe(_scene(5, 1))
    assert small.statistics() == {"gaussian_kernel": 0}


def test_config_is_validated() -> None:
    with pytest.raises(RecipeError, match="block_x must divide"):
        build_pipeline(parse_recipe({"name": "x", "source": {"plugin": "synthetic"},
                                     "descriptor": {"plugin": "rst_shelo", "params": {"block_x": 5}}}, "r"), "r")
    with pytest.raises(RecipeError, match="odd"):
        build_pipeline(parse_recipe({"name": "x", "source": {"plugin": "synthetic"},
                                     "descriptor": {"plugin": "rst_shelo", "params": {"gaussian_kernel": 4}}}, "r"), "r")


def test_an_image_smaller_than_the_grid_is_a_clear_error() -> None:
    image = np.repeat(np.repeat(np.array([[0, 200], [200, 0]], np.uint8), 4, axis=0), 4, axis=1)
    frame = Frame(index=3, timestamp=0.0, image=image, name="tiny.png")
    with pytest.raises(DataError, match="frame 3 \\(tiny.png\\).*cannot be split into 32x16 cells"):
        RstShelo().process(StageInputs(frame=frame))


def test_nordland_retrieval_with_and_without_preprocessing(shared_data: Path) -> None:
    """Rodrigues 2019 §4.2 on real data (frames 0-399, summer vs winter, zeta = 3): a correct
    reference among the 1 and the 20 nearest descriptors. A regression check of the defaults
    (chosen elsewhere, on held-out data): measured 0.54/0.89 with the default preprocessing
    (equalisation; no blur at 64 x 32), 0.50/0.88 without, 0.45/0.79 with the 5 x 5 blur."""
    folder = shared_data / "nordland"
    names = sorted(p.name for p in (folder / "summer").glob("*.png"))[:400]

    def recall(config: RstShelo.Config) -> np.ndarray:
        d = RstShelo(config)
        ref = np.stack([d.describe(cv2.imread(str(folder / "summer" / n), cv2.IMREAD_GRAYSCALE)) for n in names])
        qry = np.stack([d.describe(cv2.imread(str(folder / "winter" / n), cv2.IMREAD_GRAYSCALE)) for n in names])
        nearest = k_nearest(qry, ref, 20, "l1")
        hit = np.abs(nearest - np.arange(len(names))[:, None]) <= 3
        return np.array([hit[:, :k].any(axis=1).mean() for k in (1, 20)])

    for config in (RstShelo.Config(), RstShelo.Config(preprocess=False)):
        at_1, at_20 = recall(config)
        assert at_1 >= 0.45 and at_20 >= 0.8


def _add_at_histograms(theta, weight, block_x, block_y, bins, spatial_soft):  # type: ignore[no-untyped-def]
    """The former np.add.at implementation of block_histograms, kept as the oracle."""
    cells_y, cells_x = theta.shape
    blocks_y, blocks_x = cells_y // block_y, cells_x // block_x
    position = theta / np.pi * bins - 0.5
    low_bin = np.floor(position).astype(int)
    bin_frac = position - low_bin
    if spatial_soft:
        row = (np.arange(cells_y) + 0.5) / block_y - 0.5
        col = (np.arange(cells_x) + 0.5) / block_x - 0.5
    else:
        row = np.arange(cells_y) // block_y + 0.0
        col = np.arange(cells_x) // block_x + 0.0
    row_grid, col_grid = np.meshgrid(row, col, indexing="ij")
    row0, col0 = np.floor(row_grid).astype(int), np.floor(col_grid).astype(int)
    row_frac, col_frac = row_grid - row0, col_grid - col0
    padded = np.zeros((blocks_y + 2, blocks_x + 2, bins))
    for dr, wr in ((0, 1 - row_frac), (1, row_frac)):
        for dc, wc in ((0, 1 - col_frac), (1, col_frac)):
            for db, wb in ((0, 1 - bin_frac), (1, bin_frac)):
                np.add.at(padded, (row0 + dr + 1, col0 + dc + 1, (low_bin + db) % bins), weight * wr * wc * wb)
    return padded[1:-1, 1:-1]


@pytest.mark.parametrize(("cells", "blocks", "bins"), [((16, 32), (4, 4), 9), ((12, 8), (3, 2), 6), ((5, 5), (5, 1), 4)])
@pytest.mark.parametrize("soft", [True, False])
def test_bincount_histograms_are_the_add_at_bits(cells: tuple[int, int], blocks: tuple[int, int], bins: int,
                                                 soft: bool) -> None:
    rng = np.random.default_rng(bins)
    for _ in range(5):
        theta, weight = rng.random(cells) * np.pi, rng.random(cells) * 40
        expected = _add_at_histograms(theta, weight, blocks[1], blocks[0], bins, soft)
        assert block_histograms(theta, weight, blocks[1], blocks[0], bins, soft).tobytes() == expected.tobytes()
        assert block_histograms_reference(theta, weight, blocks[1], blocks[0], bins, soft).tobytes() == expected.tobytes()


def test_compiled_descriptor_is_the_numpy_reference_on_real_frames(shared_data: Path) -> None:
    """The compiled cell sums and votes give the NumPy implementation's bits on real
    Nordland frames (64 x 32: 2 x 2-pixel cells, both seasons), and the same descriptor
    to float tolerance on larger images (cells of many pixels, whose sums NumPy may order
    differently)."""
    folder = shared_data / "nordland"
    names = sorted(p.name for p in (folder / "summer").glob("*.png"))[::40][:60]
    c = RstShelo.Config()
    for season in ("summer", "winter"):
        for name in names:
            image = preprocess(cv2.imread(str(folder / season / name), cv2.IMREAD_GRAYSCALE), 0)
            for gray, exact in ((image, True), (cv2.resize(image, (640, 320)), False)):
                theta, weight = cell_orientations(gray, c.cells_x, c.cells_y)
                want_theta, want_weight = cell_orientations_reference(gray, c.cells_x, c.cells_y)
                got = block_histograms(theta, weight, c.block_x, c.block_y, c.bins, c.spatial_soft)
                want = block_histograms_reference(want_theta, want_weight, c.block_x, c.block_y, c.bins, c.spatial_soft)
                if exact:
                    assert theta.tobytes() == want_theta.tobytes() and weight.tobytes() == want_weight.tobytes()
                    assert got.tobytes() == want.tobytes()
                else:
                    assert np.allclose(square_root_normalise(got), square_root_normalise(want), rtol=0, atol=1e-6)


def test_compiled_gradients_and_descriptor_are_the_opencv_numpy_bits() -> None:
    """The compiled Sobel (OpenCV's border included, down to 1-pixel images), the edge
    strength and the one-call histogram + square-root normalisation give the bits of
    OpenCV's Sobel, ``np.mean`` and block_histograms_reference + square_root_normalise."""
    from slamfront_plugins.descriptors.rst_shelo import _gradients, _sobel

    rng = np.random.default_rng(7)
    descriptor = RstShelo(RstShelo.Config(preprocess=False, cells_x=8, cells_y=4, min_edge_strength=0.0))
    c = descriptor.config
    for n in range(60):
        height, width = int(rng.integers(1, 40)), int(rng.integers(1, 70))
        gray = (rng.integers(0, 256, (height, width)) // int(rng.integers(1, 60))).astype(np.uint8)
        gx, gy, magnitude = _gradients(gray)
        want_x, want_y = _sobel(gray)
        assert gx.tobytes() == want_x.tobytes() and gy.tobytes() == want_y.tobytes()
        assert magnitude.tobytes() == np.sqrt(want_x * want_x + want_y * want_y).tobytes()
        assert edge_strength(gray) == float(np.sqrt(want_x * want_x + want_y * want_y).mean())
        # the descriptor's own compiled edge strength (scratch arrays kept per image size)
        assert descriptor._workspace(gray.shape).edge_strength(gray) == edge_strength(gray)
        if height >= c.cells_y and width >= c.cells_x:
            theta, weight = cell_orientations_reference(gray, c.cells_x, c.cells_y)
            histogram = block_histograms_reference(theta, weight, c.block_x, c.block_y, c.bins, c.spatial_soft)
            assert descriptor.describe(gray).tobytes() == square_root_normalise(histogram).tobytes(), n


def test_descriptors_returned_earlier_are_not_overwritten_by_later_calls() -> None:
    """The scratch arrays are reused call after call (one set per image size); the
    descriptors handed out are not among them."""
    rng = np.random.default_rng(11)
    descriptor = RstShelo()
    images = [rng.integers(0, 256, shape, dtype=np.uint8) for shape in ((32, 64), (48, 80), (32, 64), (48, 80))]
    first = [descriptor.describe(image) for image in images]
    kept = [vector.copy() for vector in first]
    again = [descriptor.describe(image) for image in images[::-1]][::-1]
    for vector, copy, repeat in zip(first, kept, again):
        assert vector.tobytes() == copy.tobytes() == repeat.tobytes()
    assert len({vector.tobytes() for vector in first}) == 4  # four different images
    # images of ever new sizes keep only a few sets of scratch arrays, and the same answers
    for side in range(40, 60):
        image = rng.integers(0, 256, (32, side), dtype=np.uint8)
        assert descriptor.describe(image).tobytes() == RstShelo().describe(image).tobytes()
    assert len(descriptor._workspaces) <= 8


def test_a_featureless_image_smaller_than_the_grid_describes_to_zeros() -> None:
    """As before the scratch arrays: a tiny image is an error only when it has edges to describe."""
    vector = RstShelo().describe(np.full((4, 4), 90, dtype=np.uint8))
    assert not vector.any() and vector.dtype == np.float32
