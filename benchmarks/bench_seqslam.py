"""How SeqSLAM's cost grows with the map: 1k/2k/4k/8k reference frames of the synthetic world.

Frames are rendered and described once per size (not timed); the timed part is the
detector alone, fed the same vectors: ``seqslam`` (full difference matrix),
``seqslam_fast`` (k = 20 nearest references, exact and by FAISS HNSW) and the single-image
``nearest_neighbour`` baseline. Peak memory is what the detector allocates (tracemalloc).

Run: .venv/bin/python benchmarks/bench_seqslam.py [--sizes 1000 2000 4000 8000]
"""

from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.frame import Frame  # noqa: E402
from slamfront.messages import Features  # noqa: E402
from slamfront.plugin import StageInputs  # noqa: E402
from slamfront_plugins.descriptors.downsampled import DownsampledImage  # noqa: E402
from slamfront_plugins.descriptors.seqslam_thumbnail import SeqSlamThumbnail  # noqa: E402
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour  # noqa: E402
from slamfront_plugins.loop_detectors.seqslam import SeqSlam, SeqSlamFast  # noqa: E402
from slamfront_plugins.sources.synthetic import SyntheticWorld  # noqa: E402


def describe(n: int) -> tuple[list[Frame], np.ndarray, np.ndarray]:
    """Frames (pixels dropped) and both descriptors of a paired synthetic run of n + n frames."""
    source = SyntheticWorld(SyntheticWorld.Config(
        frames_per_traversal=n, route_length_m=float(n), image_width=64, image_height=32, query_occluders=0,
    ))
    thumbnail, downsampled = SeqSlamThumbnail(), DownsampledImage()
    frames, seq, down = [], [], []
    for frame in tqdm(source.frames(), total=len(source), desc=f"render {n}+{n}", leave=False):
        seq.append(thumbnail.describe(frame.image))
        down.append(downsampled.describe(frame.image))
        frames.append(Frame(index=frame.index, timestamp=frame.timestamp, image=frame.image[:1, :1],
                            traversal=frame.traversal))
    return frames, np.array(seq), np.array(down)


def timed(detector, frames: list[Frame], vectors: np.ndarray) -> tuple[float, float, int]:
    """Seconds, peak MB allocated, and number of answers of one detector over the run."""
    tracemalloc.start()
    start = time.perf_counter()
    answers = 0
    for frame, vector in zip(frames, vectors):
        inputs = StageInputs(frame=frame, outputs={"descriptor": [Features(frame=frame.index, vector=vector)]})
        answers += sum(r.match >= 0 for r in detector.process(inputs))
    answers += sum(r.match >= 0 for r in detector.finish())
    seconds = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    return seconds, peak, answers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 2000, 4000, 8000])
    args = parser.parse_args()
    rows = []
    base = None
    for n in args.sizes:
        frames, seq, down = describe(n)
        full_s, full_mb, full_n = timed(SeqSlam(), frames, seq)
        fast_s, fast_mb, _ = timed(SeqSlamFast(), frames, seq)
        hnsw_s, _, _ = timed(SeqSlamFast(SeqSlamFast.Config(knn="hnsw")), frames, seq)
        nn_s, nn_mb, _ = timed(NearestNeighbour(), frames, down)
        base = base or full_s
        rows.append([n, full_s, full_s / base, full_mb, fast_s, full_s / fast_s, hnsw_s, full_s / hnsw_s, fast_mb,
                     nn_s, full_s / nn_s, full_n])
        print(table(["refs"], [[n]]), flush=True)
    body = "\n\n".join([
        "Paired synthetic world, n reference + n query frames at 64x32 (1 m apart), OpenSeqSLAM defaults "
        "(ds 10, v 0.8-1.2, R 10); detector time only (rendering and description excluded).",
        table(
            ["references", "seqslam s", "vs first", "seqslam peak MB", "fast (exact kNN) s", "speed-up",
             "fast (HNSW) s", "speed-up", "fast peak MB", "nearest_neighbour s", "seqslam / NN", "answers"],
            rows,
        ),
        "Doubling the map doubles the work per query and the number of queries: seqslam's time grows "
        "about 4x per doubling (n^2); memory stays bounded by the chunked difference matrix "
        "(references x 256 queries), not n^2. The exact-kNN fast variant still compares every "
        "reference (only the search shrinks); the HNSW variant avoids that, at the cost of building "
        "the index.",
    ])
    publish("seqslam_scaling", "SeqSLAM scaling with map size", body)


if __name__ == "__main__":
    main()
