"""The numba kernel behind :meth:`slamfront.core.line_costs.PairDistances.line_costs`:
every straight line through one anchor scored in one call, the descriptor distances it
needs computed (once, into the caller's table) on the way.

A module of its own so that numba's on-disk cache of :mod:`slamfront.core.compiled_kernels`
stays valid. The arithmetic repeats the NumPy reference
(:func:`slamfront.core.line_costs.line_costs_reference`) operation for operation:

- a descriptor distance is ``rowwise``'s float32 L1, ``|x - y|`` summed in NumPy's pairwise
  order (:func:`pairwise_l1`, the same tree as
  :func:`slamfront.core.compiled_kernels.pairwise_sum`, with the absolute differences taken
  on the fly instead of from a buffer, and a block's 8 running sums kept in one 8-wide
  vector: :func:`lane_sums_l1`);
- a line's cost is the float64 sum, in NumPy's pairwise order, of its R entries (0 where
  the line leaves the map or meets a featureless map frame), divided by its pair count.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from slamfront.core.compiled_kernels import pairwise_sum
from slamfront.core.kernels import PAIRWISE_BLOCK

jit = numba.njit(nogil=True, cache=True, error_model="numpy")
_U = np.uint64  # unsigned indices: numba skips the negative-index wraparound, which kept the loops slow


def _l1_term(context, builder, array_type, x, y):  # type: ignore[no-untyped-def]
    # codegen of |x[i:i+8] - y[i:i+8]| as one 8-wide float32 vector (uint8 widened first),
    # as a function of the index i: the step both lane-sum intrinsics add up
    xs = context.make_array(array_type)(context, builder, x).data
    ys = context.make_array(array_type)(context, builder, y).data
    floats = ir.VectorType(ir.FloatType(), 8)
    loaded = ir.VectorType(xs.type.pointee, 8)
    fabs = cgutils.get_or_insert_function(builder.module, ir.FunctionType(floats, [floats]), "llvm.fabs.v8f32")

    def term(index):  # type: ignore[no-untyped-def]
        a = builder.load(builder.bitcast(builder.gep(xs, [index]), loaded.as_pointer()), align=1)
        b = builder.load(builder.bitcast(builder.gep(ys, [index]), loaded.as_pointer()), align=1)
        if array_type.dtype == types.uint8:
            a, b = builder.uitofp(a, floats), builder.uitofp(b, floats)
        return builder.call(fabs, [builder.fsub(a, b)])

    return term


@intrinsic
def lane_sums_l1(typingctx, x, y, start, stop):  # type: ignore[no-untyped-def]
    # The 8 running sums of NumPy's pairwise block over [start, stop) (a multiple of 8
    # values, at least 8): lane k adds |x[i] - y[i]| for i = start + k, start + k + 8, ...,
    # one after the other from the first, as r0..r7 of compiled_kernels.block_sum do. One
    # 8-wide vector add per step (lane-wise IEEE adds, so the same bits as 8 scalar sums):
    # numba's loops left the 8 sums scalar. uint8 values are widened to float32 first, as
    # ``a.astype(np.float32) - b`` does.
    if not (isinstance(x, types.Array) and x == y and x.ndim == 1 and x.layout == "C"
            and x.dtype in (types.float32, types.uint8)):
        return None
    signature = types.UniTuple(types.float32, 8)(x, y, types.intp, types.intp)

    def codegen(context, builder, sig, args):  # type: ignore[no-untyped-def]
        term = _l1_term(context, builder, sig.args[0], args[0], args[1])
        lo, hi = args[2], args[3]
        sums = cgutils.alloca_once_value(builder, term(lo))
        eight = ir.Constant(lo.type, 8)
        with cgutils.for_range_slice(builder, builder.add(lo, eight), hi, eight, lo.type) as (index, _):
            builder.store(builder.fadd(builder.load(sums), term(index)), sums)
        total = builder.load(sums)
        lanes = [builder.extract_element(total, ir.Constant(ir.IntType(32), k)) for k in range(8)]
        return context.make_tuple(builder, sig.return_type, lanes)

    return signature, codegen


@intrinsic
def lane_sums_l1_x4(typingctx, x, y, s0, s1, s2, s3, count):  # type: ignore[no-untyped-def]
    # lane_sums_l1 of the four blocks [s0, s0 + count), ..., [s3, s3 + count) (count a multiple
    # of 8, at least 8), in one loop: each block keeps its own 8-wide sum, added in the same
    # order as lane_sums_l1 adds it (the same bits), but the four independent chains of adds
    # overlap instead of each waiting for the previous add to finish. 32 values, block by block.
    if not (isinstance(x, types.Array) and x == y and x.ndim == 1 and x.layout == "C"
            and x.dtype in (types.float32, types.uint8)):
        return None
    signature = types.UniTuple(types.float32, 32)(x, y, types.intp, types.intp, types.intp, types.intp, types.intp)

    def codegen(context, builder, sig, args):  # type: ignore[no-untyped-def]
        term = _l1_term(context, builder, sig.args[0], args[0], args[1])
        starts, n = args[2:6], args[6]
        sums = [cgutils.alloca_once_value(builder, term(start)) for start in starts]
        eight = ir.Constant(n.type, 8)
        with cgutils.for_range_slice(builder, eight, n, eight, n.type) as (offset, _):
            for total, start in zip(sums, starts):
                builder.store(builder.fadd(builder.load(total), term(builder.add(start, offset))), total)
        lanes = []
        for total in sums:
            vector = builder.load(total)
            lanes += [builder.extract_element(vector, ir.Constant(ir.IntType(32), k)) for k in range(8)]
        return context.make_tuple(builder, sig.return_type, lanes)

    return signature, codegen


@jit
def _lanes_total(r0, r1, r2, r3, r4, r5, r6, r7):  # type: ignore[no-untyped-def]
    # a block's 8 running sums combined as NumPy's pairwise block combines them
    return ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))


@jit
def block_l1(x, y, start, n):  # type: ignore[no-untyped-def]
    # NumPy's pairwise summation of |x - y| over n <= 128 values from start (block_sum of
    # the absolute differences): 8 running sums combined as a fixed tree, then the rest one by one
    if n < 8:
        res = np.float32(-0.0)
        for i in range(start, start + n):
            res += abs(np.float32(x[_U(i)]) - np.float32(y[_U(i)]))
        return res
    full = n - n % 8
    r0, r1, r2, r3, r4, r5, r6, r7 = lane_sums_l1(x, y, start, start + full)
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for k in range(start + full, start + n):
        res += abs(np.float32(x[_U(k)]) - np.float32(y[_U(k)]))
    return res


@jit
def pairwise_l1(x, y, frames, partial):  # type: ignore[no-untyped-def]
    # float32 sum of |x - y| in NumPy's pairwise order (compiled_kernels.pairwise_sum's tree,
    # on an explicit stack), plus the reduction's initial 0 as np.sum adds it. The walk repeats
    # pairwise_sum's rather than taking the block function as an argument: numba does not
    # cache a kernel that passes a function, and pairwise_sum's own blocks (behind SeqSLAM's
    # difference matrix) are left as they are
    n = x.shape[0]
    if n <= PAIRWISE_BLOCK:
        return np.float32(0.0) + block_l1(x, y, 0, n)
    # a length NumPy halves exactly down to its blocks (1,152 = 16 blocks of 72) is a full
    # binary tree over equal blocks of whole 8-value steps: the blocks four at a time
    # (lane_sums_l1_x4), then the tree level by level, the same additions as the walk below
    size, leaves = n, 1
    while size > PAIRWISE_BLOCK and size % 16 == 0:
        size //= 2
        leaves *= 2
    if size <= PAIRWISE_BLOCK and size % 8 == 0 and leaves % 4 == 0 and leaves <= partial.shape[0]:
        for g in range(0, leaves, 4):
            t = lane_sums_l1_x4(x, y, g * size, (g + 1) * size, (g + 2) * size, (g + 3) * size, size)
            partial[g] = _lanes_total(t[0], t[1], t[2], t[3], t[4], t[5], t[6], t[7])
            partial[g + 1] = _lanes_total(t[8], t[9], t[10], t[11], t[12], t[13], t[14], t[15])
            partial[g + 2] = _lanes_total(t[16], t[17], t[18], t[19], t[20], t[21], t[22], t[23])
            partial[g + 3] = _lanes_total(t[24], t[25], t[26], t[27], t[28], t[29], t[30], t[31])
        while leaves > 1:
            leaves //= 2
            for i in range(leaves):
                partial[i] = partial[2 * i] + partial[2 * i + 1]
        return np.float32(0.0) + partial[0]
    top = 0
    frames[0, 0], frames[1, 0], frames[2, 0] = 0, n, 0
    result = np.float32(0.0)
    while top >= 0:
        s, m = frames[0, top], frames[1, top]
        if m <= PAIRWISE_BLOCK:
            result = block_l1(x, y, s, m)
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
    return np.float32(0.0) + result


@jit
def line_costs(table, owner, state, rows, anchor_query, anchor_map, shifts, velocities, n_map, map_informative,
               need, vectors, query_rows, map_rows, costs, counts):  # type: ignore[no-untyped-def]
    # The lines anchor_map + shifts[s] + round((rows - anchor_query) * velocities[v]): costs
    # (S, V) float64 (inf where fewer than ``need`` pairs are inside the map on informative
    # map frames), counts (S, V) int64. The distance of query position t and map position m
    # sits in table[t % keep, m] (NaN: not computed yet; owner[t % keep] = t); state is
    # [newest query position seen, distances computed]. Returns 0, or, before changing
    # anything, the rows the table needs when this call's positions span more than it has.
    # Distances: vectors[query_rows[t]] against vectors[map_rows[m]].
    keep = table.shape[0]
    n_shifts = shifts.shape[0]
    n_speeds = velocities.shape[0]
    n_rows = rows.shape[0]
    steps = np.empty((n_speeds, n_rows), dtype=np.int64)
    for v in range(n_speeds):
        for r in range(n_rows):
            steps[v, r] = np.int64(np.floor(np.float64(rows[r] - anchor_query) * velocities[v] + 0.5))
    # pass 1: which pairs each line has inside the map, on informative map frames, how many;
    # and which rows any line with enough pairs compares
    inside = np.zeros((n_shifts, n_speeds, n_rows), dtype=np.bool_)
    asked = np.zeros(n_rows, dtype=np.bool_)
    for s in range(n_shifts):
        base = anchor_map + shifts[s]
        for v in range(n_speeds):
            count = 0
            for r in range(n_rows):
                m = base + steps[v, r]
                if 0 <= m < n_map and map_informative[m]:
                    inside[s, v, r] = True
                    count += 1
            counts[s, v] = count
            if count >= need:
                for r in range(n_rows):
                    if inside[s, v, r]:
                        asked[r] = True
    lowest = np.int64(-1)
    highest = np.int64(-1)
    for r in range(n_rows):
        if asked[r]:
            if lowest < 0 or rows[r] < lowest:
                lowest = rows[r]
            if rows[r] > highest:
                highest = rows[r]
    if lowest < 0:  # no line has enough pairs
        costs[:, :] = np.inf
        return 0
    if highest - lowest >= keep:
        return highest - lowest + 1
    # rows that hold another position, or one older than the newest minus keep, are cleared
    newest = state[0]
    slots = np.empty(n_rows, dtype=np.int64)
    for r in range(n_rows):
        t = rows[r]
        slots[r] = t % keep
        if asked[r] and (owner[slots[r]] != t or t <= newest - keep):
            table[slots[r], :] = np.nan
            owner[slots[r]] = t
    state[0] = max(newest, highest)
    # pass 2: each line's entries (its distances, computed when missing), summed as NumPy sums
    values = np.empty(n_rows, dtype=np.float64)
    frames = np.empty((3, 64), dtype=np.int64)
    partial = np.empty(64, dtype=np.float32)
    frames64 = np.empty((3, 64), dtype=np.int64)
    partial64 = np.empty(64, dtype=np.float64)
    computed = 0
    for s in range(n_shifts):
        base = anchor_map + shifts[s]
        for v in range(n_speeds):
            if counts[s, v] < need:
                costs[s, v] = np.inf
                continue
            for r in range(n_rows):
                if inside[s, v, r]:
                    m = base + steps[v, r]
                    value = table[slots[r], m]
                    if np.isnan(value):
                        value = pairwise_l1(vectors[query_rows[rows[r]]], vectors[map_rows[m]], frames, partial)
                        table[slots[r], m] = value
                        computed += 1
                    values[r] = np.float64(value)
                else:
                    values[r] = 0.0
            costs[s, v] = (0.0 + pairwise_sum(values, 0, n_rows, frames64, partial64)) / np.float64(counts[s, v])
    state[1] += computed
    return 0


@jit
def best_lines(table, owner, state, rows, anchor_queries, anchor_maps, first, shifts, velocities, n_map,
               map_informative, need, vectors, query_rows, map_rows, best, best_costs, best_counts):  # type: ignore[no-untyped-def]
    # line_costs for the anchors first.. (one call instead of one per anchor), each reduced to
    # its lowest line as NumPy's argmin picks it: the first NaN if any, else the first lowest
    # (best[a] = flat index s * V + v; -1 when no line has a finite cost and none is NaN-first
    # with a finite one elsewhere, as best_trajectory's None). Returns (anchor, rows needed)
    # when the table must grow before anchor ``anchor`` (the anchors before it are done), else
    # (-1, 0).
    n_speeds = velocities.shape[0]
    costs = np.empty((shifts.shape[0], n_speeds), dtype=np.float64)
    counts = np.empty((shifts.shape[0], n_speeds), dtype=np.int64)
    for a in range(first, anchor_queries.shape[0]):
        needed = line_costs(table, owner, state, rows, anchor_queries[a], anchor_maps[a], shifts, velocities, n_map,
                            map_informative, need, vectors, query_rows, map_rows, costs, counts)
        if needed:
            return a, needed
        lowest = -1
        first_nan = -1
        finite = False
        flat = costs.ravel()
        for i in range(flat.shape[0]):
            value = flat[i]
            if np.isnan(value):
                if first_nan < 0:
                    first_nan = i
            else:
                if np.isfinite(value):
                    finite = True
                if lowest < 0 or value < flat[lowest]:
                    lowest = i
        chosen = first_nan if first_nan >= 0 else lowest
        if chosen < 0 or (not np.isfinite(flat[chosen]) and not finite):
            best[a] = -1
            best_costs[a] = np.inf
            best_counts[a] = 0
        else:
            best[a] = chosen
            best_costs[a] = flat[chosen]
            best_counts[a] = counts.ravel()[chosen]
    return -1, 0
