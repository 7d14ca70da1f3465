"""The two hierarchical detectors on the whole Nordland route: how each deviation from
Rodrigues 2019 changes the result, how steady the result is in nu, and whether the
continuation of earlier answers drifts.

1. nu: the automatic nu (chosen on the summer traversal) and nu +- 0.005, +- 0.01, for the
   frame-level detector (``nordland_hsl``) and the faithful one (``nordland_hsl_faithful``):
   recall at 100 % precision, AUC-PR, the correct-answer ceiling, distances.
2. Deviations: the frame-level detector with each of its departures from the thesis switched
   back one at a time (same route, same nu).
3. Drift: accuracy of the answers against how many iterations in a row the continuation
   answered (frame-level: the track; faithful: the rebuilt sequence and the synthetic
   continuation), from the runs' ``SequenceDecision`` / ``FaithfulSequenceDecision`` messages.

Run: nice .venv/bin/python benchmarks/bench_hierarchical_modes.py
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.mcaplog.reader import read_messages  # noqa: E402
from slamfront.mcaplog.topics import topic_for  # noqa: E402
from slamfront.messages import LoopResult  # noqa: E402
from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from slamfront.runtime import run_pipeline  # noqa: E402
from slamfront_plugins.loop_detectors.hierarchical_faithful import FaithfulSequenceDecision  # noqa: E402
from slamfront_plugins.loop_detectors.hierarchical_sequence import SequenceDecision  # noqa: E402

Decision = SequenceDecision | FaithfulSequenceDecision

QUICK = ["log.images=false", "eval.retrieval_max_k=0", "eval.tolerances=[]", "eval.plots=false"]
KEYS = ("recall_at_100p", "auc_pr", "correct_answer_ceiling", "answered_of_answerable", "n_distances")
DEVIATIONS = [  # label, overrides of nordland_hsl (the frame-level detector)
    ("frame-level detector, shipped defaults", []),
    ("level 2 of every level-1 candidate in full (refine: 0)", ["loop_detector.params.refine=0"]),
    ("no track (level-1 candidates only)", ["loop_detector.params.track=false"]),
    ("confidence 1 - v/2 of the chosen pairs (eq. 3.14)", ["loop_detector.params.confidence=distance"]),
    ("confidence of its own iteration only (evidence_iterations: 1)", ["loop_detector.params.evidence_iterations=1"]),
    ("no level-3 realignment of Q", ["loop_detector.params.realign=false"]),
    ("no waiting / isolation (every answer at once)", ["loop_detector.params.isolate=false"]),
    ("no line check (uniqueness against other candidates only)", ["loop_detector.params.line_check=false"]),
    ("Gaussian 5x5 as the thesis (not scaled to the image)", ["descriptor.params.gaussian_kernel=5"]),
]


def run(recipe: str, overrides: list[str], out: Path) -> tuple[dict, list[tuple[Decision, bool]]]:
    """The run's metrics, and each level-3 decision with whether its last query frame's answer
    is correct (zeta 3; exp. 1 is frame-aligned: query k shows summer frame k)."""
    loaded, path = load_recipe(recipe, [*QUICK, *overrides])
    result = run_pipeline(build_pipeline(loaded, str(path)), str(path), out, progress=False)
    topics = [topic_for("loop_detector", kind) for kind in (SequenceDecision, FaithfulSequenceDecision, LoopResult)]
    decisions, answers = [], {}
    for message in read_messages(result.log_path, topics):
        if isinstance(message.decoded, (SequenceDecision, FaithfulSequenceDecision)):
            decisions.append(message.decoded)
        else:
            answers[message.decoded.frame] = message.decoded.match
    n = int(result.metrics["n_frames_reference"])
    judged = [(d, abs(answers.get(int(d.query_frames[-1]), -10**9) - (int(d.query_frames[-1]) - n)) <= 3)
              for d in decisions]
    return result.metrics, judged


def row(label: str, metrics: dict, seqslam: float | None = None) -> list[object]:
    cells: list[object] = [label, *(round(float(metrics[k]), 3) for k in KEYS[:4]), f"{metrics['n_distances']:,}"]
    if seqslam:
        cells.append(f"{seqslam / metrics['n_distances']:.1f}x")
    return cells


BUCKETS = ("0", "1", "2-3", "4-7", "8-15", "16-31", "32+")


def drift(judged: list[tuple[Decision, bool]], faithful: bool) -> list[list[object]]:
    """Accuracy of the answered sequences by how many iterations in a row the continuation of
    earlier answers chose them: the track (frame-level), or a rebuilt sequence or the
    synthetic continuation (faithful)."""
    runs: dict[str, list[bool]] = {}
    streak = 0
    for d, correct in sorted(judged, key=lambda item: item[0].iteration):
        if d.last < 0:
            continue
        continued = d.used_synthetic or d.branch == "rebuilt" if faithful else d.track  # type: ignore[union-attr]
        streak = streak + 1 if continued else 0
        bucket = next(b for b in reversed(BUCKETS) if streak >= int(b.split("-")[0].rstrip("+")))
        runs.setdefault(bucket, []).append(correct)
    return [[b, len(runs[b]), round(float(np.mean(runs[b])), 3)] for b in BUCKETS if b in runs]


def main() -> None:
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as scratch:
        base, base_decisions = run("nordland_hsl", [], Path(scratch) / "base")
        seqslam, _ = run("nordland_seqslam", [], Path(scratch) / "seqslam")
        faithful, faithful_decisions = run("nordland_hsl_faithful", [], Path(scratch) / "faithful")
        nu = float(base["similarity_threshold"])
        sensitivity = []
        for recipe, label in (("nordland_hsl", "frame-level"), ("nordland_hsl_faithful", "faithful")):
            nu_mode = float((base if recipe == "nordland_hsl" else faithful)["similarity_threshold"])
            values = []
            for delta in (-0.01, -0.005, 0.0, 0.005, 0.01):
                if delta == 0.0:
                    metrics = base if recipe == "nordland_hsl" else faithful
                else:
                    setting = f"place_map.params.similarity_threshold={nu_mode + delta:.3f}"
                    metrics, _ = run(recipe, [setting], Path(scratch) / f"{label}{delta}")
                values.append(metrics["recall_at_100p"])
                sensitivity.append([label, f"{nu_mode + delta:.3f}", metrics["n_places_reference"],
                                    *row("", metrics)[1:]])
            sensitivity.append([label, "range of R@100%P", "", round(max(values) - min(values), 3), "", "", "", ""])
        deviations = [row("faithful detector (nordland_hsl_faithful)", faithful, seqslam["n_distances"])]
        for label, overrides in DEVIATIONS:
            metrics = base if not overrides else run("nordland_hsl", overrides, Path(scratch) / label[:12])[0]
            deviations.append(row(label, metrics, seqslam["n_distances"]))
        deviations.append(row("SeqSLAM (nordland_seqslam), for scale", seqslam, seqslam["n_distances"]))
        track = drift(base_decisions, faithful=False)
        rebuilt = drift(faithful_decisions, faithful=True)
    headers = ["setting", "R@100%P", "AUC-PR", "correct-answer ceiling", "answered of answerable", "distances"]
    body = "\n\n".join([
        f"`nice .venv/bin/python benchmarks/bench_hierarchical_modes.py` (load average {load:.1f} at the start). "
        f"Nordland whole route, summer reference, winter queries, zeta = 3; automatic nu = {nu:.3f} (frame-level "
        f"recipe) and {float(faithful['similarity_threshold']):.3f} (faithful recipe, 5x5 blur: other descriptors).",
        "## Deviations from Rodrigues 2019, one at a time\n\n"
        + table([*headers, "SeqSLAM distances / these"], deviations),
        "## Sensitivity to nu (auto +- 0.01)\n\n" + table(
            ["detector", "nu", "reference places", "R@100%P", "AUC-PR", "correct-answer ceiling", "answered of answerable",
             "distances"], sensitivity),
        "## Does the continuation drift? Accuracy of the answered query sequences (their last frame) by how many "
        "iterations in a row the continuation of earlier answers chose them\n\nFrame-level detector, `hierarchical_sequence` (the track, "
        "re-aligned and competing with level 1 at every iteration):\n\n"
        + table(["iterations in a row", "sequences", "accuracy"], track)
        + "\n\nFaithful detector, `hierarchical_faithful` (rebuilt sequences and the synthetic continuation of eq. 3.12-3.13):\n\n"
        + table(["iterations in a row", "sequences", "accuracy"], rebuilt),
    ])
    publish("hierarchical_modes", "Hierarchical detector: deviations, nu, drift (Nordland whole route)", body)


if __name__ == "__main__":
    main()
