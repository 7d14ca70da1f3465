"""How the RST-SHelo defaults were chosen: retrieval on held-out data only.

The held-out data is in no reported number: Nordland frames 2900-3575 (summer reference,
winter query; the generalisation benchmark's Nordland chunks and its "frames 0-2899" row
leave them out) and the synthetic street world at seeds 100, 101 and 102, day reference
against a dusk and a night query (the benchmark uses seeds 0-4). For each descriptor
setting: the share of queries with a correct reference (zeta = 3) among the psi nearest
descriptors (L1), psi = 1, 5, 20 (Rodrigues 2019 Figs 4.1/4.2); synthetic = mean of the
six pairs. First the grid (cells, cells per block, bins, spatial sharing) with the
preprocessing at its default; then the preprocessing variants on the chosen grid.

Run: nice .venv/bin/python benchmarks/bench_descriptor_tuning.py
"""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.core.distances import k_nearest  # noqa: E402
from slamfront_plugins.descriptors.rst_shelo import RstShelo  # noqa: E402
from slamfront_plugins.sources.paired_datasets import Nordland  # noqa: E402
from slamfront_plugins.sources.synthetic import SyntheticWorld  # noqa: E402

NORDLAND_HELD_OUT = 2900
SYNTHETIC_SEEDS = (100, 101, 102)
KS = (1, 5, 20)
CHOSEN = {"cells_x": 32, "cells_y": 16, "block_x": 2, "block_y": 2, "bins": 9, "spatial_soft": True}
PREPROCESSING = {
    "auto (default: no blur below a 192-pixel short side; equalisation)": {},
    "Gaussian 5x5 + equalisation (Rodrigues 2019 as written)": {"gaussian_kernel": 5},
    "equalisation only": {"gaussian_kernel": 0},
    "none": {"preprocess": False},
}


def paired_grey(source: object) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Reference and query grey images of a frame-aligned paired source."""
    reference, query = [], []
    for frame in source.frames():  # type: ignore[attr-defined]
        (reference if frame.traversal == "reference" else query).append(frame.gray())
    return reference, query


def held_out() -> dict[str, tuple[list[np.ndarray], list[np.ndarray]]]:
    data = {"nordland": paired_grey(Nordland(Nordland.Config(reference="summer", query="winter",
                                                             start=NORDLAND_HELD_OUT)))}
    for seed, light in itertools.product(SYNTHETIC_SEEDS, ("dusk", "night")):
        config = SyntheticWorld.Config(seed=seed, query_illumination=light, frames_per_traversal=400,
                                       route_length_m=400)
        data[f"synthetic {seed} {light}"] = paired_grey(SyntheticWorld(config))
    return data


def retrieval(params: dict, reference: list[np.ndarray], query: list[np.ndarray], tolerance: int = 3) -> np.ndarray:
    """(len(KS),) recall among the psi nearest; featureless queries count as misses."""
    describe = RstShelo(RstShelo.Config(**params)).describe
    refs = np.stack([describe(g) for g in reference])
    queries = np.stack([describe(g) for g in query])
    nearest = k_nearest(queries, refs, max(KS), "l1")
    hit = np.abs(nearest - np.arange(len(queries))[:, None]) <= tolerance
    hit[~queries.any(axis=1)] = False
    return np.array([hit[:, :k].any(axis=1).mean() for k in KS])


def scores(params: dict, data: dict) -> list[object]:
    per = {name: retrieval(params, *pair) for name, pair in data.items()}
    synthetic = np.mean([v for name, v in per.items() if name.startswith("synthetic")], axis=0)
    return ["/".join(f"{x:.3f}" for x in per["nordland"]), "/".join(f"{x:.3f}" for x in synthetic)]


def main() -> None:
    data = held_out()
    grid_rows = []
    for (cx, cy), (bx, by), bins, soft in itertools.product(((16, 8), (32, 16)), ((2, 2), (4, 4)), (6, 9, 12),
                                                          (True, False)):
        params = {"cells_x": cx, "cells_y": cy, "block_x": bx, "block_y": by, "bins": bins, "spatial_soft": soft}
        mark = " **(chosen)**" if params == CHOSEN else ""
        length = (cx // bx) * (cy // by) * bins
        grid_rows.append([f"{cx} x {cy}", f"{bx} x {by}", bins, "yes" if soft else "no", length + 0,
                          *scores(params, data), mark])
    pre_rows = [[label, *scores({**CHOSEN, **extra}, data)] for label, extra in PREPROCESSING.items()]
    headers = ["Nordland 2900-3575 r@1/5/20", "synthetic seeds 100-102 r@1/5/20"]
    body = "\n\n".join([
        "`nice .venv/bin/python benchmarks/bench_descriptor_tuning.py`. Held-out data only: Nordland frames "
        f"{NORDLAND_HELD_OUT}-3575 (summer reference, winter query) and the synthetic world at seeds "
        f"{', '.join(map(str, SYNTHETIC_SEEDS))} (day reference, dusk and night queries, 400 frames each; mean of "
        "the six). Recall among the 1, 5 and 20 nearest descriptors, zeta = 3.",
        "## Grid, with the default preprocessing\n\n" + table(
            ["cells", "cells per block", "bins", "votes shared between blocks", "values", *headers, ""], grid_rows),
        "## Preprocessing, on the chosen grid\n\n" + table(["preprocessing", *headers], pre_rows),
    ])
    publish("descriptor_tuning", "RST-SHelo defaults chosen on held-out data", body)


if __name__ == "__main__":
    main()
