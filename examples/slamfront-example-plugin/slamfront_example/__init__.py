"""An example third-party plugin module: a colour-histogram global descriptor."""

from __future__ import annotations

import logging
from collections.abc import Sequence

import cv2
import numpy as np
from pydantic import Field

import slamfront
from slamfront.messages import Features

logger = logging.getLogger(__name__)  # its records go to the run's /log; warnings also to the terminal


class ColourHistogram(slamfront.Descriptor):
    """Hue-saturation histogram of the whole image: a global descriptor blind to layout.

    Robust to viewpoint, fragile under illumination change; an example, not a method.
    """

    name = "colour_histogram"
    version = "0.1.0"
    produces_global = True

    class Config(slamfront.PluginConfig):
        hue_bins: int = Field(16, ge=2, le=180, description="bins over hue")
        saturation_bins: int = Field(8, ge=2, le=256, description="bins over saturation")

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self._warned_grey = False

    def process(self, inputs: slamfront.StageInputs) -> Sequence[Features]:
        image = inputs.frame.image
        if image.ndim == 2 and not self._warned_grey:
            logger.warning("frame %d is grey: hue carries nothing, only saturation 0 is filled", inputs.frame.index)
            self._warned_grey = True
        rgb = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        bins = [self.config.hue_bins, self.config.saturation_bins]
        histogram = cv2.calcHist([hsv], [0, 1], None, bins, [0, 180, 0, 256]).ravel()
        vector = np.sqrt(histogram / max(float(histogram.sum()), 1.0)).astype(np.float32)
        return [Features(frame=inputs.frame.index, vector=vector, metric="l2")]


@slamfront.hookimpl
def slamfront_descriptors() -> list[type[slamfront.Descriptor]]:
    return [ColourHistogram]
