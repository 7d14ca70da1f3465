"""Local features on a real image: every descriptor type, its metric, bucketing, blanks, SURF."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slamfront.errors import RecipeError
from slamfront.frame import Frame
from slamfront.imageio import read_image
from slamfront.local_features import DESCRIPTORS, LocalFeatureExtractor
from slamfront.plugin import StageInputs
from slamfront.recipe import apply_overrides, build_pipeline, parse_recipe
from slamfront_plugins.descriptors.local_features import LocalFeaturesDescriptor
from tests.helpers import small_synthetic_recipe

CASES = [(name, "fast" if spec.needs_detector else "native") for name, spec in DESCRIPTORS.items()]


@pytest.fixture(scope="module")
def desk(shared_data: Path) -> np.ndarray:
    return read_image(shared_data / "images/loop10/1.png", mode="gray")


@pytest.mark.parametrize(("descriptor", "detector"), CASES, ids=[c[0] for c in CASES])
def test_every_descriptor_type_on_a_real_image(desk: np.ndarray, descriptor: str, detector: str) -> None:
    spec = DESCRIPTORS[descriptor]
    found = LocalFeatureExtractor(descriptor, detector, max_features=300).extract(desk)  # type: ignore[arg-type]
    assert 50 <= len(found) <= 300
    assert found.descriptors.shape == (len(found), spec.length)
    assert found.descriptors.dtype == spec.dtype
    assert found.metric == ("hamming" if spec.dtype == np.uint8 else "l2")
    assert found.keypoints.shape == (len(found), 2) and found.info.shape == (len(found), 4)
    # strongest first
    assert np.all(np.diff(found.info[:, 2]) <= 1e-6)


def test_rootsift_is_the_hellinger_map_of_sift(desk: np.ndarray) -> None:
    sift = LocalFeatureExtractor("sift", max_features=100).extract(desk)
    root = LocalFeatureExtractor("rootsift", max_features=100).extract(desk)
    expected = np.sqrt(sift.descriptors / sift.descriptors.sum(axis=1, keepdims=True))
    np.testing.assert_allclose(root.descriptors, expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(root.descriptors, axis=1), 1.0, rtol=1e-5)


def test_grid_bucketing_spreads_features(desk: np.ndarray) -> None:
    plain = LocalFeatureExtractor("orb", max_features=200).extract(desk)
    spread = LocalFeatureExtractor("orb", max_features=200, grid=(4, 4)).extract(desk)

    def occupied(points: np.ndarray) -> int:
        cells = np.floor(points / [desk.shape[1] / 4, desk.shape[0] / 4]).astype(int)
        return len({tuple(c) for c in cells})

    assert occupied(spread.keypoints) > occupied(plain.keypoints)
    assert occupied(spread.keypoints) >= 10  # a few cells of this desk scene are blank wall


@pytest.mark.parametrize("descriptor", ["orb", "sift", "akaze"])
def test_blank_frame_gives_no_features_not_an_error(descriptor: str) -> None:
    plugin = LocalFeaturesDescriptor(LocalFeaturesDescriptor.Config(descriptor=descriptor))
    frame = Frame(index=0, timestamp=0.0, image=np.zeros((48, 64, 3), np.uint8))
    (features,) = plugin.process(StageInputs(frame=frame))
    assert features.descriptors.shape == (0, DESCRIPTORS[descriptor].length)
    assert features.keypoints.shape == (0, 2)


def test_surf_is_refused_with_the_reason() -> None:
    raw = apply_overrides(small_synthetic_recipe(), ["descriptor.plugin=local_features", "descriptor.params={descriptor: surf}"])
    del raw["loop_detector"]
    with pytest.raises(RecipeError, match="descriptor.params.descriptor: .*SURF is patented"):
        build_pipeline(parse_recipe(raw, "r.yaml"), "r.yaml")


def test_describe_only_types_need_a_detector() -> None:
    raw = apply_overrides(small_synthetic_recipe(), ["descriptor.plugin=local_features", "descriptor.params={descriptor: freak}"])
    del raw["loop_detector"]
    with pytest.raises(RecipeError, match="freak only describes keypoints"):
        build_pipeline(parse_recipe(raw, "r.yaml"), "r.yaml")
