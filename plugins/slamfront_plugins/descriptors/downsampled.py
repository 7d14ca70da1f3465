"""The ``downsampled`` descriptor: the image itself, tiny and normalised."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from slamfront import Descriptor, PluginConfig, StageInputs
from slamfront.core.thumbnail import patch_normalise, thumbnail
from slamfront.lazy import lazy_module
from slamfront.messages import Features

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it

__all__ = ["DownsampledImage", "patch_normalise"]


class DownsampledImage(Descriptor):
    """A whole-image descriptor: the grey image shrunk to a thumbnail and normalised.

    The simplest global descriptor that works for place recognition under moderate
    change. ``normalisation: patch`` normalises each small block of the thumbnail
    (the idea of SeqSLAM's patch normalisation), which removes most illumination
    change; ``global`` only equalises the histogram. The vector is zero-mean and
    unit-norm, so L2 distance ranks like correlation.
    """

    name = "downsampled"
    produces_global = True

    class Config(PluginConfig):
        width: int = Field(32, ge=2, description="thumbnail width in pixels")
        height: int = Field(24, ge=2, description="thumbnail height in pixels")
        normalisation: Literal["patch", "global"] = Field("patch", description="per block, or whole image")
        patch_size: int = Field(8, ge=2, description="block side for patch normalisation")
        metric: Literal["l2", "cosine", "l1"] = Field("l2", description="how vectors are compared")

        @model_validator(mode="after")
        def _patches_tile(self) -> DownsampledImage.Config:
            p = self.patch_size
            if self.normalisation == "patch" and (self.width % p or self.height % p):
                raise ValueError(f"width and height must be multiples of patch_size ({p})")
            return self

    def describe(self, image: np.ndarray) -> np.ndarray:
        """(width * height,) float32 descriptor of an RGB or grey uint8 image."""
        c = self.config
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        return thumbnail(grey, c.width, c.height, c.patch_size if c.normalisation == "patch" else None)

    def process(self, inputs: StageInputs) -> Sequence[Features]:
        return [Features(frame=inputs.frame.index, vector=self.describe(inputs.frame.image), metric=self.config.metric)]
