"""The topics of a run log and which part of the run writes each.

- Frame topics: what the source gave for a frame (written by the frame logger).
- Stage topics: ``/<stage kind>/...``, a stage's outputs (JSON, one topic per message
  type) and the Foxglove messages that draw them (protobuf).
- Run topics: written by the runtime itself (phases, ground truth, scene, log lines,
  metrics).

A replay copies frame topics, copies or recomputes stage topics, and regenerates the
run topics.
"""

from __future__ import annotations

import re

from slamfront.messages import Message
from slamfront.plugin import STAGE_KINDS

FRAMES_TOPIC = "/frames"
IMAGE_TOPIC = "/camera/image"
DEPTH_TOPIC = "/camera/depth"
POINTS_TOPIC = "/camera/points"
CALIBRATION_TOPIC = "/camera/calibration"
GROUND_TRUTH_TOPIC = "/ground_truth/pose"
TF_TOPIC = "/tf"
FRAME_TOPICS = (FRAMES_TOPIC, IMAGE_TOPIC, DEPTH_TOPIC, POINTS_TOPIC, CALIBRATION_TOPIC, GROUND_TRUTH_TOPIC, TF_TOPIC)

EVENTS_TOPIC = "/run/events"
LOOP_TRUTH_TOPIC = "/ground_truth/loops"
SCENE_TOPIC = "/scene/map"
LOG_TOPIC = "/log"
METRICS_TOPIC = "/metrics"

STATISTICS_SUFFIX = "stage_statistics"


def topic_for(kind: str, message: Message | type[Message]) -> str:
    """``/<stage kind>/<message type in snake_case>``, e.g. ``/loop_detector/loop_result``."""
    cls = message if isinstance(message, type) else type(message)
    snake = re.sub(r"(?<!^)(?=[A-Z])", "_", cls.__name__).lower()
    return f"/{kind}/{snake}"


def stage_of(topic: str) -> str | None:
    """The stage kind a topic belongs to, or None for frame and run topics."""
    head = topic.split("/")[1] if topic.startswith("/") and topic.count("/") >= 2 else ""
    return head if head in STAGE_KINDS else None


def statistics_topic(kind: str) -> str:
    """Where a stage's end-of-run statistics are logged."""
    return f"/{kind}/{STATISTICS_SUFFIX}"
