"""The ``local_features`` descriptor: OpenCV keypoints + descriptors for every frame."""

from __future__ import annotations

from collections.abc import Sequence
from functools import cached_property

from pydantic import Field, model_validator

from slamfront import Descriptor, PluginConfig, StageInputs
from slamfront.local_features import DESCRIPTORS, DescriptorName, DetectorType, LocalFeatureExtractor
from slamfront.messages import Features


class LocalFeaturesDescriptor(Descriptor):
    """Local features (SIFT, RootSIFT, ORB, BRISK, AKAZE, KAZE, BRIEF, FREAK) of each frame.

    The output carries the distance the descriptor needs: ``l2`` for float descriptors
    (SIFT, RootSIFT, KAZE), ``hamming`` on packed bits for binary ones. BRIEF and FREAK
    describe keypoints found by a named ``detector``. SURF is refused with an
    explanation: it is patented and not in OpenCV's wheels.
    """

    name = "local_features"
    produces_local = True

    class Config(PluginConfig):
        descriptor: DescriptorName = Field("orb", description="descriptor type (SURF is not available: see the docs)")
        detector: DetectorType = Field(
            "native", description="keypoint detector: the descriptor's own, or fast/agast/gftt/orb/sift/brisk"
        )
        max_features: int = Field(1000, ge=1, description="keep at most this many, strongest first")
        grid: tuple[int, int] | None = Field(
            None, description="(rows, cols) bucketing: strongest features per cell, spread over the image"
        )
        scale: float = Field(
            1.0, gt=0, le=8, description="resize the image by this factor before detection (e.g. 4 for 64x32 thumbnails)"
        )

        @model_validator(mode="after")
        def _detector_for_describe_only(self) -> LocalFeaturesDescriptor.Config:
            if DESCRIPTORS[self.descriptor].needs_detector and self.detector == "native":
                raise ValueError(f"{self.descriptor} only describes keypoints: set detector (e.g. fast)")
            return self

    @cached_property
    def extractor(self) -> LocalFeatureExtractor:
        c = self.config
        return LocalFeatureExtractor(c.descriptor, c.detector, c.max_features, c.grid, c.scale)

    def process(self, inputs: StageInputs) -> Sequence[Features]:
        found = self.extractor.extract(inputs.frame.gray())
        return [
            Features(
                frame=inputs.frame.index,
                keypoints=found.keypoints,
                descriptors=found.descriptors,
                metric=found.metric,
                keypoint_info=found.info,
            )
        ]
