"""Cases of the generated stress benchmark: what they are, how they are drawn, how they are laid out.

A case is one pair of traversals of the same route (a Nordland season pair, or a synthetic
street world by day against dusk or night), cut to a sub-window of the route and changed
by what a robot meets in the field: the roles of reference and query swapped, the query
driven backwards, at another pace (constant or smoothly varying between 0.5x and 2x),
with stops, or with a jump (a part of the route skipped, or driven again). Cases are drawn
once from a master seed (:func:`draw`) and written to ``stress_seeds.json``; the benchmark
only reads them. :func:`lay_out` writes a case as two image folders of links and a CSV of
query-reference pairs (the ``paired_folders`` source), so every detector runs the same
frames with its shipped recipe and only the source swapped.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from slamfront_plugins.sources.paired import images_in

NORDLAND_FRAMES = 3576
"""Frames per season of the Nordland route (summer, winter)."""
SYNTHETIC_WORLDS = (40, 41, 42, 43)
"""Synthetic street world seeds rendered for the benchmark (no design choice looked at them)."""
SYNTHETIC_FRAMES = 400
"""Frames per synthetic traversal (one per metre of a 400 m street, as the generalisation rows)."""
LIGHTS = ("dusk", "night")
WINDOW = (30, 300)
"""Frames of a case's sub-window of the route (uniform, both ends included)."""
PACE = (0.5, 2.0)
"""Speeds of a re-paced query, in reference frames per query frame."""
MAX_QUERY = 400
"""At most this many query frames per case (a 300-frame window at 0.5x would give 600): keeps a case's
cost bounded on a small machine; the pass is cut at its end."""
FAMILIES = ("swap", "reversed", "pace", "jump", "stop")
"""What a case may change, each drawn on its own; a case with none of them is *unchanged* (a sub-window)."""
CHANCE = {"swap": 0.3, "reversed": 0.25, "pace": 0.4, "jump": 0.2, "stop": 0.2}
UNCHANGED_SHARE = 0.25
"""Share of cases drawn unchanged (only a sub-window), so the recall rule has its own sample."""
TOLERANCE = 3
"""zeta: a match within this many reference frames of the query's place is correct."""


def _positions(length: int, changes: dict[str, Any]) -> np.ndarray:
    """(m,) route positions (reference frames of the window, 0..length-1) of the query pass."""
    pace = changes.get("pace")
    if pace is None:
        speeds = np.ones(4 * MAX_QUERY)
    elif pace["kind"] == "constant":
        speeds = np.full(4 * MAX_QUERY, pace["speed"])
    else:  # smooth swing between low and high, period in query frames
        t = np.arange(4 * MAX_QUERY)
        mid, half = (pace["low"] + pace["high"]) / 2, (pace["high"] - pace["low"]) / 2
        speeds = mid + half * np.sin(2 * np.pi * t / pace["period"] + pace["phase"])
    for stop in changes.get("stops", []):  # a stop: the query frame repeats (speed 0)
        speeds = np.insert(speeds, stop["at"], np.zeros(stop["frames"]))
    positions = np.concatenate([[0.0], np.cumsum(speeds)])
    positions = positions[positions <= length - 1][:MAX_QUERY]
    jump = changes.get("jump")
    if jump is not None:  # the pass leaves the route at `at` and resumes `by` frames further (or back)
        at = int(jump["at"] * (len(positions) - 1))
        after = positions[at:] + jump["by"] * length
        positions = np.concatenate([positions[:at], after[(after >= 0) & (after <= length - 1)]])
    if changes.get("reversed"):
        positions = (length - 1) - positions
    return positions


def query_places(case: dict[str, Any]) -> np.ndarray:
    """(m,) int64 reference frames of the window shown by each query frame (the pass's ground truth)."""
    return np.floor(_positions(case["length"], case["changes"]) + 1e-9).astype(np.int64)


def draw_case(master: np.random.Generator, number: int) -> dict[str, Any]:
    """One case, all its randomness from ``master`` (so the list depends on the master seed alone)."""
    seed = int(master.integers(2**31))
    rng = np.random.default_rng(seed)
    if rng.random() < 0.6:
        pair: dict[str, Any] = {"pair": "nordland", "reference": "summer", "query": "winter"}
        frames = NORDLAND_FRAMES
    else:
        pair = {"pair": "synthetic", "world": int(rng.choice(SYNTHETIC_WORLDS)), "reference": "day",
                "query": str(rng.choice(LIGHTS))}
        frames = SYNTHETIC_FRAMES
    length = int(rng.integers(WINDOW[0], WINDOW[1] + 1))
    start = int(rng.integers(0, frames - length + 1))
    changes: dict[str, Any] = {}
    if rng.random() >= UNCHANGED_SHARE:
        while not changes:  # a changed case changes something
            if rng.random() < CHANCE["swap"]:
                changes["swap"] = True
            if rng.random() < CHANCE["reversed"]:
                changes["reversed"] = True
            if rng.random() < CHANCE["pace"]:
                if rng.random() < 0.5:
                    changes["pace"] = {"kind": "constant", "speed": round(float(np.exp(rng.uniform(*np.log(PACE)))), 3)}
                else:
                    low = float(rng.uniform(PACE[0], 1.0))
                    changes["pace"] = {"kind": "varying", "low": round(low, 3),
                                       "high": round(float(rng.uniform(max(low + 0.3, 1.0), PACE[1])), 3),
                                       "period": int(rng.integers(60, 301)),
                                       "phase": round(float(rng.uniform(0, 2 * np.pi)), 3)}
            if rng.random() < CHANCE["jump"]:
                by = float(rng.uniform(0.15, 0.4)) * (1 if rng.random() < 0.5 else -1)
                changes["jump"] = {"at": round(float(rng.uniform(0.3, 0.7)), 3), "by": round(by, 3)}
            if rng.random() < CHANCE["stop"]:
                changes["stops"] = [{"at": int(rng.integers(5, max(6, length - 5))), "frames": int(rng.integers(5, 41))}
                                    for _ in range(int(rng.integers(1, 4)))]
    if changes.get("swap"):
        pair["reference"], pair["query"] = pair["query"], pair["reference"]
    return {"case": f"c{number:03d}", "seed": seed, **pair, "start": start, "length": length, "changes": changes}


def families(case: dict[str, Any]) -> list[str]:
    """The families a case belongs to: what it changes (``stop`` for stops), or ``unchanged``."""
    changes = case["changes"]
    found = [f for f in FAMILIES if changes.get("stops" if f == "stop" else f)]
    return found or ["unchanged"]


def draw(master_seed: int, n: int) -> dict[str, Any]:
    """The benchmark's case list: ``n`` cases from ``master_seed``, and an empty ``shaped`` list."""
    master = np.random.default_rng(master_seed)
    return {"master_seed": master_seed, "n": n, "cases": [draw_case(master, k) for k in range(n)], "shaped": []}


def read_seeds(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())


def lay_out(case: dict[str, Any], folders: dict[str, Path], out: Path) -> dict[str, str]:
    """Write ``case`` under ``out`` as reference/ and query/ folders of links and pairs.csv; return the
    ``paired_folders`` source params. ``folders`` maps a traversal name (summer, winter, day, dusk,
    night) to its folder of images in route order (for a synthetic world: that world's)."""
    out.mkdir(parents=True, exist_ok=True)
    reference, query = out / "reference", out / "query"
    for side in (reference, query):
        side.mkdir(exist_ok=True)
        for old in side.iterdir():
            old.unlink()
    ref_images = images_in(folders[case["reference"]])
    query_images = images_in(folders[case["query"]])
    window = range(case["start"], case["start"] + case["length"])
    for k, p in enumerate(window):
        (reference / f"{k:05d}{ref_images[p].suffix}").symlink_to(ref_images[p].resolve())
    places = query_places(case)
    lines = ["query,reference"]
    for j, place in enumerate(places):
        image = query_images[case["start"] + int(place)]
        (query / f"{j:05d}{image.suffix}").symlink_to(image.resolve())
        lines.append(f"{j},{int(place)}")
    (out / "pairs.csv").write_text("\n".join(lines) + "\n")
    return {"reference_folder": str(reference), "query_folder": str(query), "pairs": str(out / "pairs.csv"),
            "tolerance": TOLERANCE}
