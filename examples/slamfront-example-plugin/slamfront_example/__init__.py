"""An example third-party plugin module: a colour-histogram global descriptor, the message
it logs besides its features, and the evaluation that reports it."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pydantic import Field

import slamfront
from slamfront.messages import Features

logger = logging.getLogger(__name__)  # its records go to the run's /log; warnings also to the terminal


@dataclass(frozen=True, eq=False)
class ColourSummary(slamfront.Message):
    """How colourful one frame is: its mean saturation and its most common hue."""

    schema_name: ClassVar[str] = "slamfront_example.ColourSummary"  # your package's prefix: unique, kept stable
    frame: int
    mean_saturation: float
    """0 (grey) to 1 (fully saturated)."""
    dominant_hue_bin: int
    """The hue bin holding the most pixels."""


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

    def process(self, inputs: slamfront.StageInputs) -> Sequence[slamfront.Message]:
        import cv2  # here, not at the top: `slamfront plugins` lists this plugin without loading OpenCV

        image = inputs.frame.image
        if image.ndim == 2 and not self._warned_grey:
            logger.warning("frame %d is grey: hue carries nothing, only saturation 0 is filled", inputs.frame.index)
            self._warned_grey = True
        rgb = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        bins = [self.config.hue_bins, self.config.saturation_bins]
        histogram = cv2.calcHist([hsv], [0, 1], None, bins, [0, 180, 0, 256])
        vector = np.sqrt(histogram.ravel() / max(float(histogram.sum()), 1.0)).astype(np.float32)
        summary = ColourSummary(
            frame=inputs.frame.index,
            mean_saturation=float(hsv[..., 1].mean() / 255.0),
            dominant_hue_bin=int(np.argmax(histogram.sum(axis=1))),
        )
        return [Features(frame=inputs.frame.index, vector=vector, metric="l2"), summary]


class ColourReport(slamfront.Evaluation):
    """Summarises the run's ``ColourSummary`` messages: how colourful its frames were."""

    title = "Colour"
    GREY = 0.05
    """Mean saturation below which a frame counts as grey."""

    def __init__(self) -> None:
        self._saturation: list[float] = []

    def observe(self, kind: str, message: slamfront.Message) -> None:
        if isinstance(message, ColourSummary):
            self._saturation.append(message.mean_saturation)

    def finish(self, context: slamfront.EvaluationContext) -> slamfront.EvaluationReport | None:
        if not self._saturation:
            return None  # the run's descriptor is another one: nothing to report
        saturation = np.asarray(self._saturation)
        metrics = {
            "colour_mean_saturation": float(saturation.mean()),
            "colour_grey_frames": int(np.sum(saturation < self.GREY)),
        }
        markdown = (
            f"Mean saturation {metrics['colour_mean_saturation']:.3f} over {len(saturation)} frames; "
            f"{metrics['colour_grey_frames']} grey frames (below {self.GREY}), where hue says nothing.\n"
        )
        return slamfront.EvaluationReport(self.title, metrics=metrics, markdown=markdown)


@slamfront.hookimpl
def slamfront_descriptors() -> list[type[slamfront.Descriptor]]:
    return [ColourHistogram]


@slamfront.hookimpl
def slamfront_message_types() -> list[type[slamfront.Message]]:
    return [ColourSummary]  # so `slamfront inspect --validate`, diff and replay know it


@slamfront.hookimpl
def slamfront_evaluations(kinds: frozenset[str]) -> list[slamfront.Evaluation]:
    return [ColourReport()] if "descriptor" in kinds else []
