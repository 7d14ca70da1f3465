"""The ``rst_shelo`` descriptor: a global histogram of cell edge orientations (Rodrigues 2019 §3.1).

RST-SHELO (Saavedra 2015) describes where edges of each orientation are in the image:

1. The image is split into a fixed number of cells (``cells_x`` x ``cells_y``), so a
   cell's size follows the image size and the descriptor does not depend on scale.
2. Each cell gets one *dominant* orientation: the structure-tensor average of its
   Sobel gradients, ``theta = 1/2 atan2(sum 2 gx gy, sum gx^2 - gy^2)`` (orientations
   are modulo pi: a dark-to-bright and a bright-to-dark edge are the same edge).
3. Cells are grouped into non-overlapping blocks (``block_x`` x ``block_y`` cells);
   each block is a histogram of ``bins`` orientations. A cell votes with the mean
   gradient magnitude of its pixels, split linearly between the two nearest
   orientation bins and, with ``spatial_soft``, bilinearly between the four nearest
   blocks (the "soft" of S-HELO), so a small shift or rotation moves votes smoothly.
4. The block histograms are concatenated, L1-normalised, square-rooted (the "square
   root normalisation" of RST-SHELO, as in RootSIFT) and L1-normalised again.

Distances are L1 (Rodrigues 2019, Table 3.1), between 0 and 2; the place map's similarity is
``1 - D / 2``. Sketch tokens, the edge detector RST-SHELO uses for sketches, need a
trained forest; on photographs Rodrigues 2019 applies the descriptor to preprocessed images
directly, and so do we.

Preprocessing (Rodrigues 2019 §3.1.1, §4.2): grey, Gaussian blur 5x5, histogram equalisation.
A 5 x 5 kernel only means something relative to the image: ``gaussian_kernel: auto``
(the default) scales it with the image's short side, 5 at ``blur_reference_side`` = 480
pixels (frames hundreds of pixels high, as in Rodrigues 2019's datasets; the thesis does
not state their size), the nearest odd size, no blur below 3 (:func:`kernel_for`). On
Nordland's 64 x 32 frames that is no blur; the kernel used is in the run's metrics.

An image whose raw mean gradient magnitude is below ``min_edge_strength`` (a tunnel,
a lens cap, a black frame) has no edges to describe: its descriptor is all zeros, which
detectors read as "featureless" and answer with no match instead of a guess. Without
this check, equalisation would stretch sensor noise into strong random edges.

Defaults, chosen by retrieval on held-out data that no reported number uses (Nordland
frames 2900-3575, and the synthetic world at seeds 100-102, dusk and night; the table is
in docs/loop_closure.md): 32 x 16 cells (2 x 2 pixels on the 64 x 32 Nordland frames),
2 x 2 cells per block (16 x 8 blocks), 9 bins: 1152 values, votes weighted by gradient
magnitude and shared between blocks. Coarser grids and larger blocks lost the spatial
layout, 9 bins matched or beat 6 and 12, and the 5 x 5 blur was the worst preprocessing
at these sizes (hence ``auto``).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from slamfront import DataError, Descriptor, PluginConfig, StageInputs
from slamfront.core.kernels import compiled
from slamfront.lazy import lazy_module
from slamfront.messages import Features

cv2 = lazy_module("cv2")  # loads on first use: listing plugins does not import it

MAX_L1_DISTANCE = 2.0
"""The largest L1 distance between two descriptors (both are non-negative with unit L1 norm)."""


def preprocess(gray: np.ndarray, gaussian_kernel: int = 5, equalise: bool = True) -> np.ndarray:
    """Rodrigues 2019 §3.1.1: Gaussian blur (``gaussian_kernel`` x ``gaussian_kernel``, sigma from
    the size as OpenCV does; 0 or 1 = no blur) then histogram equalisation. (H, W) uint8 in and out."""
    out = gray
    if gaussian_kernel > 1:
        out = cv2.GaussianBlur(out, (gaussian_kernel, gaussian_kernel), 0)
    return cv2.equalizeHist(out) if equalise else out


def kernel_for(shape: tuple[int, ...], reference_side: int = 480, reference_kernel: int = 5) -> int:
    """The Gaussian kernel side for an image of ``shape`` (H, W): ``reference_kernel`` at a
    short side of ``reference_side`` pixels, scaled with the short side, rounded to the
    nearest odd size; 0 (no blur) when that is below 3."""
    scaled = reference_kernel * min(shape[:2]) / reference_side
    side = int(np.floor(scaled / 2)) * 2 + 1
    return side if side >= 3 else 0


def _sobel(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's 3 x 3 Sobel gradients (float32) of a grey image (the reference the compiled one reproduces)."""
    image = gray.astype(np.float32)
    return cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3)


def _gradients(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(gx, gy, magnitude)``, (H, W) float32: :func:`_sobel`'s bits and ``sqrt(gx^2 + gy^2)``,
    in one compiled pass for a uint8 image (a descriptor costs a few calls, not a dozen)."""
    if gray.dtype != np.uint8 or gray.ndim != 2:
        gx, gy = _sobel(gray)
        return gx, gy, np.sqrt(gx * gx + gy * gy)
    gx, gy, magnitude = (np.empty(gray.shape, dtype=np.float32) for _ in range(3))
    compiled().sobel_3x3(np.ascontiguousarray(gray), gx, gy, magnitude)
    return gx, gy, magnitude


def edge_strength(gray: np.ndarray) -> float:
    """Mean Sobel gradient magnitude of a (H, W) uint8 image, in grey levels per pixel."""
    return _mean(_gradients(gray)[2])


def _mean(values: np.ndarray) -> float:
    """``float(values.mean())`` for a float32 array, the same bits without ``np.mean``'s
    Python steps: NumPy's sum (float32), divided by the count as an intp (in float64, as
    ``np.mean`` divides) and rounded back to float32."""
    return float(np.float32(np.add.reduce(values, axis=None) / np.intp(values.size)))


def cell_orientations(
    gray: np.ndarray, cells_x: int, cells_y: int
) -> tuple[np.ndarray, np.ndarray]:
    """Dominant orientation and vote of every cell.

    :returns: ``(theta, weight)``, both (cells_y, cells_x) float64: the orientation in
        [0, pi) and the cell's mean gradient magnitude.
    """
    height, width = gray.shape
    if width < cells_x or height < cells_y:
        raise ValueError(f"a {width}x{height} image cannot be split into {cells_x}x{cells_y} cells")
    xs, ys, area = _cell_edges(height, width, cells_y, cells_x)
    along, across, magnitude = (np.empty((cells_y, cells_x)) for _ in range(3))
    if gray.dtype == np.uint8:  # the gradients and the cell sums in one compiled call
        scratch = np.empty((3, height, width), dtype=np.float32)
        compiled().rst_shelo_cells(np.ascontiguousarray(gray), xs, ys, scratch[0], scratch[1], scratch[2],
                                   along, across, magnitude)
    else:
        gx, gy, _ = _gradients(gray)
        compiled().cell_sums(gx, gy, xs, ys, along, across, magnitude)
    theta = np.mod(0.5 * np.arctan2(along, across), np.pi)
    return theta, magnitude / area


def cell_orientations_reference(
    gray: np.ndarray, cells_x: int, cells_y: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cell_orientations` in plain NumPy (what the compiled cell sums reproduce; tests compare the two)."""
    height, width = gray.shape
    gx, gy = _sobel(gray)
    xs, ys, area = _cell_edges(height, width, cells_y, cells_x)

    def per_cell(values: np.ndarray) -> np.ndarray:
        return np.add.reduceat(np.add.reduceat(values.astype(np.float64), ys[:-1], axis=0), xs[:-1], axis=1)

    along = per_cell(2.0 * gx * gy)
    across = per_cell(gx * gx - gy * gy)
    magnitude = per_cell(np.sqrt(gx * gx + gy * gy))
    theta = np.mod(0.5 * np.arctan2(along, across), np.pi)
    return theta, magnitude / area


@functools.lru_cache(maxsize=16)
def _cell_edges(height: int, width: int, cells_y: int, cells_x: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel edges of the cells across (``cells_x + 1``) and down (``cells_y + 1``), and each cell's area."""
    xs = np.linspace(0, width, cells_x + 1).round().astype(np.int64)
    ys = np.linspace(0, height, cells_y + 1).round().astype(np.int64)
    area = np.outer(np.diff(ys), np.diff(xs))
    for array in (xs, ys, area):
        array.flags.writeable = False
    return xs, ys, area


@functools.lru_cache(maxsize=16)
def _block_geometry(
    cells_y: int, cells_x: int, block_y: int, block_x: int, bins: int, spatial_soft: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What :func:`block_histograms` needs that depends on the grid only, not on the image:
    for the 8 (row, column, bin) corners of every cell's vote, in the order the votes are
    added, the flat histogram index of its block, its row and column weights and the
    bin step (0 or 1). Shapes (8, cells_y, cells_x); read-only."""
    blocks_x = cells_x // block_x
    if spatial_soft:  # cell centre in block units, block centres at integers
        row = (np.arange(cells_y) + 0.5) / block_y - 0.5
        col = (np.arange(cells_x) + 0.5) / block_x - 0.5
    else:  # each cell in its own block, no sharing
        row = np.arange(cells_y) // block_y + 0.0
        col = np.arange(cells_x) // block_x + 0.0
    row_grid, col_grid = np.meshgrid(row, col, indexing="ij")
    row0, col0 = np.floor(row_grid).astype(int), np.floor(col_grid).astype(int)
    row_frac, col_frac = row_grid - row0, col_grid - col0
    blocks, row_weights, col_weights, bin_steps = [], [], [], []
    for dr, wr in ((0, 1 - row_frac), (1, row_frac)):
        for dc, wc in ((0, 1 - col_frac), (1, col_frac)):
            for db in (0, 1):
                blocks.append(((row0 + dr + 1) * (blocks_x + 2) + col0 + dc + 1) * bins)
                row_weights.append(wr)
                col_weights.append(wc)
                bin_steps.append(np.full(row0.shape, db))
    arrays = tuple(np.stack(a) for a in (blocks, row_weights, col_weights, bin_steps))
    for array in arrays:
        array.flags.writeable = False
    return arrays  # type: ignore[return-value]


def block_histograms(
    theta: np.ndarray, weight: np.ndarray, block_x: int, block_y: int, bins: int, spatial_soft: bool
) -> np.ndarray:
    """(blocks_y, blocks_x, bins) orientation histograms of the cells (see module docstring).

    Each cell's vote is split over 2 rows x 2 columns of blocks x 2 bins; the eight
    shares of every cell go into one ``np.bincount`` in the order (row, column, bin
    corner, then cell) in which they are added, so the sums are the same bits as
    adding them one corner at a time.
    """
    cells_y, cells_x = theta.shape
    blocks_y, blocks_x = cells_y // block_y, cells_x // block_x
    blocks, row_weights, col_weights, bin_steps = _block_geometry(cells_y, cells_x, block_y, block_x, bins, spatial_soft)
    size = (blocks_y + 2) * (blocks_x + 2) * bins
    padded = np.empty(size)
    compiled().soft_votes(np.ascontiguousarray(theta, dtype=np.float64), np.ascontiguousarray(weight, dtype=np.float64),
                          blocks, row_weights, col_weights, bin_steps, bins, padded)
    return padded.reshape(blocks_y + 2, blocks_x + 2, bins)[1:-1, 1:-1]


def block_histograms_reference(
    theta: np.ndarray, weight: np.ndarray, block_x: int, block_y: int, bins: int, spatial_soft: bool
) -> np.ndarray:
    """:func:`block_histograms` in plain NumPy (what the compiled votes reproduce; tests compare the two)."""
    cells_y, cells_x = theta.shape
    blocks_y, blocks_x = cells_y // block_y, cells_x // block_x
    blocks, row_weights, col_weights, bin_steps = _block_geometry(cells_y, cells_x, block_y, block_x, bins, spatial_soft)
    position = theta / np.pi * bins - 0.5  # bin centres at (b + 0.5) * pi / bins
    low_bin = np.floor(position).astype(int)
    bin_frac = position - low_bin
    bin_weights = np.where(bin_steps == 1, bin_frac, 1 - bin_frac)
    targets = blocks + (low_bin + bin_steps) % bins
    votes = weight * row_weights * col_weights * bin_weights
    size = (blocks_y + 2) * (blocks_x + 2) * bins
    padded = np.bincount(targets.ravel(), votes.ravel(), size).reshape(blocks_y + 2, blocks_x + 2, bins)
    return padded[1:-1, 1:-1]


def square_root_normalise(histogram: np.ndarray) -> np.ndarray:
    """L1-normalise, square-root, L1-normalise again; all zeros stay all zeros. float32 out."""
    flat = np.asarray(histogram, dtype=np.float64).ravel()
    total = flat.sum()
    if total <= 0:
        return np.zeros(flat.shape, dtype=np.float32)
    rooted = np.sqrt(flat / total)
    return (rooted / rooted.sum()).astype(np.float32)


_WORKSPACES = 8
"""Image sizes whose scratch arrays a descriptor keeps (a source rarely mixes more)."""


class _Workspace:
    """The compiled steps of one image size with their scratch arrays, allocated once: a
    64 x 32 descriptor costs a few compiled calls, and a dozen NumPy allocations around them
    cost as much again. The same bits as the NumPy steps (tests/test_rst_shelo.py). Its
    arrays are reused by every call, so one descriptor instance describes one image at a time
    (as a pipeline's stage does)."""

    def __init__(self, shape: tuple[int, int], cells_x: int, cells_y: int, block_x: int, block_y: int, bins: int,
                 spatial_soft: bool) -> None:
        height, width = shape
        self.too_small = (f"a {width}x{height} image cannot be split into {cells_x}x{cells_y} cells"
                          if width < cells_x or height < cells_y else "")
        self.size = np.intp(height * width)
        self.pixels = np.empty((3, height, width), dtype=np.float32)  # gx, gy, magnitude
        self.frames, self.partial = np.empty((3, 64), dtype=np.int64), np.empty(64, dtype=np.float32)
        self.xs, self.ys, self.area = _cell_edges(height, width, cells_y, cells_x)
        self.cells = np.empty((3, cells_y, cells_x))  # along, across, magnitude
        self.blocks_y, self.blocks_x = cells_y // block_y, cells_x // block_x
        self.geometry = _block_geometry(cells_y, cells_x, block_y, block_x, bins, spatial_soft)
        self.padded = np.empty((self.blocks_y + 2) * (self.blocks_x + 2) * bins)
        self.flat = np.empty(self.blocks_y * self.blocks_x * bins)
        self.partial64 = np.empty(64)

    def edge_strength(self, gray: np.ndarray) -> float:
        """:func:`edge_strength` of a uint8 image of this size (the same bits)."""
        gx, gy, magnitude = self.pixels
        total = compiled().sobel_magnitude_sum(np.ascontiguousarray(gray), gx, gy, magnitude, self.frames, self.partial)
        return float(np.float32(total / self.size))

    def descriptor(self, image: np.ndarray, bins: int) -> np.ndarray:
        """The descriptor of a preprocessed uint8 image: :func:`cell_orientations`, then
        :func:`block_histograms` and :func:`square_root_normalise` in one compiled call."""
        if self.too_small:
            raise ValueError(self.too_small)
        along, across, magnitude = self.cells
        compiled().rst_shelo_cells(np.ascontiguousarray(image), self.xs, self.ys, *self.pixels, along, across, magnitude)
        theta = np.mod(0.5 * np.arctan2(along, across), np.pi)
        vector = np.empty(len(self.flat), dtype=np.float32)
        compiled().rst_shelo_histogram(theta, magnitude / self.area, *self.geometry, bins, self.blocks_y, self.blocks_x,
                                       self.padded, self.flat, self.frames, self.partial64, vector)
        return vector


class RstShelo(Descriptor):
    """RST-SHELO edge-orientation descriptor with Rodrigues 2019's Gaussian + equalisation preprocessing.

    A fixed grid of cells, one dominant orientation per cell, soft block histograms,
    square-root normalisation; compared with L1 (0..2). Featureless images (raw mean
    gradient below ``min_edge_strength``) get an all-zero vector, which detectors treat
    as "no answer". See the module docstring for the steps and the defaults' rationale.
    """

    name = "rst_shelo"
    produces_global = True

    class Config(PluginConfig):
        preprocess: bool = Field(True, description="Gaussian blur + histogram equalisation first (Rodrigues 2019 §3.1.1)")
        gaussian_kernel: int | Literal["auto"] = Field(
            "auto", description="side of the Gaussian kernel (odd; 0 or 1: no blur); auto: 5 at a short image side "
            "of blur_reference_side pixels, scaled with the image"
        )
        blur_reference_side: int = Field(
            480, ge=1, description="gaussian_kernel auto: the short image side at which the kernel is 5 x 5"
        )
        equalise: bool = Field(True, description="histogram equalisation after the blur (when preprocess is on)")
        cells_x: int = Field(32, ge=1, description="cells across the image (fixed count: cell size follows image size)")
        cells_y: int = Field(16, ge=1, description="cells down the image")
        block_x: int = Field(2, ge=1, description="cells per block across; must divide cells_x")
        block_y: int = Field(2, ge=1, description="cells per block down; must divide cells_y")
        bins: int = Field(9, ge=2, description="orientation bins over [0, pi)")
        spatial_soft: bool = Field(True, description="share each cell's vote bilinearly with neighbouring blocks")
        min_edge_strength: float = Field(
            5.0, ge=0, description="raw mean Sobel magnitude (grey levels) below which an image is featureless"
        )

        @model_validator(mode="after")
        def _blocks_tile_cells(self) -> RstShelo.Config:
            if self.cells_x % self.block_x or self.cells_y % self.block_y:
                raise ValueError("block_x must divide cells_x and block_y must divide cells_y")
            if self.gaussian_kernel != "auto" and self.gaussian_kernel > 1 and self.gaussian_kernel % 2 == 0:
                raise ValueError("gaussian_kernel must be odd")
            if self.gaussian_kernel != "auto" and self.gaussian_kernel < 0:
                raise ValueError("gaussian_kernel must be 'auto' or >= 0")
            return self

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self._kernels: set[int] = set()  # Gaussian kernel sides used (one per image size)
        self._workspaces: dict[tuple[int, int], _Workspace] = {}  # scratch arrays per image size

    @property
    def length(self) -> int:
        """Descriptor length: blocks x bins."""
        c = self.config
        return (c.cells_x // c.block_x) * (c.cells_y // c.block_y) * c.bins

    def describe(self, gray: np.ndarray) -> np.ndarray:
        """(length,) float32 descriptor of a (H, W) uint8 grey image (zeros if featureless)."""
        c = self.config
        if gray.dtype != np.uint8 or gray.ndim != 2:  # the NumPy steps (the compiled ones take uint8)
            return self._describe_any(gray)
        work = self._workspace(gray.shape)
        if work.edge_strength(gray) < c.min_edge_strength:
            return np.zeros(self.length, dtype=np.float32)
        kernel = kernel_for(gray.shape, c.blur_reference_side) if c.gaussian_kernel == "auto" else c.gaussian_kernel
        self._kernels.add(kernel if c.preprocess else 0)
        image = preprocess(gray, kernel, c.equalise) if c.preprocess else gray
        return work.descriptor(image, c.bins)

    def _describe_any(self, gray: np.ndarray) -> np.ndarray:
        """:meth:`describe` of an image that is not (H, W) uint8, through the NumPy steps."""
        c = self.config
        if edge_strength(gray) < c.min_edge_strength:
            return np.zeros(self.length, dtype=np.float32)
        kernel = kernel_for(gray.shape, c.blur_reference_side) if c.gaussian_kernel == "auto" else c.gaussian_kernel
        self._kernels.add(kernel if c.preprocess else 0)
        image = preprocess(gray, kernel, c.equalise) if c.preprocess else gray
        theta, weight = cell_orientations(image, c.cells_x, c.cells_y)
        histogram = block_histograms(theta, weight, c.block_x, c.block_y, c.bins, c.spatial_soft)
        return square_root_normalise(histogram)

    def _workspace(self, shape: tuple[int, int]) -> _Workspace:
        work = self._workspaces.get(shape)
        if work is None:
            if len(self._workspaces) >= _WORKSPACES:  # images of ever new sizes: keep the most recent few
                del self._workspaces[next(iter(self._workspaces))]
            c = self.config
            work = self._workspaces[shape] = _Workspace(shape, c.cells_x, c.cells_y, c.block_x, c.block_y, c.bins,
                                                        c.spatial_soft)
        return work

    def process(self, inputs: StageInputs) -> Sequence[Features]:
        frame = inputs.frame
        try:
            vector = self.describe(frame.gray())
        except ValueError as exc:
            raise DataError(f"frame {frame.index} ({frame.name or 'unnamed'}): {exc}") from exc
        return [Features(frame=frame.index, vector=vector, metric="l1")]

    def statistics(self) -> dict[str, float | int]:
        """The Gaussian kernel used (the largest, if images of several sizes came)."""
        return {"gaussian_kernel": max(self._kernels)} if self._kernels else {}
