"""A long route built from the Nordland route: tiles of it, each seen as another place.

Nordland gives 3,576 frame-aligned places in summer and in winter. A route of n frames
repeats them in tiles (tile t holds places ``t * 3576 .. t * 3576 + 3575``), and every
tile is made a different stretch of railway that looks like the others:

- a geometric change of its own: the image panned cyclically by a multiple of 4 pixels
  (of 64) and possibly mirrored, a (pan, mirror) pair no other tile has (32 of them, for
  up to 32 tiles = 114k frames), plus a small seeded shift (+-1 x +-0.5 pixels), scale
  (0.97-1.03) and roll (+-1 degree);
- a photometric change of its own: gain 0.75-1.25, gamma 0.75-1.33, offset +-15 grey levels.

Both seasons of a tile get the same change, so a query of tile t is correct only in
tile t (within the tolerance); the other tiles are look-alikes (the same railway,
weather and seasons) that grow with the map. Without the distinct pan and mirror the
tiles would be copies of one route: histogram equalisation and patch normalisation undo
the photometric change, and small shifts are what these descriptors are built to ignore.

Frames are made on the fly from the 2 x 3,576 source images held in memory (7 MB);
nothing derived is written to disk. The same seed always gives the same route.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

TILE = 3576
"""Frames per tile: the Nordland route, once."""


@dataclass(frozen=True)
class TileChange:
    """One tile's photometric and geometric change."""

    pan: int
    """cyclic pan, pixels"""
    mirror: bool
    gain: float
    gamma: float
    offset: float
    shift_x: float
    """pixels (of 64)"""
    shift_y: float
    """pixels (of 32)"""
    scale: float
    roll_degrees: float


PANS = 16
"""Distinct cyclic pans (multiples of 4 pixels of 64); with mirroring, 32 distinct tiles."""


def tile_change(tile: int, seed: int) -> TileChange:
    """Tile ``tile``'s change, drawn from ``seed`` and the tile number alone (the pan and
    mirror from one seeded order of the 32 pairs, so no two tiles share them)."""
    if not 0 <= tile < 2 * PANS:
        raise ValueError(f"tile {tile}: a route has at most {2 * PANS} distinct tiles")
    pair = int(np.random.default_rng([seed, 10**6]).permutation(2 * PANS)[tile])
    rng = np.random.default_rng([seed, tile])
    return TileChange(
        pan=4 * (pair % PANS), mirror=bool(pair // PANS),
        gain=float(rng.uniform(0.75, 1.25)), gamma=float(np.exp(rng.uniform(np.log(0.75), np.log(1.33)))),
        offset=float(rng.uniform(-15, 15)), shift_x=float(rng.uniform(-1, 1)), shift_y=float(rng.uniform(-0.5, 0.5)),
        scale=float(rng.uniform(0.97, 1.03)), roll_degrees=float(rng.uniform(-1, 1)),
    )


class TiledRoute:
    """Reference (summer) and query (winter) frames of a tiled route, made on demand."""

    def __init__(self, nordland: Path, seed: int = 0) -> None:
        names = sorted(p.name for p in (nordland / "summer").glob("*.png"))
        if len(names) != TILE:
            raise RuntimeError(f"{nordland}: expected {TILE} summer frames, found {len(names)}")
        self.seasons = {
            traversal: np.stack([cv2.imread(str(nordland / season / name), cv2.IMREAD_GRAYSCALE) for name in names])
            for traversal, season in (("reference", "summer"), ("query", "winter"))
        }
        self.seed = seed
        self._changes: dict[int, tuple[TileChange, np.ndarray, np.ndarray]] = {}

    def _change(self, tile: int) -> tuple[TileChange, np.ndarray, np.ndarray]:
        """(change, lookup table (256,) uint8, affine (2, 3)) of a tile."""
        if tile not in self._changes:
            c = tile_change(tile, self.seed)
            levels = np.arange(256) / 255.0
            table = np.clip(255 * c.gain * levels**c.gamma + c.offset, 0, 255).round().astype(np.uint8)
            height, width = self.seasons["reference"].shape[1:]
            affine = cv2.getRotationMatrix2D((width / 2, height / 2), c.roll_degrees, c.scale)
            affine[:, 2] += (c.shift_x, c.shift_y)
            self._changes[tile] = (c, table, affine)
        return self._changes[tile]

    def image(self, traversal: str, index: int) -> np.ndarray:
        """(32, 64) uint8 grey frame ``index`` of the route (place ``index``, tile ``index // TILE``)."""
        tile, place = divmod(index, TILE)
        change, table, affine = self._change(tile)
        source = np.roll(self.seasons[traversal][place], change.pan, axis=1)
        if change.mirror:
            source = np.ascontiguousarray(source[:, ::-1])
        height, width = source.shape
        moved = cv2.warpAffine(source, affine, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        return cv2.LUT(moved, table)
