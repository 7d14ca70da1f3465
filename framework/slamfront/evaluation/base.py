"""What an evaluation is: it watches the run's messages, then turns them into metrics,
a report section and plots.

The framework scores the shared contract itself (frames, descriptors, loop results);
plugin packages contribute evaluations of their own messages with the
``slamfront_evaluations`` hook, as ``slamfront.Evaluation`` subclasses.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from slamfront.formats.poses import Trajectory as PoseFile
from slamfront.messages import Message
from slamfront.plugin import Source
from slamfront.recipe import EvalOptions


@dataclass
class EvaluationContext:
    """What an evaluation gets at the end of a run."""

    source: Source
    out_dir: Path
    options: EvalOptions
    statistics: dict[str, Any]
    """Stage statistics and run counters already in ``metrics.json``."""
    plugin_names: dict[str, str]
    """The recipe's plugin name per kind, for labels."""


@dataclass
class EvaluationReport:
    """An evaluation's results: metrics for ``metrics.json`` and a section of ``report.md``."""

    title: str
    metrics: dict[str, Any] = field(default_factory=dict)
    markdown: str = ""
    figures: list[str] = field(default_factory=list)
    """PNG file names (relative to the run folder) the section shows."""
    trajectories: dict[str, PoseFile] = field(default_factory=dict)
    """Trajectories the runtime writes into the run folder as ``<name>.tum`` (TUM format,
    stamped with the frames' own timestamps): ``groundtruth``, ``odometry``, ``optimised``,
    ``estimated``."""


class Evaluation:
    """Base of every evaluation, the framework's and the plugins'. One object scores one
    run: :meth:`observe` sees each message as it is logged (keep only what the end needs,
    never images), :meth:`finish` turns that into an :class:`EvaluationReport`."""

    title: ClassVar[str] = ""

    def observe(self, kind: str, message: Message) -> None:
        """Called for every message the run logs; ``kind`` is the producing stage or ``frames``."""

    def finish(self, context: EvaluationContext) -> EvaluationReport | None:
        """Compute metrics and write plots; None when there is nothing to evaluate."""
        raise NotImplementedError
