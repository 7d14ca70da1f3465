"""Writing a run's trajectories as TUM files (``<name>.tum``), atomically.

The runtime writes them once, beside ``metrics.json``, from what the evaluations
collected (:attr:`slamfront.evaluation.EvaluationReport.trajectories`): plugins never
write files. Each line is ``timestamp tx ty tz qx qy qz qw`` with the frame's own
timestamp, so ``evo`` and the TUM benchmark tools pair the files with each other and
with any other trajectory of the same recording.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from slamfront.formats.poses import Trajectory, write_tum

SUFFIX = ".tum"


def write_trajectory_files(out_dir: Path, trajectories: Mapping[str, Trajectory]) -> list[Path]:
    """Write each trajectory to ``out_dir/<name>.tum`` (atomically, never through a link).

    :returns: the files written, in the order given.
    """
    written = []
    for name, trajectory in trajectories.items():
        if len(trajectory) == 0:
            continue
        written.append(write_tum(out_dir / f"{name}{SUFFIX}", trajectory))
    return written
