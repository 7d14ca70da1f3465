"""What a plugin is: a class with a name, a kind, a docstring and a pydantic ``Config``.

Kinds, in the order a run calls them for each frame::

    source -> descriptor -> place_map -> loop_detector -> localizer -> registration -> backend

A plugin is constructed as ``Plugin(config)``, nothing else. A stage receives each frame
together with the outputs earlier stages produced for it (:class:`StageInputs`) and
returns its own outputs as :class:`~slamfront.messages.Message` objects, which the
runtime logs and evaluates. Plugins never write files.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

import numpy as np
from pydantic import BaseModel, ConfigDict

from slamfront.errors import PluginError
from slamfront.frame import Frame
from slamfront.kinds import KINDS, STAGE_KINDS, Kind  # noqa: F401 (re-exported: plugin authors import them from here)
from slamfront.messages import Features, Message

if TYPE_CHECKING:
    from slamfront.core.loops import LoopGroundTruth
    from slamfront.datasets import DatasetDownload
    from slamfront.feeds import FrameLogger
    from slamfront.recipe import LogOptions



class PluginConfig(BaseModel):
    """Base of every plugin's ``Config``: unknown keys are errors, not silently ignored."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class Plugin:
    """Base of every plugin.

    :cvar name: the name recipes use (``plugin: <name>``); unique within its kind.
    :cvar kind: one of :data:`KINDS`; set by the kind's base class below.
    :cvar version: the plugin's own version, recorded in every log it runs in.
    """

    name: ClassVar[str]
    kind: ClassVar[Kind]
    version: ClassVar[str] = "0.1.0"

    class Config(PluginConfig):
        """No parameters."""

    def __init__(self, config: PluginConfig | None = None) -> None:
        self.config = config if config is not None else self.Config()

    @classmethod
    def summary(cls) -> str:
        """The first line of the docstring."""
        return (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""

    def check(self, stages: Mapping[str, Plugin]) -> None:
        """Verify this plugin can work with the others in the recipe, before any frame.

        :param stages: every plugin of the recipe, by kind (``"source"`` included).
        :raises PluginError: naming the incompatible plugins and why.
        """


class Source(Plugin):
    """Yields frames. Sources are the only plugins that read data."""

    kind: ClassVar[Kind] = "source"
    downloads: ClassVar[tuple[DatasetDownload, ...]] = ()
    """Public datasets this source reads, for ``slamfront datasets download``."""

    def frames(self) -> Iterator[Frame]:
        """Yield the run's frames in order, lazily, with ``index`` counting from 0."""
        raise NotImplementedError

    def __len__(self) -> int:
        """How many frames :meth:`frames` will yield (for progress bars)."""
        raise NotImplementedError

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        """Which reported matches count as correct, for loop-detection evaluation."""
        return None

    def statistics(self) -> dict[str, float | int]:
        """Counters for ``metrics.json`` (e.g. frames a recording dropped), read after the last frame."""
        return {}

    def loop_ground_truth_at(self, tolerance: int) -> LoopGroundTruth | None:
        """The same ground truth with another tolerance zeta (frames either side).

        Lets one run be scored at several tolerances (``eval.tolerances``). None: this
        source has no tolerance to change.
        """
        return None

    def frame_logger(self, options: LogOptions) -> FrameLogger:
        """What writes each frame's own topics to the run's log (info, image, depth,
        calibration, pose). The default encodes the frame as the recipe's ``log`` options
        say; a source whose frames arrive already encoded may return a logger that copies
        them (a replayed log's source does)."""
        from slamfront.feeds import FrameLogger

        return FrameLogger(options)

    def ending_note(self) -> str:
        """Said at the end of the run's last ``/log`` line: what a reader of the log should
        know about how the frames were read (e.g. frames left out). Default: nothing."""
        return ""


@dataclass
class StageInputs:
    """What a stage gets for one frame: the outputs of the stages that ran before it.

    :ivar frame: the frame being processed.
    :ivar outputs: messages earlier stages returned for this frame, by stage kind.
    :ivar stages: the earlier stage plugins themselves, by kind, for stages that query
        another (a detector asking the place map for nearest neighbours).
    """

    frame: Frame
    outputs: dict[str, list[Message]] = field(default_factory=dict)
    stages: Mapping[str, Stage] = field(default_factory=dict)

    def one(self, kind: str, message_type: type[Any] = Message) -> Any:
        """The single message of ``message_type`` an earlier ``kind`` stage produced.

        :raises KeyError: when that stage produced none for this frame.
        """
        for message in self.outputs.get(kind, ()):
            if isinstance(message, message_type):
                return message
        raise KeyError(f"stage {kind!r} produced no {message_type.__name__} for frame {self.frame.index}")


def require_global_descriptor(stages: Mapping[str, Plugin]) -> None:
    """For ``check()``: refuse a recipe whose descriptor produces no global vector.

    :raises PluginError: naming the descriptor.
    """
    descriptor = stages.get("descriptor")
    if descriptor is None or not getattr(descriptor, "produces_global", False):
        name = descriptor.name if descriptor is not None else "none"
        raise PluginError(f"needs a global descriptor; {name!r} produces none")


def global_features(inputs: StageInputs) -> Features:
    """The descriptor's ``Features`` for this frame, which must carry a global ``vector``.

    :raises PluginError: the descriptor gave no global vector.
    """
    features: Features = inputs.one("descriptor", Features)
    if features.vector is None:
        raise PluginError(f"descriptor gave no global vector for frame {features.frame}")
    return features


class Stage(Plugin):
    """A processing stage: called once per frame, then once at the end of the run."""

    requires: ClassVar[tuple[Kind, ...]] = ()
    """Stage kinds that must run before this one (checked when the recipe is loaded)."""

    reads_pixels: ClassVar[bool] = False
    """Whether :meth:`process` reads ``frame.image`` or ``frame.depth``. A replay
    (``slamfront replay``) re-runs such a stage only from a log that stores them exactly
    (``log.image_format: png`` at full width, depth as ``32FC1``)."""

    @classmethod
    def reads_pixels_with(cls, config: PluginConfig) -> bool:
        """Whether a stage with this ``config`` reads pixels: :attr:`reads_pixels` unless a
        plugin overrides it because some settings make the pixels unnecessary."""
        return cls.reads_pixels

    def process(self, inputs: StageInputs) -> Sequence[Message]:
        """Process one frame; return this stage's outputs (possibly about earlier frames)."""
        raise NotImplementedError

    def finish(self) -> Sequence[Message]:
        """Called after the last frame: return any outputs still pending."""
        return ()

    def statistics(self) -> dict[str, float | int]:
        """Counters for ``metrics.json`` (e.g. ``n_searches``), read after :meth:`finish`."""
        return {}


class Descriptor(Stage):
    """Frame -> global vector and/or local keypoints with descriptors (``Features``)."""

    kind: ClassVar[Kind] = "descriptor"
    reads_pixels: ClassVar[bool] = True
    produces_global: ClassVar[bool] = False
    produces_local: ClassVar[bool] = False


class PlaceMap(Stage):
    """An incremental topological map with nearest-neighbour search over its places."""

    kind: ClassVar[Kind] = "place_map"
    requires: ClassVar[tuple[Kind, ...]] = ("descriptor",)


@runtime_checkable
class SearchablePlaceMap(Protocol):
    """What a sequence loop detector may ask of the recipe's place map, and nothing more.

    A place map groups the frames it sees into *places* (runs of consecutive frames of one
    traversal) and tells each frame's place in a ``PlaceAssignment``; it may hold frames
    back (while it calibrates itself) and assign several at once, or in its ``finish``.
    Some places join its searchable *map* at once (the reference traversal's); a detector
    adds the others with :meth:`commit`.

    Addresses: frames by frame index; places by place id (every place ever made, in
    order); map places by *map position* (0, 1, ... in joining order); the frames of the
    map places, in map order, by *map-frame position*. The built-in ``hierarchical`` place
    map (Rodrigues 2019 §3.1) and ``flat`` (one place per frame) implement it; a detector
    checks for it with ``isinstance(place_map, SearchablePlaceMap)``, never for a class.
    """

    # --- places -------------------------------------------------------------------------
    def place_of(self, frame: int) -> int:
        """The id of the place a frame was assigned to."""

    def vectors(self, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        """(n, D) descriptors of frames (by frame index)."""

    def informative(self, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        """(n,) bool: frames whose descriptor is not all zeros (not featureless)."""

    def representatives(self, places: Sequence[int] | np.ndarray) -> np.ndarray:
        """(n, D) the vectors places are searched by, R(P) (by place id)."""

    # --- the map --------------------------------------------------------------------------
    def commit(self, place: int) -> int:
        """Add a place to the map (places join in order); returns its map position."""

    def place_offsets(self) -> np.ndarray:
        """(P + 1,) map-frame offsets of the P map places: place p covers ``[o[p], o[p + 1])``."""

    def map_frames_at(self, positions: np.ndarray) -> np.ndarray:
        """Frame indices at map-frame positions."""

    def map_representatives(self, positions: Sequence[int] | np.ndarray) -> np.ndarray:
        """(n, D) representatives of map places (by map position)."""

    # --- search and distance calibration --------------------------------------------------
    def nearest(self, vector: np.ndarray, k: int, lo: int = 0, hi: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` map places whose representatives are nearest to ``vector`` among map
        positions ``lo..hi`` (exact): ``(positions, distances)``, nearest first."""

    @property
    def search_distances(self) -> int:
        """Descriptor distances :meth:`nearest` computed so far."""

    @property
    def metric(self) -> str:
        """The descriptor distance (``l1``, ``l2``, ``hamming`` or ``cosine``)."""

    def similarity(self, distance: float | np.ndarray) -> float | np.ndarray:
        """A distance on the map's similarity scale S in [0, 1] (1: identical)."""


class LoopDetector(Stage):
    """Query frame -> ``LoopResult``: a match and a confidence, or an explicit no-answer."""

    kind: ClassVar[Kind] = "loop_detector"


class Localizer(Stage):
    """Frame -> pose or node in a keyframe map."""

    kind: ClassVar[Kind] = "localizer"
    reads_pixels: ClassVar[bool] = True


class Registration(Stage):
    """Point clouds -> relative transforms and a global model."""

    kind: ClassVar[Kind] = "registration"
    reads_pixels: ClassVar[bool] = True


class Backend(Stage):
    """Odometry and loop closures -> an optimised trajectory."""

    kind: ClassVar[Kind] = "backend"


KIND_BASES: Mapping[Kind, type[Plugin]] = {
    "source": Source,
    "descriptor": Descriptor,
    "place_map": PlaceMap,
    "loop_detector": LoopDetector,
    "localizer": Localizer,
    "registration": Registration,
    "backend": Backend,
}
