"""SeqSLAM's detector against the hardware floor for the same work, on the whole Nordland route.

The work of `nordland_seqslam` (Rodrigues 2019's settings: 32x32 thumbnails, ds 40, v 1-1.5,
3,576 references x 3,576 queries): the difference matrix (13 billion absolute byte
differences), the contrast enhancement, and the straight-trajectory search (for each of
3,536 answered queries, 21 velocities x 41 columns x 3,576 start rows: 10.9 billion
float64 additions), then the answers. Its default search is now the speed-free one (``search: paths``: paths of
straight 20-frame segments at 0.5-2x, both directions, by dynamic programming); the
straight-trajectory search (``search: lines``, OpenSeqSLAM's) is timed beside it, and the
whole detector with each.

The path search's floor is derived, not compiled: its additions (per answered query and
reference row, 2 directions x 2 sides x moves x segment length) at the rate the C floor
adds the straight trajectories' (the same contiguous float64 adds; the path's minimum per
segment is left out, so the ratio is an upper bound).

The floor is that arithmetic and nothing else, as tight C compiled here with
``gcc -O3 -march=native -fopenmp`` on 2 threads: the difference matrix with AVX2's
``_mm256_sad_epu8`` (32 absolute differences summed per instruction), and the trajectory
sums as contiguous float64 vector adds. The detector is timed fed the same thumbnails
(description and the rest of the run excluded), in the same process, right after.
Both numbers and their ratio come from one run.

Run: .venv/bin/python benchmarks/bench_seqslam_floor.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import ctypes
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from common import publish, table  # noqa: E402

from slamfront.core.seqslam import (  # noqa: E402
    difference_columns,
    enhance_contrast,
    path_offsets,
    path_scores_block,
    path_segments,
    sequence_scores_block,
    trajectory_offsets,
)
from slamfront.frame import Frame  # noqa: E402
from slamfront.messages import Features  # noqa: E402
from slamfront.plugin import StageInputs  # noqa: E402
from slamfront.recipe import build_pipeline, load_recipe  # noqa: E402
from tests.test_seqslam import _numpy_sequence_scores  # noqa: E402  (the former sweep, the tests' oracle)

FLOOR_C = r"""
#include <immintrin.h>
#include <stdint.h>
#include <omp.h>

/* out[i*m + j] = sum |a_i - b_j| over p bytes (p a multiple of 32) */
void sad_matrix(const uint8_t *a, const uint8_t *b, int32_t *out, int n, int m, int p, int threads) {
    #pragma omp parallel for num_threads(threads) schedule(static)
    for (int i = 0; i < n; i++) {
        const uint8_t *ai = a + (long)i * p;
        for (int j = 0; j < m; j++) {
            const uint8_t *bj = b + (long)j * p;
            __m256i acc = _mm256_setzero_si256();
            for (int k = 0; k < p; k += 32) {
                __m256i x = _mm256_loadu_si256((const __m256i *)(ai + k));
                __m256i y = _mm256_loadu_si256((const __m256i *)(bj + k));
                acc = _mm256_add_epi64(acc, _mm256_sad_epu8(x, y));
            }
            __m128i s = _mm_add_epi64(_mm256_castsi256_si128(acc), _mm256_extracti128_si256(acc, 1));
            out[(long)i * m + j] = (int32_t)(_mm_cvtsi128_si64(s) + _mm_extract_epi64(s, 1));
        }
    }
}

/* columns: (c, stride) float64, query q uses columns q..q+w-1; best: (nq, r) */
void trajectories(const double *columns, long stride, const long *offsets, int nv, int w, int r, int nq,
                  double *best, int threads) {
    #pragma omp parallel num_threads(threads)
    {
        double *cost = (double *)__builtin_alloca(sizeof(double) * r);
        #pragma omp for schedule(static)
        for (int q = 0; q < nq; q++) {
            double *b = best + (long)q * r;
            for (int x = 0; x < r; x++) b[x] = __builtin_inf();
            for (int v = 0; v < nv; v++) {
                for (int x = 0; x < r; x++) cost[x] = 0.0;
                for (int k = 0; k < w; k++) {
                    const double *col = columns + (long)(q + k) * stride + offsets[v * w + k];
                    for (int x = 0; x < r; x++) cost[x] += col[x];
                }
                for (int x = 0; x < r; x++) b[x] = cost[x] < b[x] ? cost[x] : b[x];
            }
        }
    }
}
"""


def former_difference(references: np.ndarray, query: np.ndarray) -> np.ndarray:
    """One query's difference column as the former code computed it (OpenCV absdiff + row sums)."""
    absolute = cv2.absdiff(references, np.broadcast_to(query, references.shape).copy())
    return cv2.reduce(absolute, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S)[:, 0]


def compile_floor(folder: Path) -> ctypes.CDLL | None:
    """The floor kernels, or None when no C compiler or no AVX2 is available."""
    if platform.machine() not in ("x86_64", "AMD64"):
        return None
    source, library = folder / "floor.c", folder / "floor.so"
    source.write_text(FLOOR_C)
    done = subprocess.run(["gcc", "-O3", "-march=native", "-fopenmp", "-shared", "-fPIC", str(source), "-o", str(library)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        print(done.stderr)
        return None
    lib = ctypes.CDLL(str(library))
    pointer = np.ctypeslib.ndpointer
    lib.sad_matrix.argtypes = [pointer(np.uint8), pointer(np.uint8), pointer(np.int32)] + [ctypes.c_int] * 4
    lib.trajectories.argtypes = [pointer(np.float64), ctypes.c_long, pointer(np.int64)] + [ctypes.c_int] * 4 + \
        [pointer(np.float64), ctypes.c_int]
    return lib


def nordland_thumbnails() -> tuple[list[Frame], np.ndarray, dict]:
    """The recipe's reference and query thumbnails (described once, not timed) and its detector config."""
    recipe, path = load_recipe("nordland_seqslam", [])
    pipeline = build_pipeline(recipe, str(path))
    describe = pipeline.plugins["descriptor"].describe
    frames, vectors = [], []
    for frame in tqdm(pipeline.source.frames(), total=len(pipeline.source), desc="describe", leave=False):
        vectors.append(describe(frame.image))
        frames.append(Frame(index=frame.index, timestamp=frame.timestamp, image=frame.image[:1, :1],
                            traversal=frame.traversal))
    return frames, np.array(vectors), pipeline.plugins["loop_detector"]


def time_detector(detector_factory, frames: list[Frame], vectors: np.ndarray) -> float:  # type: ignore[no-untyped-def]
    detector = detector_factory()
    start = time.perf_counter()
    for frame, vector in zip(frames, vectors):
        detector.process(StageInputs(frame=frame, outputs={"descriptor": [Features(frame=frame.index, vector=vector)]}))
    detector.finish()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="best of this many timings of each")
    args = parser.parse_args()
    frames, vectors, detector = nordland_thumbnails()
    c = detector.config
    is_ref = np.array([f.traversal == "reference" for f in frames])
    references, queries = np.ascontiguousarray(vectors[is_ref]), np.ascontiguousarray(vectors[~is_ref])
    offsets = trajectory_offsets(c.ds, c.vmin, c.vmax)
    n_ref, n_q, pixels = len(references), len(queries), references.shape[1]
    answered = n_q - c.ds
    load = [os.getloadavg()[0]]

    def best(work) -> float:  # type: ignore[no-untyped-def]
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            work()
            times.append(time.perf_counter() - start)
        return min(times)

    # our pieces (the detector's own functions), then the whole detector
    differences = difference_columns(references, queries)
    enhanced = enhance_contrast(differences, c.contrast_window)
    shifted = enhanced.astype(np.float64) - float(enhanced.min())
    blocks = range(0, answered, c.chunk)  # the detector's blocks of queries
    ours = {
        "difference matrix": best(lambda: difference_columns(references, queries)),
        "contrast enhancement": best(lambda: [enhance_contrast(differences[:, s : s + c.chunk + c.ds], c.contrast_window)
                                              for s in blocks]),
        "trajectory search": best(lambda: [sequence_scores_block(shifted[:, s : min(s + c.chunk, answered) + c.ds], offsets)
                                           for s in blocks]),
        "path search (default)": best(lambda: [path_scores_block(
            shifted[:, s : min(s + c.chunk, answered) + c.ds], c.ds, c.path_segment, c.path_low, c.path_high,
            c.reverse) for s in blocks]),
    }
    # the former implementation on a sample of queries, scaled to all of them
    sample = 64
    former = {
        "difference matrix": best(lambda: [former_difference(references, q) for q in queries[:sample]]) * n_q / sample,
        "trajectory search": best(lambda: [_numpy_sequence_scores(shifted[:, n : n + c.ds + 1], offsets)
                                           for n in range(sample)]) * answered / sample,
    }
    detector_seconds = best(lambda: time_detector(lambda: type(detector)(detector.config), frames, vectors))
    lines_config = detector.config.model_copy(update={"search": "lines"})
    lines_seconds = best(lambda: time_detector(lambda: type(detector)(lines_config), frames, vectors))
    load.append(os.getloadavg()[0])

    floor: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as folder:
        lib = compile_floor(Path(folder))
        if lib is not None:
            sums = np.empty((n_ref, n_q), dtype=np.int32)
            floor["difference matrix"] = best(lambda: lib.sad_matrix(references, queries, sums, n_ref, n_q, pixels, 2))
            assert np.array_equal(sums.astype(np.float32) / np.float32(pixels), differences), "floor SAD disagrees"
            reach = int(offsets.max())
            columns = np.full((n_q, n_ref + reach + 1), np.inf)
            columns[:, :n_ref] = shifted.T
            flat_offsets = np.ascontiguousarray(offsets, dtype=np.int64)
            scores = np.empty((answered, n_ref))
            floor["trajectory search"] = best(lambda: lib.trajectories(
                columns, columns.shape[1], flat_offsets, len(offsets), c.ds + 1, n_ref, answered, scores, 2))
            check = sequence_scores_block(shifted[:, : 50 + c.ds], offsets)
            assert np.array_equal(check, scores[:50]), "floor trajectory sums disagree"
    load.append(os.getloadavg()[0])
    bounds = path_segments(c.ds, c.path_segment)
    moves = path_offsets(bounds, c.path_low, c.path_high).shape[1]
    path_adds = answered * n_ref * (2 if c.reverse else 1) * 2 * moves * int(bounds[-1])
    line_adds = answered * len(offsets) * (c.ds + 1) * n_ref
    if "trajectory search" in floor:
        floor["path search (default)"] = floor["trajectory search"] * path_adds / line_adds

    work = {
        "difference matrix": f"{n_ref * n_q * pixels / 1e9:.1f} G byte differences",
        "contrast enhancement": f"{n_ref * n_q / 1e6:.1f} M entries",
        "trajectory search": f"{line_adds / 1e9:.1f} G float64 additions (search: lines)",
        "path search (default)": f"{path_adds / 1e9:.1f} G float64 additions (search: paths; floor derived)",
    }
    rows = [[part, work[part], former.get(part, "-"), ours[part], floor.get(part, "-"),
             ours[part] / floor[part] if part in floor else "-"] for part in ours]
    floor_paths = floor.get("difference matrix", 0.0) + floor.get("path search (default)", 0.0)
    floor_lines = floor.get("difference matrix", 0.0) + floor.get("trajectory search", 0.0)
    rows.append(["whole detector (process + finish), search: paths (default)", "difference matrix + paths + answers",
                 "-", detector_seconds, floor_paths if floor else "-", detector_seconds / floor_paths if floor else "-"])
    rows.append(["whole detector (process + finish), search: lines", "difference matrix + lines + answers", "-",
                 lines_seconds, floor_lines if floor else "-", lines_seconds / floor_lines if floor else "-"])
    body = "\n\n".join([
        f"Whole Nordland route, `nordland_seqslam` settings (ds {c.ds}, v {c.vmin}-{c.vmax} for lines, paths of "
        f"{c.path_segment}-frame segments at {c.path_low}-{c.path_high} both ways, R {c.contrast_window}): "
        f"{n_ref} references x {n_q} queries of {pixels} pixels. Best of {args.repeats}; load (1-min average) "
        f"{', '.join(f'{v:.1f}' for v in load)} at start, after ours, after the floor, on {os.cpu_count()} cores.",
        table(["part", "work", "former NumPy/OpenCV s (sampled)", "slamfront s", "floor s (C, 2 threads)",
               "slamfront / floor"], rows),
        f"The former column runs the code these parts replaced (OpenCV `absdiff` per query; the NumPy sweep, "
        f"kept as the tests' oracle) on the first {sample} queries and scales to all of them.",
        "Floor: gcc -O3 -march=native -fopenmp, 2 threads: `_mm256_sad_epu8` for the difference matrix (its "
        "sums are checked equal to ours), contiguous float64 adds for the trajectory search (checked equal to "
        "ours on 50 queries). The floor's whole-detector figure is its difference matrix + trajectory search only "
        "(contrast enhancement and answers left out), so the ratio is an upper bound. The path search's floor is "
        "the C straight-trajectory floor scaled by the ratio of additions (derived, not compiled): it is only as "
        "tight as that kernel's addition rate, and the path kernel's vectorised slice additions beat it (a ratio "
        "below 1 says the derived figure is not a floor).",
    ])
    publish("seqslam_floor", "SeqSLAM detector vs the hardware floor", body)


if __name__ == "__main__":
    main()
