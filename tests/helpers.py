"""Small builders shared by the tests."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from mcap.records import Attachment, Channel, Message, Metadata, Schema

from slamfront.formats.poses import Trajectory, write_tum
from slamfront.frame import Frame
from slamfront.mcaplog.diff import comparable_bytes
from slamfront.mcaplog.reader import read_messages, summarize
from slamfront.mcaplog.scan import RecordScanner
from slamfront.mcaplog.writer import RunLogWriter


def small_synthetic_recipe(**source_params: Any) -> dict[str, Any]:
    """A recipe dict for a quick synthetic run (few, small frames)."""
    params = {"frames_per_traversal": 40, "route_length_m": 80, "image_width": 64, "image_height": 48}
    params.update(source_params)
    return {
        "name": "small",
        "source": {"plugin": "synthetic", "params": params},
        "descriptor": {"plugin": "downsampled", "params": {"width": 16, "height": 16}},
        "loop_detector": {"plugin": "nearest_neighbour", "params": {}},
        "eval": {"plots": False},
    }


def rewrite_log(
    source: Path, target: Path, change: Callable[[str, int, bytes], bytes | None] = lambda _t, _i, data: data,
    attachment: Callable[[str, bytes], bytes] = lambda _name, data: data,
) -> None:
    """Copy a log record by record; ``change(topic, index in topic, data)`` may alter a
    message (return new bytes) or drop it (return None); ``attachment(name, data)`` may
    alter an attachment. Metadata are kept."""
    counts: dict[str, int] = {}
    with RunLogWriter(target, chunk_size=1 << 16) as log:
        for record, channel, schema in scanned_records(source):
            if isinstance(record, Message):
                index = counts.get(channel.topic, 0)
                counts[channel.topic] = index + 1
                data = change(channel.topic, index, bytes(record.data))
                if data is not None:
                    log.write_raw(channel.topic, schema.name, schema.encoding, bytes(schema.data),
                                  channel.message_encoding, data, record.log_time, record.publish_time)
            elif isinstance(record, Metadata):
                log.add_metadata(record.name, dict(record.metadata))
            elif isinstance(record, Attachment):
                log.add_attachment(record.name, record.media_type, attachment(record.name, bytes(record.data)),
                                   record.log_time)


def scanned_records(path: Path) -> Iterator[tuple[Any, Any, Any]]:
    """Every record of a log in file order, as ``(record, channel, schema)``: a message's
    channel and schema resolved from the records before it, None for any other record."""
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    with open(path, "rb") as stream:
        for record in RecordScanner(stream, path.stat().st_size).records():
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels[record.channel_id]
                yield record, channel, schemas[channel.schema_id]
                continue
            yield record, None, None


def stage_topic_bytes(path: Path, prefix: str) -> dict[str, list[bytes]]:
    """Every message's bytes on the topics starting with ``prefix``, by topic, as
    ``slamfront diff`` compares them (wall-time fields left out)."""
    topics: dict[str, list[bytes]] = {}
    for message in read_messages(path):
        if message.topic.startswith(prefix):
            topics.setdefault(message.topic, []).append(comparable_bytes(message))
    return topics


def write_tum_layout(root: Path, frames: Sequence[Frame], depth_scale: float = 5000.0) -> Path:
    """Write frames as a TUM RGB-D sequence folder: ``rgb/``, ``depth/``, ``rgb.txt``,
    ``depth.txt`` and ``groundtruth.txt`` (depth 4 ms and poses 1 ms after each image, as
    the benchmark's files are offset)."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb, depth, stamps = ["# color images"], ["# depth maps"], []
    for i, frame in enumerate(frames):
        t = 1305031102.0 + i / 30
        cv2.imwrite(str(root / f"rgb/{t:.6f}.png"), cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR))
        raw = np.clip(np.nan_to_num(frame.depth) * depth_scale, 0, 65535).astype(np.uint16)
        cv2.imwrite(str(root / f"depth/{t + 0.004:.6f}.png"), raw)
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth.append(f"{t + 0.004:.6f} depth/{t + 0.004:.6f}.png")
        stamps.append(t + 0.001)
    (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (root / "depth.txt").write_text("\n".join(depth) + "\n")
    write_tum(root / "groundtruth.txt", Trajectory(np.array(stamps), np.stack([f.pose for f in frames])))
    return root


# --- Foxglove layouts ----------------------------------------------------------------------

DRAWN_IN_3D = {
    "foxglove.SceneUpdate", "foxglove.PointCloud", "foxglove.PoseInFrame", "foxglove.PosesInFrame",
    "foxglove.CameraCalibration", "foxglove.CompressedImage", "foxglove.RawImage",
}
"""What Foxglove's 3-D panel draws, by schema (Foxglove docs, "3D panel")."""


def _mosaic_panels(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    if isinstance(node, dict):
        return _mosaic_panels(node.get("first")) + _mosaic_panels(node.get("second"))
    return []


def placed_panels(layout: dict[str, Any], tab: str | None = None) -> list[str]:
    """The panels on screen: the layout's mosaic and, through ``Tab!`` panels, each tab's
    (only the tab titled ``tab`` when given)."""
    panels = []
    for panel in _mosaic_panels(layout["layout"]):
        if panel.startswith("Tab!"):
            for entry in layout["configById"][panel]["tabs"]:
                if tab is None or entry["title"] == tab:
                    panels += _mosaic_panels(entry["layout"])
        elif tab is None:
            panels.append(panel)
    return panels


def layout_problems(layout: dict[str, Any], log: Path, tab: str | None = None) -> list[str]:
    """Why a log would not fill a Foxglove layout's panels (empty when every panel's topic
    is in the log, with a schema the panel shows and every plotted field present)."""
    schemas = {t.topic: t.schema_name for t in summarize(log).topics}
    config = layout["configById"]
    problems = [f"{p}: configured but not placed" for p in config
                if not p.startswith("Tab!") and p not in placed_panels(layout)]

    def need(panel: str, topic: str, allowed: set[str]) -> None:
        if topic not in schemas:
            problems.append(f"{panel}: topic {topic} is not in the log")
        elif schemas[topic] not in allowed:
            problems.append(f"{panel}: {topic} is {schemas[topic]}, not one of {sorted(allowed)}")

    for panel in placed_panels(layout, tab):
        settings = config[panel]
        kind = panel.split("!")[0]
        if kind == "Image":
            need(panel, settings["imageMode"]["imageTopic"], {"foxglove.CompressedImage", "foxglove.RawImage"})
            need(panel, settings["imageMode"]["calibrationTopic"], {"foxglove.CameraCalibration"})
        elif kind == "3D":
            if settings.get("followTf") != "map":
                problems.append(f"{panel}: does not follow the map frame")
            for topic, shown in settings["topics"].items():
                need(panel, topic, DRAWN_IN_3D)
                if not shown.get("visible"):
                    problems.append(f"{panel}: {topic} hidden")
        elif kind == "Plot":
            for path in (p["value"] for p in settings["paths"]):
                topic, field = path.split(".", 1)
                name, _, index = field.partition("[")
                if topic not in schemas:
                    problems.append(f"{panel}: topic {topic} is not in the log")
                    continue
                values = [json.loads(m.data).get(name, "missing") for m in read_messages(log, [topic])]
                if all(v == "missing" for v in values):
                    problems.append(f"{panel}: {topic} has no field {name}")
                elif index and not any(isinstance(v, list) and len(v) > int(index.rstrip("]")) for v in values):
                    problems.append(f"{panel}: {topic}.{name} is never a list of plain numbers long enough for {path}")
        elif kind == "RawMessages":
            if settings["topicPath"] not in schemas:
                problems.append(f"{panel}: topic {settings['topicPath']} is not in the log")
        elif kind == "RosOut":
            need(panel, settings["topicToRender"], {"foxglove.Log"})
        else:
            problems.append(f"{panel}: a panel type this check does not know")
    return problems
