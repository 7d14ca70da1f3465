"""Levels 2 and 3 of the frame-level hierarchical detector (``hierarchical_sequence``):
candidate sequences compared frame by frame, as trajectories through the map frames.

Rodrigues 2019's level 2 compares the j-th query place with the j-th place of each
candidate (eq. 3.5). Two traversals split the same route into places differently, so
that pairing is often wrong even for the right candidate; this mode keeps level 1's
candidates (the search-space reduction) and compares each candidate frame by frame:

- a candidate is an *anchor*, a query position paired with a map-frame position: the
  first frame of the query place searched at level 1 with the first frame of the map
  place it hit, or the last answer continued (the *track*, see below);
- a trajectory through an anchor pairs query position ``t`` with map-frame position
  ``anchor_map + shift + round((t - anchor_query) * v)``, for shifts in
  ``-slack..slack`` (a place's frames are not all alike) and speeds ``v`` in
  ``vmin..vmax`` (SeqSLAM's straight-line trajectories, Milford & Wyeth 2012);
- its cost is the mean descriptor distance of the pairs over the last ``length``
  informative query frames (at least half of them must fall inside the map on an
  informative map frame: a featureless frame, on either side, has nothing to compare and
  is left out rather than counted as a mismatch);
- each candidate is worth its best trajectory, and the best candidate answers.

Positions are counted in the detector's own order: query position ``t`` is the t-th
query frame it has seen, map-frame position ``m`` the m-th frame of the place map in map
order. Every distance is computed once while its query frame is recent
(:class:`slamfront.core.line_costs.PairDistances`, which scores the lines through an anchor
in one compiled step), and counted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from slamfront.core.line_costs import PairDistances
from slamfront.core.operating_point import distinctiveness
from slamfront.core.sequences import coarse_to_fine_lengths, cone_speeds, refined_speeds

MIN_INSIDE = 0.5
"""Share of a sequence's rows a line must pair inside the map, on informative map frames,
to be scored (on those rows): a route may go on past the map's end, or past a stretch
the map holds elsewhere, yet half of the sequence still tells where it is. Set when the
frame-level level 2 was written (on held-out data); requiring all rows or a quarter both
lose recall on data it was not set on (benchmarks/results/hierarchical_ablation.md)."""


@dataclass(frozen=True)
class Trajectory:
    """A straight line through the map frames: query position ``t`` pairs with
    ``anchor_map + round((t - anchor_query) * speed)``; ``cost`` is its mean distance
    over ``rows`` pairs."""

    cost: float
    anchor_query: int
    anchor_map: int
    speed: float
    rows: int

    def at(self, positions: np.ndarray | int) -> np.ndarray:
        """Map-frame positions paired with query positions (may fall outside the map)."""
        if isinstance(positions, int):  # one position: the same float64 steps without NumPy's per-call cost
            return np.int64(self.anchor_map + math.floor((positions - self.anchor_query) * self.speed + 0.5))
        offset = (np.asarray(positions, dtype=np.int64) - self.anchor_query) * self.speed
        return self.anchor_map + np.floor(offset + 0.5).astype(np.int64)


def speeds(vmin: float, vmax: float, length: int) -> np.ndarray:
    """(V,) speeds from ``vmin`` to ``vmax`` in steps of ``1 / length``: each step moves the
    far end of a ``length``-frame trajectory by one map frame (SeqSLAM's resolution).
    Speed 1 is always included when it lies in the range."""
    step = 1.0 / max(length, 1)
    values = np.arange(vmin, vmax + step / 2, step)
    if vmin <= 1.0 <= vmax:
        values = np.append(values, 1.0)
    return np.unique(np.round(values, 9))


def trajectory_costs(
    distances: PairDistances,
    rows: np.ndarray,
    anchor_query: int,
    anchor_map: int,
    shifts: np.ndarray,
    velocities: np.ndarray,
    n_map: int,
    map_informative: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean distance of every line through one anchor, in one lookup.

    :param rows: (R,) query positions compared (informative frames of the window).
    :param shifts: (S,) moves of the anchor's map position tried.
    :param velocities: (V,) speeds tried.
    :param n_map: map-frame positions ``0..n_map-1`` may be paired.
    :param map_informative: (>= n_map,) bool per map-frame position, False for featureless
        frames, which are left out of the pairs (None: all informative).
    :returns: (S, V) costs, inf where fewer than :data:`MIN_INSIDE` of the rows stay inside
        the map on an informative frame; (S, V) the number of rows each cost is over.
    """
    return distances.line_costs(rows, anchor_query, anchor_map, shifts, velocities, n_map, map_informative,
                                max(1, math.ceil(len(rows) * MIN_INSIDE)))


def best_trajectory(
    distances: PairDistances,
    rows: np.ndarray,
    anchor_query: int,
    anchor_map: int,
    slack: int,
    velocities: np.ndarray,
    n_map: int,
    map_informative: np.ndarray | None = None,
) -> Trajectory | None:
    """The lowest-cost trajectory through one anchor, shifts ``-slack..slack`` of its map
    position and the speeds ``velocities`` tried (:func:`trajectory_costs`).

    :returns: None when no trajectory keeps at least half of the rows inside the map.
    """
    if len(rows) == 0:
        return None
    shifts = np.arange(-slack, slack + 1, dtype=np.int64)
    costs, counts = trajectory_costs(distances, rows, anchor_query, anchor_map, shifts, velocities, n_map,
                                     map_informative)
    best = int(costs.argmin())
    # (the lowest cost is finite exactly when any is, NaN aside: NaN is only looked for then)
    if not math.isfinite(costs.flat[best]) and not np.isfinite(costs).any():
        return None
    s, v = divmod(best, costs.shape[1])
    return Trajectory(
        cost=float(costs[s, v]), anchor_query=int(anchor_query), anchor_map=int(anchor_map + shifts[s]),
        speed=float(velocities[v]), rows=int(counts[s, v]),
    )


def best_trajectories(
    distances: PairDistances,
    rows: np.ndarray,
    anchors: list[tuple[int, int]],
    slack: int,
    velocities: np.ndarray,
    n_map: int,
    map_informative: np.ndarray | None = None,
) -> list[Trajectory | None]:
    """:func:`best_trajectory` of each ``(anchor query position, anchor map position)``, in
    one call to the distances (the same trajectories, the same distances computed)."""
    if len(rows) == 0 or not anchors:
        return [None] * len(anchors)
    shifts = np.arange(-slack, slack + 1, dtype=np.int64)
    queries, maps = (np.fromiter((a[i] for a in anchors), dtype=np.int64, count=len(anchors)) for i in (0, 1))
    best, costs, counts = distances.best_lines(rows, queries, maps, shifts, velocities, n_map, map_informative,
                                               max(1, math.ceil(len(rows) * MIN_INSIDE)))
    found: list[Trajectory | None] = []
    for a, (query, anchor_map) in enumerate(anchors):
        if best[a] < 0:
            found.append(None)
            continue
        s, v = divmod(int(best[a]), len(velocities))
        found.append(Trajectory(cost=float(costs[a]), anchor_query=int(query), anchor_map=int(anchor_map + shifts[s]),
                                speed=float(velocities[v]), rows=int(counts[a])))
    return found


@dataclass(frozen=True)
class Cone:
    """The speed-free search: lines at any speed ``low..high`` (map frames per query frame)
    in each of ``directions`` (1: forward, -1: the route driven the other way), found
    coarse to fine (:func:`cone_trajectory`) rather than by trying every line."""

    low: float
    high: float
    directions: tuple[float, ...]
    first: int
    """Query frames of the coarse stage (the lines nearest the anchor; doubled per stage)."""
    keep: int
    """Lines kept from one stage to the next."""
    near_anchor: bool = False
    """Each stage compares the rows nearest the anchor (:func:`rows_near`) rather than the
    window's last rows: they differ for an anchor before the last ``first`` rows (the track,
    anchored where the last answer ended, after a long query sequence)."""


def rows_near(rows: np.ndarray, anchor_query: int, n: int) -> np.ndarray:
    """The ``n`` consecutive ``rows`` (ascending query positions) nearest ``anchor_query``:
    the last ``n``, unless the anchor lies before them, then the ``n`` from the anchor on.

    A line is pinned at its anchor, so over frames near it every speed of the cone stays
    in the map and is told apart by the descriptors; far from it the lines fan out, and
    where the route left the map (the map's end, a stretch the map holds elsewhere) the
    right line is not even scored there."""
    if n >= len(rows):
        return rows
    start = min(int(np.searchsorted(rows, anchor_query)), len(rows) - n)
    return rows[start:start + n]


def cone_trajectory(
    distances: PairDistances,
    rows: np.ndarray,
    anchor_query: int,
    anchors: tuple[int, int],
    slack: int,
    cone: Cone,
    n_map: int,
    map_informative: np.ndarray | None = None,
    stages: int | None = None,
) -> Trajectory | None:
    """The lowest-cost line through one anchor at any speed of the ``cone``, coarse to fine.

    The coarse stage tries every speed of the cone (steps of ``1 / cone.first``, in each
    of its directions) and shifts ``-slack..slack`` over the last
    ``cone.first`` rows; each following stage doubles the rows and tries, around each of
    the ``cone.keep`` best lines so far, the speeds within one coarse step (in the finer
    step) and shifts of -1..1 (:func:`slamfront.core.sequences.refined_speeds`). A line
    found over few frames is refined rather than every line of the cone tried over all
    of them: the work grows with the cone's width only at the coarse stage. This is the
    cone search with a wide speed range of the speed-free sequence matching literature
    (SeqSLAM's lines, Milford & Wyeth 2012, without their fixed speed range); a match
    whose speed changes within one window is followed only as well as one line fits it.

    :param anchors: the map-frame position paired with ``anchor_query`` for forward lines
        and for reverse ones (a place's first frame is paired with its first frame going
        forward, its last going backwards).
    :param stages: stop after this many stages (None: until all rows are compared).
    :returns: None when no line keeps at least half of the rows inside the map.
    """
    if len(rows) == 0:
        return None
    lengths = coarse_to_fine_lengths(cone.first, len(rows))[:stages]
    shifts = np.arange(-slack, slack + 1, dtype=np.int64)

    def stage(n: int) -> np.ndarray:
        return rows_near(rows, anchor_query, n) if cone.near_anchor else rows[-n:]

    found: list[Trajectory] = []
    for sign in cone.directions:
        anchor_map = anchors[0] if sign > 0 else anchors[1]
        velocities = sign * cone_speeds(cone.low, cone.high, lengths[0], False)
        found += _lines(distances, stage(lengths[0]), anchor_query, anchor_map, shifts, velocities, n_map,
                        map_informative, cone.keep)
    for coarse, fine in zip(lengths[:-1], lengths[1:]):
        kept = sorted(found, key=lambda t: t.cost)[: cone.keep]
        found = []
        for line in kept:
            velocities = refined_speeds(line.speed, coarse, fine, cone.low, cone.high)
            found += _lines(distances, stage(fine), anchor_query, line.anchor_map, np.arange(-1, 2), velocities,
                            n_map, map_informative, cone.keep)
    return min(found, key=lambda t: t.cost) if found else None


def _lines(
    distances: PairDistances,
    rows: np.ndarray,
    anchor_query: int,
    anchor_map: int,
    shifts: np.ndarray,
    velocities: np.ndarray,
    n_map: int,
    map_informative: np.ndarray | None,
    limit: int,
) -> list[Trajectory]:
    """The ``limit`` lowest-cost lines through the anchor's shifts and speeds that fit in the
    map (ties: shift, then speed order), in shift-then-speed order (one lookup).

    The caller keeps the ``limit`` lowest of several calls' lines with a stable sort (and
    the lowest one): the ``limit`` lowest of each call hold them, in the same order, so the
    rest are not made into trajectories at all."""
    costs, counts = trajectory_costs(distances, rows, anchor_query, anchor_map, shifts, velocities, n_map,
                                     map_informative)
    flat = costs.ravel()
    fitting = np.flatnonzero(np.isfinite(flat))
    if len(fitting) > limit:
        fitting = np.sort(fitting[np.argsort(flat[fitting], kind="stable")[:limit]])
    return [Trajectory(cost=float(flat[k]), anchor_query=int(anchor_query), anchor_map=int(anchor_map + shifts[s]),
                       speed=float(velocities[v]), rows=int(counts[s, v]))
            for k, (s, v) in zip(fitting.tolist(), zip(*np.divmod(fitting, costs.shape[1])))]


def uniqueness(costs: np.ndarray, ends: np.ndarray, best: int, window: int) -> float:
    """SeqSLAM's confidence among the candidates: ``1 - best / second``, ``second`` being
    the lowest cost of a candidate ending more than ``window`` map frames from the best;
    0 when there is none (nothing to tell the answer apart from)."""
    far = np.abs(ends - ends[best]) > window
    return distinctiveness(float(costs[best]), costs[far])


def line_uniqueness(
    distances: PairDistances,
    rows: np.ndarray,
    line: Trajectory,
    slack: int,
    window: int,
    n_map: int,
    map_informative: np.ndarray | None = None,
) -> float:
    """How much better ``line`` fits the query positions ``rows`` than the same line moved
    along the map by more than ``slack`` and at most ``window`` map frames:
    ``1 - cost / second``, ``second`` the lowest cost of the moved lines (each scored as
    :func:`best_trajectory` scores one line: no slack, at the line's speed).

    :func:`uniqueness` cannot see this: to it a candidate ending within ``window`` frames
    is the same answer. Where the route runs through frames that all look alike, the
    moved lines cost as much as the line itself and which of them is right is chance:
    near 0 then. 0 also when the line or no moved line fits in the map (nothing to tell
    the answer apart from)."""
    if len(rows) == 0:
        return 0.0
    moves = np.arange(slack + 1, window + 1, dtype=np.int64)
    shifts = np.concatenate([[0], -moves, moves])
    costs, _ = trajectory_costs(distances, rows, line.anchor_query, line.anchor_map, shifts,
                                np.asarray([line.speed]), n_map, map_informative)
    own, second = float(costs[0, 0]), float(costs[1:, 0].min(initial=np.inf))
    if not np.isfinite(own) or not np.isfinite(second) or second <= 0:
        return 0.0
    return float(np.clip(1.0 - own / second, 0.0, 1.0))


# --- level 2: the candidates ------------------------------------------------------------------


def compare_candidates(
    distances: PairDistances,
    anchors: list[tuple[int, int, int]],
    rows: np.ndarray,
    n_map: int,
    map_informative: np.ndarray,
    *,
    velocities: np.ndarray,
    slack: int,
    refine: int,
    screen_frames: int,
    screen_speeds: np.ndarray,
    cone: Cone | None = None,
    reverse_anchors: list[int] | None = None,
    distinct: int = 0,
    found_before: dict[tuple[bool, int, int, int], Trajectory | None] | None = None,
) -> list[tuple[Trajectory, int]]:
    """Level 2, frame by frame: each anchor's best trajectory over the query positions
    ``rows``, best first (ties: the anchors' order).

    :param anchors: ``(query position, map-frame position, source)``; source >= 0 for a
        level-1 hit (its map place), < 0 for the track.
    :param refine: when > 0 and there are more level-1 anchors, only the ``refine`` whose
        best line at ``screen_speeds`` over the last ``screen_frames`` rows costs least (and
        the track) get the full comparison, at every speed of ``velocities``.
    :param cone: None: lines at ``velocities`` (``screen_speeds`` for the screening); else
        lines at any speed of the cone (:func:`cone_trajectory`), screened by its coarse
        stage over ``screen_frames`` rows.
    :param reverse_anchors: each anchor's map-frame position for reverse lines (with a cone,
        or when every speed is negative; None: the same as forward).
    :param distinct: with ``refine``, when the ``refine`` best screened lines all end within
        this many map frames of the best one's, the best ending farther away is compared in
        full too (0: never): anchors of one place all find the same line, and the uniqueness
        confidence needs a candidate ending elsewhere to compare with.
    :param found_before: the trajectories already found per anchor (filled here): a second
        call with the same rows, speeds, cone, slack, map and screening reuses them (the
        leave-one-out null of ``accept: auto`` compares most of the iteration's anchors again).
    :returns: ``(trajectory, source)`` of the anchors with a trajectory in the map.
    """
    backwards = reverse_anchors if reverse_anchors is not None else [m for _, m, _ in anchors]
    known = {} if found_before is None else found_before

    def search(k: int, compared: np.ndarray, screening: bool) -> Trajectory | None:
        t, m, _ = anchors[k]
        if cone is None:
            tried = screen_speeds if screening else velocities
            return best_trajectory(distances, compared, t, backwards[k] if tried.max() < 0 else m, slack, tried,
                                   n_map, map_informative)
        if screening:
            return cone_trajectory(distances, compared, t, (m, backwards[k]), slack,
                                   Cone(cone.low, cone.high, cone.directions, screen_frames, cone.keep, cone.near_anchor),
                                   n_map,
                                   map_informative, stages=1)
        return cone_trajectory(distances, compared, t, (m, backwards[k]), slack, cone, n_map, map_informative)

    def search_all(ks: list[int], compared: np.ndarray, screening: bool) -> list[Trajectory | None]:
        keys = [(screening, anchors[k][0], anchors[k][1], backwards[k]) for k in ks]
        missing = [k for k, key in zip(ks, keys) if key not in known]
        if cone is not None:
            new = [search(k, compared, screening) for k in missing]
        else:  # every anchor's lines in one call
            tried = screen_speeds if screening else velocities
            forward = tried.max() >= 0
            new = best_trajectories(distances, compared, [(anchors[k][0], anchors[k][1] if forward else backwards[k])
                                                          for k in missing], slack, tried, n_map, map_informative)
        for k, trajectory in zip(missing, new):
            known[(screening, anchors[k][0], anchors[k][1], backwards[k])] = trajectory
        return [known[key] for key in keys]

    kept = list(range(len(anchors)))
    searched = [k for k, a in enumerate(anchors) if a[2] >= 0]
    if refine and len(searched) > refine:
        screened = []
        end = int(rows[-1])
        for k, found in zip(searched, search_all(searched, rows[-screen_frames:], True)):
            if found is not None:
                screened.append((found.cost, k, int(found.at(end))))
        screened.sort()
        best = screened[:refine]
        if distinct > 0 and all(abs(entry[2] - best[0][2]) <= distinct for entry in best):
            # all at one place: the best ending elsewhere too, for the uniqueness to compare with
            best += [entry for entry in screened[refine:] if abs(entry[2] - best[0][2]) > distinct][:1]
        kept = [k for _, k, _ in best] + [k for k, a in enumerate(anchors) if a[2] < 0]
    found = []
    for order, (k, trajectory) in enumerate(zip(kept, search_all(kept, rows, False))):
        if trajectory is not None:
            found.append((trajectory.cost, order, trajectory, anchors[k][2]))
    return [(trajectory, source) for _, _, trajectory, source in sorted(found, key=lambda f: (f[0], f[1]))]


# --- level 3: where Q's frames are answered -----------------------------------------------------


def realign(
    distances: PairDistances,
    chosen: list[Trajectory],
    rows: np.ndarray,
    slack: int,
    n_map: int,
    map_informative: np.ndarray,
    pace: bool = True,
) -> Trajectory:
    """Level 3 (eq. 3.10 on Q's frames): Q's informative query positions ``rows`` slid along
    the ``chosen`` trajectories and, as the thesis's template matching, at speed 1 through
    their middle (-1 for a trajectory running backwards), ``-slack..slack`` map frames; the placement they fit best (ties: the
    first tried; ``chosen[0]`` when none fits).

    A placement may leave the map (the route goes on past the map's end, or past a
    stretch the map holds elsewhere) as long as at least half of the rows stay inside, as
    in level 2; it is scored on those, by level 2's rule (the line alone, no slack).
    ``pace: False`` slides Q at each chosen trajectory's own speed instead of speed 1 (a
    query that need not run at the map's pace)."""
    if not len(rows):
        return chosen[0]
    middle = int(rows[len(rows) // 2])
    placements: list[Trajectory] = []
    for trajectory in dict.fromkeys(chosen):
        placements.append(trajectory)
        for shift in range(-slack, slack + 1):
            speed = math.copysign(1.0, trajectory.speed) if pace else trajectory.speed
            placements.append(Trajectory(trajectory.cost, middle, int(trajectory.at(middle)) + shift, speed,
                                         trajectory.rows))
            if shift:
                placements.append(Trajectory(trajectory.cost, trajectory.anchor_query,
                                             trajectory.anchor_map + shift, trajectory.speed, trajectory.rows))
    costs = []
    for placement in placements:
        scored = best_trajectory(distances, rows, placement.anchor_query, placement.anchor_map, 0,
                                 np.asarray([placement.speed]), n_map, map_informative)
        costs.append(np.inf if scored is None else scored.cost)
    if not np.isfinite(min(costs)):
        return chosen[0]
    return placements[int(np.argmin(costs))]

