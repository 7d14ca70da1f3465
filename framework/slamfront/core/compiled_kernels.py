"""The numba kernels behind :mod:`slamfront.core.kernels` (see there for what each
reproduces); module-level functions, so numba caches their machine code on disk."""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from slamfront.core.kernels import PAIRWISE_BLOCK

jit = numba.njit(nogil=True, cache=True, error_model="numpy")


@jit
def block_sum(values, start, n):  # type: ignore[no-untyped-def]
    # NumPy's pairwise summation of n <= 128 values (numpy/_core/src/umath/loops_utils.h.src)
    if n < 8:
        res = values.dtype.type(-0.0)
        for i in range(start, start + n):
            res += values[i]
        return res
    r0, r1, r2, r3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    r4, r5, r6, r7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    i = 8
    while i < n - (n % 8):
        j = start + i
        r0 += values[j]
        r1 += values[j + 1]
        r2 += values[j + 2]
        r3 += values[j + 3]
        r4 += values[j + 4]
        r5 += values[j + 5]
        r6 += values[j + 6]
        r7 += values[j + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += values[start + i]
        i += 1
    return res


@jit
def pairwise_sum(values, start, n, frames, partial):  # type: ignore[no-untyped-def]
    # NumPy's pairwise summation of any n: blocks of <= 128 combined as
    # sum(a, n) = sum(a, h) + sum(a + h, n - h), h = n / 2 rounded down to a multiple of 8.
    # The recursion runs on an explicit stack (numba cannot cache recursive functions):
    # frames (3, depth) int64 holds (start, length, stage) per level, partial the left sums.
    if n <= PAIRWISE_BLOCK:
        return block_sum(values, start, n)
    top = 0
    frames[0, 0], frames[1, 0], frames[2, 0] = start, n, 0
    result = values.dtype.type(0.0)
    while top >= 0:
        s, m = frames[0, top], frames[1, top]
        if m <= PAIRWISE_BLOCK:
            result = block_sum(values, s, m)
            top -= 1
            continue
        h = m // 2
        h -= h % 8
        stage = frames[2, top]
        if stage == 0:  # descend into the left half
            frames[2, top] = 1
            top += 1
            frames[0, top], frames[1, top], frames[2, top] = s, h, 0
        elif stage == 1:  # left done: keep it, descend into the right half
            partial[top] = result
            frames[2, top] = 2
            top += 1
            frames[0, top], frames[1, top], frames[2, top] = s + h, m - h, 0
        else:  # both halves done
            result = partial[top] + result
            top -= 1
    return result


@jit
def l1_uint8(a, b, out, lo, hi):  # type: ignore[no-untyped-def]
    # out[i, j] = sum |a[i] - b[j]| for rows lo..hi of a; exact in int32
    p = a.shape[1]
    for i in range(lo, hi):
        ai = a[i]
        for j in range(b.shape[0]):
            bj = b[j]
            acc = np.int32(0)
            for k in range(p):
                x = np.int32(ai[k])
                y = np.int32(bj[k])
                acc += x - y if x > y else y - x
            out[i, j] = acc

@jit
def l1_pair(x, y, buffer, frames, partial):  # type: ignore[no-untyped-def]
    # float32 sum |x - y| in NumPy's pairwise order, bit for bit; buffer (p,) float32,
    # frames (3, 64) int64 and partial (64,) float32 are the caller's scratch
    p = x.shape[0]
    for k in range(p):
        buffer[k] = abs(x[k] - y[k])
    return np.float32(0.0) + pairwise_sum(buffer, 0, p, frames, partial)


@jit
def l1_float32(a, b, out, lo, hi):  # type: ignore[no-untyped-def]
    # float32 |a - b| summed in NumPy's pairwise order, bit for bit
    buffer = np.empty(a.shape[1], dtype=np.float32)
    frames = np.empty((3, 64), dtype=np.int64)
    partial = np.empty(64, dtype=np.float32)
    for i in range(lo, hi):
        for j in range(b.shape[0]):
            out[i, j] = l1_pair(a[i], b[j], buffer, frames, partial)

@jit
def sweep(columns, offsets, queries, out, lo, hi):  # type: ignore[no-untyped-def]
    # columns: (C, R + reach + 1) float64 (rows past R are inf); query n = queries[i]
    # uses columns n .. n + W - 1; out[n, r] = min over trajectories of the sum
    # of their W entries added one after the other
    n_ref = out.shape[1]
    n_traj, width = offsets.shape
    cost = np.empty(n_ref, dtype=np.float64)
    for i in range(lo, hi):
        n = queries[i]
        best = out[n]
        best[:] = np.inf
        for v in range(n_traj):
            cost[:] = 0.0
            for k in range(width):
                # a slice, not ``cost[r] += column[r + shift]``: with a signed index numba's loop
                # was not vectorised (~3x slower); same additions, same order
                shift = offsets[v, k]
                cost += columns[n + k, shift : shift + n_ref]
            for r in range(n_ref):
                if cost[r] < best[r]:
                    best[r] = cost[r]

@jit
def gather(columns, offsets, queries, rows, starts, out, lo, hi):  # type: ignore[no-untyped-def]
    # as sweep for query queries[i]'s start rows rows[starts[i]:starts[i + 1]] only
    # (others inf), each trajectory pairwise-summed as NumPy's ``picked.sum(axis=2)``
    n_traj, width = offsets.shape
    picked = np.empty(width, dtype=np.float64)
    frames = np.empty((3, 64), dtype=np.int64)
    partial = np.empty(64, dtype=np.float64)
    for i in range(lo, hi):
        n = queries[i]
        out[n, :] = np.inf
        for index in range(starts[i], starts[i + 1]):
            row = rows[index]
            best = np.inf
            for v in range(n_traj):
                for k in range(width):
                    picked[k] = columns[n + k, row + offsets[v, k]]
                best = min(best, 0.0 + pairwise_sum(picked, 0, width, frames, partial))
            out[n, row] = best


@jit
def quantise(order, nd0, nnd0, word0, among, greedy, nndr, nd_low, nd_high, first_new, words, distances, decided_by):  # type: ignore[no-untyped-def]
    # Wang et al. 2017's update loop (slamfront.core.vocabulary), feature by feature in
    # ``order``: the nearest of the old words (nd0, nnd0, word0) or of the words this
    # image made so far (kept as running nearest / second nearest per feature from the
    # feature-to-feature distances ``among``), then the decision; new words get ids
    # first_new, first_new + 1, ... Writes words / distances / decided_by per feature and
    # returns the indices of the features that became words, in creation order.
    n = len(order)
    new_d1 = np.full(n, np.inf)
    new_d2 = np.full(n, np.inf)
    new_w1 = np.full(n, -1, dtype=np.int64)
    created = np.empty(n, dtype=np.int64)
    n_created = 0
    for position in range(n):
        k = order[position]
        if new_d1[k] < nd0[k]:
            nd = new_d1[k]
            nearest_word = new_w1[k]
            nnd = min(nd0[k], new_d2[k])
        else:
            nd = nd0[k]
            nearest_word = word0[k]
            nnd = min(nnd0[k], new_d1[k])
        # vocabulary.decide: BY_ND_HIGH 1, BY_ND_LOW -1, BY_RATIO 0
        if greedy and nd > nd_high:
            new, by = True, 1
        elif greedy and nd < nd_low:
            new, by = False, -1
        else:
            if np.isinf(nnd):
                ratio = 1.0
            elif nnd > 0:
                ratio = nd / nnd
            else:
                ratio = 0.0
            new, by = ratio > nndr, 0
        decided_by[k] = by
        if new:
            word = first_new + n_created
            created[n_created] = k
            n_created += 1
            words[k] = word
            distances[k] = 0.0
            for i in range(n):
                d = among[i, k]
                if d < new_d1[i]:
                    new_d2[i] = new_d1[i]
                    new_w1[i] = word
                    new_d1[i] = d
                else:
                    new_d2[i] = min(new_d2[i], d)
        else:
            words[k] = nearest_word
            distances[k] = nd
    return created[:n_created]


@intrinsic
def popcount64(typingctx, x):  # type: ignore[no-untyped-def]
    # set bits of a uint64: LLVM's ctpop, one instruction where the CPU has one
    signature = types.uint64(types.uint64)

    def codegen(context, builder, sig, args):  # type: ignore[no-untyped-def]
        return builder.call(builder.module.declare_intrinsic("llvm.ctpop", [ir.IntType(64)]), args)

    return signature, codegen


@jit
def _keep_two(d, j, b1, b2, r1):  # type: ignore[no-untyped-def]
    # the two smallest distances so far and the row of the smallest, with row j's d;
    # strict comparisons in row order, so ties go to the lower row
    if d < b2:
        if d < b1:
            return d, b1, j
        return b1, d, r1
    return b1, b2, r1


@jit
def two_nearest_hamming(queries, rows, d1, d2, i1):  # type: ignore[no-untyped-def]
    # per query (packed bits as uint64 words), the smallest and second-smallest Hamming
    # distance to the rows and the row of the smallest (ties to the lower row, as
    # cv2.batchDistance with K = 2)
    n_words = queries.shape[1]
    for i in range(queries.shape[0]):
        query = queries[i]
        b1 = np.int64(1) << 62
        b2 = np.int64(1) << 62
        r1 = -1
        if n_words == 4:  # 256-bit descriptors (ORB, BRIEF), unrolled: ~1.5x the loop below
            q0, q1, q2, q3 = query[0], query[1], query[2], query[3]
            for j in range(rows.shape[0]):
                d = (np.int64(popcount64(q0 ^ rows[j, 0])) + np.int64(popcount64(q1 ^ rows[j, 1]))
                     + np.int64(popcount64(q2 ^ rows[j, 2])) + np.int64(popcount64(q3 ^ rows[j, 3])))
                b1, b2, r1 = _keep_two(d, j, b1, b2, r1)
        else:
            for j in range(rows.shape[0]):
                row = rows[j]
                d = np.int64(0)
                for k in range(n_words):
                    d += np.int64(popcount64(query[k] ^ row[k]))
                b1, b2, r1 = _keep_two(d, j, b1, b2, r1)
        d1[i] = b1
        d2[i] = b2
        i1[i] = r1


@numba.njit(nogil=True, cache=True, error_model="numpy", fastmath=True)
def l1_float32_bound(a, b, out, lo, hi):  # type: ignore[no-untyped-def]
    # out[i, j] ~ sum |a[i] - b[j]| for rows lo..hi of a, summed in whatever order the
    # compiler vectorises (fastmath): within (p - 1) * 2**-24 * sum of the exact value,
    # for ranking only (k_nearest re-ranks the few near the cut with l1_float32's bits).
    # b is walked in tiles of rows that stay in cache for every row of a; four rows of a
    # at a time share each load of b and keep four sums in flight (one sum alone waits
    # on its own additions)
    p = a.shape[1]
    tile = 64
    for start in range(0, b.shape[0], tile):
        stop = min(start + tile, b.shape[0])
        i = lo
        while i + 4 <= hi:
            a0, a1, a2, a3 = a[i], a[i + 1], a[i + 2], a[i + 3]
            for j in range(start, stop):
                bj = b[j]
                s0 = np.float32(0.0)
                s1 = np.float32(0.0)
                s2 = np.float32(0.0)
                s3 = np.float32(0.0)
                for k in range(p):
                    v = bj[k]
                    s0 += abs(a0[k] - v)
                    s1 += abs(a1[k] - v)
                    s2 += abs(a2[k] - v)
                    s3 += abs(a3[k] - v)
                out[i, j] = s0
                out[i + 1, j] = s1
                out[i + 2, j] = s2
                out[i + 3, j] = s3
            i += 4
        while i < hi:
            ai = a[i]
            for j in range(start, stop):
                bj = b[j]
                s = np.float32(0.0)
                for k in range(p):
                    s += abs(ai[k] - bj[k])
                out[i, j] = s
            i += 1


@jit
def l1_float32_pairs(a, b, rows, columns, out):  # type: ignore[no-untyped-def]
    # out[n] = the l1_float32 distance (NumPy's pairwise bits) of a[rows[n]] and b[columns[n]]
    buffer = np.empty(a.shape[1], dtype=np.float32)
    frames = np.empty((3, 64), dtype=np.int64)
    partial = np.empty(64, dtype=np.float32)
    for n in range(rows.shape[0]):
        out[n] = l1_pair(a[rows[n]], b[columns[n]], buffer, frames, partial)


@jit
def greedy_places_l1(vectors, threshold, max_distance, new_place):  # type: ignore[no-untyped-def]
    # new_place[t] = whether frame t starts a place: 1 - D(R, g_t) / max_distance < threshold,
    # R the first vector of the current place, D float32 L1 in NumPy's pairwise bits (as
    # l1_float32), compared in float64 as Python compares the float32 distance
    buffer = np.empty(vectors.shape[1], dtype=np.float32)
    frames = np.empty((3, 64), dtype=np.int64)
    partial = np.empty(64, dtype=np.float32)
    representative = 0
    for t in range(vectors.shape[0]):
        if t == 0:
            new_place[t] = True
            continue
        distance = np.float64(l1_pair(vectors[t], vectors[representative], buffer, frames, partial))
        joins = 1.0 - distance / max_distance >= threshold
        new_place[t] = not joins
        if not joins:
            representative = t


@jit
def cell_sums(gx, gy, xs, ys, along, across, magnitude):  # type: ignore[no-untyped-def]
    # RST-SHelo's per-cell sums of 2 gx gy, gx^2 - gy^2 and sqrt(gx^2 + gy^2): each term in
    # float32 (as NumPy computes them from float32 gradients), then widened to float64 and
    # added down each column of the cell, then across the cell's columns, one after the
    # other, as two np.add.reduceat calls (rows, then columns) add them
    cells_y = ys.shape[0] - 1
    cells_x = xs.shape[0] - 1
    for cy in range(cells_y):
        for cx in range(cells_x):
            cell_along = 0.0
            cell_across = 0.0
            cell_magnitude = 0.0
            for c in range(xs[cx], xs[cx + 1]):
                column_along = 0.0
                column_across = 0.0
                column_magnitude = 0.0
                for r in range(ys[cy], ys[cy + 1]):
                    x = gx[r, c]
                    y = gy[r, c]
                    a = np.float64(np.float32(np.float32(2.0) * x) * y)
                    b = np.float64(np.float32(x * x) - np.float32(y * y))
                    m = np.float64(np.sqrt(np.float32(x * x) + np.float32(y * y)))
                    if r == ys[cy]:
                        column_along, column_across, column_magnitude = a, b, m
                    else:
                        column_along += a
                        column_across += b
                        column_magnitude += m
                if c == xs[cx]:
                    cell_along, cell_across, cell_magnitude = column_along, column_across, column_magnitude
                else:
                    cell_along += column_along
                    cell_across += column_across
                    cell_magnitude += column_magnitude
            along[cy, cx] = cell_along
            across[cy, cx] = cell_across
            magnitude[cy, cx] = cell_magnitude


@jit
def sobel_3x3(image, gx, gy, magnitude):  # type: ignore[no-untyped-def]
    # cv2.Sobel(image as float32, CV_32F, 1, 0) and (0, 1), ksize 3, OpenCV's default
    # border (BORDER_REFLECT_101: ..., 2, 1 | 0, 1, 2, ... | n-2, n-3, ...), of a (H, W)
    # uint8 image, and np.sqrt(gx * gx + gy * gy) in float32. The same bits in any order of
    # the additions: a gradient is an integer of at most 4 * 255, its square and the sum of
    # two squares integers below 2 ** 24, all held exactly by float32
    height, width = image.shape
    for r in range(height):
        up = r - 1 if r > 0 else (1 if height > 1 else 0)
        down = r + 1 if r < height - 1 else (height - 2 if height > 1 else 0)
        for c in range(width):
            left = c - 1 if c > 0 else (1 if width > 1 else 0)
            right = c + 1 if c < width - 1 else (width - 2 if width > 1 else 0)
            a, b, d = np.int32(image[up, left]), np.int32(image[up, c]), np.int32(image[up, right])
            e, f = np.int32(image[r, left]), np.int32(image[r, right])
            g, h, i = np.int32(image[down, left]), np.int32(image[down, c]), np.int32(image[down, right])
            fx = np.float32((d - a) + 2 * (f - e) + (i - g))
            fy = np.float32((g - a) + 2 * (h - b) + (i - d))
            gx[r, c] = fx
            gy[r, c] = fy
            magnitude[r, c] = np.sqrt(np.float32(fx * fx) + np.float32(fy * fy))


@jit
def sobel_magnitude_sum(image, gx, gy, magnitude, frames, partial):  # type: ignore[no-untyped-def]
    # sobel_3x3, then the float32 sum of the (H, W) magnitudes as np.add.reduce(magnitude,
    # axis=None) adds them (NumPy's pairwise order over the contiguous H * W values, after
    # the reduction's initial 0): RST-SHelo's edge strength without the NumPy steps
    sobel_3x3(image, gx, gy, magnitude)
    return np.float32(0.0) + pairwise_sum(magnitude.ravel(), 0, magnitude.size, frames, partial)


@jit
def rst_shelo_cells(image, xs, ys, gx, gy, pixel_magnitude, along, across, magnitude):  # type: ignore[no-untyped-def]
    # sobel_3x3 then cell_sums, in one call (RST-SHelo's cells of one uint8 image)
    sobel_3x3(image, gx, gy, pixel_magnitude)
    cell_sums(gx, gy, xs, ys, along, across, magnitude)


@jit
def soft_votes(theta, weight, blocks, row_weights, col_weights, bin_steps, bins, histogram):  # type: ignore[no-untyped-def]
    # RST-SHelo's soft votes: every cell's vote split over 2 block rows x 2 block columns x
    # 2 orientation bins, added to the flat padded histogram corner by corner, cell by cell
    # (the order of block_histograms' np.bincount), with its arithmetic term for term
    # (each cell's bin position is worked out once, not once per corner: the same operations)
    corners, cells_y, cells_x = blocks.shape
    histogram[:] = 0.0
    low_bin = np.empty((cells_y, cells_x), dtype=np.int64)
    fraction = np.empty((cells_y, cells_x), dtype=np.float64)
    for cy in range(cells_y):
        for cx in range(cells_x):
            position = theta[cy, cx] / np.pi * bins - 0.5
            low = np.floor(position)
            fraction[cy, cx] = position - low
            low_bin[cy, cx] = np.int64(low)
    for corner in range(corners):
        for cy in range(cells_y):
            for cx in range(cells_x):
                step = bin_steps[corner, cy, cx]
                share = fraction[cy, cx] if step == 1 else 1 - fraction[cy, cx]
                target = blocks[corner, cy, cx] + (low_bin[cy, cx] + step) % bins
                vote = weight[cy, cx] * row_weights[corner, cy, cx] * col_weights[corner, cy, cx] * share
                histogram[target] += vote


@jit
def root_normalise(padded, blocks_y, blocks_x, bins, flat, frames, partial, out):  # type: ignore[no-untyped-def]
    # RST-SHelo's square-root normalisation of the (blocks_y + 2, blocks_x + 2, bins) padded
    # histogram's interior, as square_root_normalise computes it in NumPy: the interior
    # copied in C order to ``flat`` (float64), L1-normalised by its pairwise sum (np.sum's
    # order, after the reduction's initial 0), square-rooted, divided by the pairwise sum
    # of the roots and rounded to float32 into ``out``; all zeros when the sum is not positive
    n = 0
    for by in range(1, blocks_y + 1):
        for bx in range(1, blocks_x + 1):
            start = (by * (blocks_x + 2) + bx) * bins
            for b in range(bins):
                flat[n] = padded[start + b]
                n += 1
    total = 0.0 + pairwise_sum(flat, 0, n, frames, partial)
    if total <= 0:
        out[:] = 0.0
        return
    for i in range(n):
        flat[i] = np.sqrt(flat[i] / total)
    rooted = 0.0 + pairwise_sum(flat, 0, n, frames, partial)
    for i in range(n):
        out[i] = np.float32(flat[i] / rooted)


@jit
def rst_shelo_histogram(theta, weight, blocks, row_weights, col_weights, bin_steps, bins, blocks_y, blocks_x,  # type: ignore[no-untyped-def]
                        padded, flat, frames, partial, out):
    # soft_votes then root_normalise, in one call: RST-SHelo's descriptor from its cells
    soft_votes(theta, weight, blocks, row_weights, col_weights, bin_steps, bins, padded)
    root_normalise(padded, blocks_y, blocks_x, bins, flat, frames, partial, out)


@jit
def path_sweep(columns, queries, half, bounds, offsets, directions, out, lo, hi):  # type: ignore[no-untyped-def]
    # columns: (C, R) float64; query n's window is columns n .. n + 2 * half, answered at
    # its middle column n + half. A path runs from the middle to each end in segments
    # bounds[s] .. bounds[s + 1] (columns away from the middle), each a line of one of
    # the moves: offsets[s, v, j] rows after j columns (j = 1 .. segment length; its last
    # entry is the segment's move), continuous at the segment ends; towards the window's
    # end rows go by +direction * offset, towards its start by -direction * offset.
    # out[n, r] = min over directions and paths through (middle, r) of the sum of their
    # entries (inf: no path stays in the reference). Cost-to-go by dynamic programming.
    n_ref = columns.shape[1]
    n_segments = len(bounds) - 1
    n_moves = offsets.shape[1]
    togo = np.empty(n_ref, dtype=np.float64)
    new = np.empty(n_ref, dtype=np.float64)
    acc = np.empty(n_ref, dtype=np.float64)
    total = np.empty(n_ref, dtype=np.float64)
    for i in range(lo, hi):
        n = queries[i]
        middle = n + half
        best = out[n]
        best[:] = np.inf
        for direction in directions:
            total[:] = columns[middle]
            for side in (1, -1):
                sign = direction * side
                togo[:] = 0.0
                for s in range(n_segments - 1, -1, -1):
                    b = bounds[s]
                    length = bounds[s + 1] - b
                    new[:] = np.inf
                    for v in range(n_moves):
                        move = sign * offsets[s, v, length]
                        r_lo = max(0, -move)
                        r_hi = min(n_ref, n_ref - move)
                        if r_lo >= r_hi:
                            continue
                        # slices, not ``acc[r] += column[r + shift]``: with a signed index numba's
                        # scalar loop ran ~6x slower (not vectorised); same additions, same order
                        line = acc[r_lo:r_hi]
                        line[:] = 0.0
                        for j in range(1, length + 1):
                            column = columns[middle + side * (b + j)]
                            shift = sign * offsets[s, v, j]
                            line += column[r_lo + shift : r_hi + shift]
                        ends = togo[r_lo + move : r_hi + move]
                        kept = new[r_lo:r_hi]
                        for r in range(r_hi - r_lo):
                            cost = line[r] + ends[r]
                            if cost < kept[r]:
                                kept[r] = cost
                    togo[:] = new
                for r in range(n_ref):
                    total[r] += togo[r]
            for r in range(n_ref):
                if total[r] < best[r]:
                    best[r] = total[r]
