"""The ``video`` source: frames of a video file, with the container's timestamps.

Decoding is OpenCV's (``cv2.VideoCapture``, FFmpeg inside the wheel slamfront already
depends on): any container and codec FFmpeg reads (MP4/H.264, MKV, AVI/MJPEG, ...).
PyAV would give the same frames and timestamps for a second large binary dependency, so
it is not used. Each frame's timestamp is its presentation time in the container
(``CAP_PROP_POS_MSEC``), not ``index / fps``, so a variable-frame-rate phone video keeps
its clock.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np
from pydantic import Field

from slamfront import Camera, DataError, Frame, Plugin, PluginConfig, Source
from slamfront.data import DataPath
from slamfront.lazy import lazy_module
from slamfront_plugins.sources.recording import TimedRecordingConfig, given_camera, n_selected
from slamfront_plugins.sources.rgbd import Intrinsics, KnownCamera

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it


class Video(Source):
    """Frames of a video file (anything OpenCV's FFmpeg decodes) with the container's times.

    Subsampled by ``step`` or to at most ``fps`` frames per second, optionally cut to a
    time range and downscaled; intrinsics from ``camera`` (given for the video's full
    resolution, scaled with the frames).
    """

    name = "video"

    class Config(TimedRecordingConfig):
        path: DataPath = Field(description="the video file (relative: under the data root)")
        fps: float | None = Field(None, gt=0, description="keep at most this many frames per second of video")
        max_width: int | None = Field(None, ge=16, description="downscale wider frames to this width")
        grey: bool = Field(False, description="give grey frames instead of colour")
        camera: Intrinsics | KnownCamera | None = Field(None, description="intrinsics at the video's full size")

    config: Config

    def __init__(self, config: PluginConfig | None = None) -> None:
        super().__init__(config)
        self.n_skipped_timestamps = 0

    def _open(self) -> cv2.VideoCapture:
        path = Path(self.config.path)
        if not path.is_file():
            raise DataError(f"{path}: no such video file")
        # FFmpeg writes its own complaints straight to stderr ("moov atom not found"); the
        # source says what failed in one line instead (set OPENCV_FFMPEG_LOGLEVEL to see them)
        os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
        capture = cv2.VideoCapture(str(path))
        if not capture.isOpened():
            raise DataError(f"{path}: not a video OpenCV (FFmpeg) can decode")
        return capture

    def check(self, stages: Mapping[str, Plugin]) -> None:
        """Open the file before the first frame: a file that is not a video is one line, before the log."""
        self._open().release()

    def __len__(self) -> int:
        capture = self._open()
        try:
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        finally:
            capture.release()
        if count <= 0 or self.config.fps or self.config.start_time_s or self.config.end_time_s:
            raise TypeError("the number of frames is known only by decoding")  # no progress total
        return n_selected(count, self.config)

    def frames(self) -> Iterator[Frame]:
        c = self.config
        path = Path(c.path)
        capture = self._open()
        self.n_skipped_timestamps = 0
        try:
            if c.start_time_s:
                capture.set(cv2.CAP_PROP_POS_MSEC, c.start_time_s * 1000.0)
            number, index = -1, 0
            last: float | None = None
            while c.limit is None or index < c.limit:
                if not capture.grab():
                    break
                number += 1
                stamp = capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
                if c.end_time_s is not None and stamp >= c.end_time_s:
                    break
                if number < c.start or (number - c.start) % c.step:
                    continue
                if c.fps is not None and last is not None and stamp - last < 1.0 / c.fps - 1e-6:
                    continue
                if last is not None and stamp <= last:
                    self.n_skipped_timestamps += 1  # a container that repeats a time: keep time increasing
                    continue
                ok, bgr = capture.retrieve()
                if not ok or bgr is None or bgr.size == 0:
                    raise DataError(f"{path}: frame {number} (t = {stamp:.3f} s) cannot be decoded")
                image = self._pixels(bgr)
                last = stamp
                yield Frame(
                    index=index, timestamp=stamp, image=image, sequence_index=number, name=f"{path.name}#{number}",
                    camera=self._camera(bgr.shape[1], image),
                )
                index += 1
        finally:
            capture.release()
        if index == 0:
            raise DataError(f"{path}: no frame decoded in the range asked for")

    def _pixels(self, bgr: np.ndarray) -> np.ndarray:
        c = self.config
        if c.max_width is not None and bgr.shape[1] > c.max_width:
            height = max(1, round(bgr.shape[0] * c.max_width / bgr.shape[1]))
            bgr = cv2.resize(bgr, (c.max_width, height), interpolation=cv2.INTER_AREA)
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY if c.grey else cv2.COLOR_BGR2RGB)

    def _camera(self, full_width: int, image: np.ndarray) -> Camera | None:
        camera = given_camera(self.config.camera, full_width, round(image.shape[0] * full_width / image.shape[1]))
        if camera is None or image.shape[1] == full_width:
            return camera
        return camera.scaled(image.shape[1] / full_width)

    def statistics(self) -> dict[str, int]:
        return {"n_frames_skipped_repeated_timestamp": self.n_skipped_timestamps}
