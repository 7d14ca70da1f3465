"""A procedural street world, ray cast on the CPU in float64, the same bits on every machine.

The world is a closed street (a rounded rectangle) lined on both sides by buildings.
Every building gets its own facade, drawn from a seeded random generator: wall colour,
window grid, shop front, signs, brick-like noise. Side-street gaps in the outer row show
a second row of buildings further away. The camera drives along the street; a second
traversal of the same route can differ in illumination (day, dusk, night with lit
windows), viewpoint (a lateral offset and a yaw offset) and moving occluders (people
and vehicles as upright cylinders). Everything is a pure function of the world seed and the
frame's parameters, so frames are deterministic and can be rendered in any order.

Every building face is a vertical wall standing on flat ground and the camera never rolls
or pitches, so a ray's horizontal direction depends on its image column only: the caster
intersects each column with the walls in 2-D, then picks per row the nearest wall the ray
passes between its foot and its top. It uses only IEEE-exact arithmetic (+ - * / sqrt,
floor), never a reduction, matrix product or library ray caster whose rounding follows the
CPU: Open3D's Embree, which this replaced, picks SSE/AVX2/AVX-512 code at run time and
returns depths that differ in the last bit between machines (on ~8 % of the pixels of an
emulated Haswell against this AVX-512 one), and the odometry downstream amplifies a
last-bit change of the depth into a different trajectory.

World frame: x east, y north, z up, metres. Camera frame: OpenCV (x right, y down,
z forward). Poses are camera-to-world 4x4 matrices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

Illumination = Literal["day", "dusk", "night"]

_CAMERA_HEIGHT = 1.6
_STOREY = 3.2
_SHOP_HEIGHT = 3.6


@dataclass(frozen=True)
class Lighting:
    """How a traversal is lit."""

    sun: np.ndarray  # unit vector towards the sun
    sun_rgb: np.ndarray
    ambient_rgb: np.ndarray
    sky_top: np.ndarray
    sky_horizon: np.ndarray
    window_lit_fraction: float  # share of windows glowing (night)
    gamma: float

    @staticmethod
    def of(kind: Illumination) -> Lighting:
        if kind == "day":
            return Lighting(
                sun=_unit([0.45, -0.35, 0.82]), sun_rgb=np.array([1.0, 0.98, 0.92]),
                ambient_rgb=np.array([0.42, 0.44, 0.48]), sky_top=np.array([0.35, 0.55, 0.85]),
                sky_horizon=np.array([0.78, 0.85, 0.95]), window_lit_fraction=0.0, gamma=1.0,
            )
        if kind == "dusk":
            return Lighting(
                # the sun is down: light is mostly diffuse, warm and dim
                sun=_unit([-0.8, 0.5, 0.18]), sun_rgb=np.array([0.2, 0.12, 0.07]),
                ambient_rgb=np.array([0.5, 0.42, 0.42]), sky_top=np.array([0.18, 0.2, 0.38]),
                sky_horizon=np.array([0.85, 0.5, 0.3]), window_lit_fraction=0.25, gamma=1.25,
            )
        if kind == "night":
            return Lighting(
                sun=_unit([0.0, 0.0, 1.0]), sun_rgb=np.array([0.05, 0.05, 0.08]),
                ambient_rgb=np.array([0.09, 0.09, 0.12]), sky_top=np.array([0.02, 0.02, 0.05]),
                sky_horizon=np.array([0.08, 0.07, 0.1]), window_lit_fraction=0.45, gamma=1.5,
            )
        raise ValueError(f"unknown illumination {kind!r}")


def _unit(v: list[float] | np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / math.sqrt(sum(float(c) * float(c) for c in v))  # no BLAS dot: its rounding follows the CPU


def _hash01(*keys: np.ndarray) -> np.ndarray:
    """A deterministic pseudo-random value in [0, 1) per element of integer arrays."""
    h = np.uint64(1469598103934665603)
    with np.errstate(over="ignore"):
        acc = np.full(np.broadcast(*keys).shape, h, dtype=np.uint64)
        for key in keys:
            acc ^= np.asarray(key).astype(np.int64).astype(np.uint64) + np.uint64(0x9E3779B97F4A7C15)
            acc *= np.uint64(1099511628211)
            acc ^= acc >> np.uint64(29)
            acc *= np.uint64(0xBF58476D1CE4E5B9)
            acc ^= acc >> np.uint64(32)
    return (acc >> np.uint64(11)).astype(np.float64) / float(1 << 53)


@dataclass(frozen=True)
class Route:
    """A closed rounded-rectangle centreline, parameterised by arc length."""

    width: float
    height: float
    corner_radius: float

    @property
    def length(self) -> float:
        straight = 2 * (self.width - 2 * self.corner_radius) + 2 * (self.height - 2 * self.corner_radius)
        return straight + 2 * np.pi * self.corner_radius

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 2) and unit headings (N, 2) at arc lengths ``s`` (wrapping)."""
        s = np.mod(np.asarray(s, dtype=np.float64), self.length)
        w, h, r = self.width, self.height, self.corner_radius
        legs = [w - 2 * r, h - 2 * r, w - 2 * r, h - 2 * r]
        quarter = np.pi * r / 2
        # counter-clockwise from the middle-left of the bottom edge
        starts = [np.array([r - w / 2, -h / 2]), np.array([w / 2, r - h / 2]),
                  np.array([w / 2 - r, h / 2]), np.array([-w / 2, h / 2 - r])]
        directions = [np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([-1.0, 0.0]), np.array([0.0, -1.0])]
        # each leg's heading angle minus 90 degrees (numpy's arctan2 rounds by the CPU's instruction set)
        start_angles = [-np.pi / 2, 0.0, np.pi / 2, -np.pi]
        pos = np.zeros((len(s), 2))
        head = np.zeros((len(s), 2))
        offset = 0.0
        for leg, start, direction, angle0 in zip(legs, starts, directions, start_angles):
            on_leg = (s >= offset) & (s < offset + leg)
            t = s[on_leg] - offset
            pos[on_leg] = start + t[:, None] * direction
            head[on_leg] = direction
            offset += leg
            on_arc = (s >= offset) & (s < offset + quarter)
            centre = start + leg * direction + r * np.array([-direction[1], direction[0]])
            phi = angle0 + (s[on_arc] - offset) / r
            pos[on_arc] = centre + r * np.stack([np.cos(phi), np.sin(phi)], axis=1)
            head[on_arc] = np.stack([-np.sin(phi), np.cos(phi)], axis=1)
            offset += quarter
        return pos, head


@dataclass
class Facades:
    """Per-building appearance parameters (arrays indexed by building id)."""

    wall_rgb: np.ndarray
    shop_rgb: np.ndarray
    trim_rgb: np.ndarray
    window_spacing: np.ndarray
    window_width: np.ndarray
    window_height: np.ndarray
    sign_rgb: np.ndarray
    sign_start: np.ndarray
    sign_length: np.ndarray
    brick: np.ndarray
    stripes: np.ndarray
    start: np.ndarray  # facade coordinate where the building begins


class StreetWorld:
    """The static scene: vertical walls on flat ground, plus facade parameters.

    :param seed: everything random in the world derives from it.
    :param route_length_m: approximate length of the closed street.
    :param street_width_m: distance between the two building rows.
    :param own_patterns: the surface patterns (road, bricks, windows, signs) derive from
        ``seed`` too. Otherwise they depend on the place only, as they always did: the
        n-th building of every world carries the same bricks and sign letters and every
        world has the same road, so two worlds' frames of one place of the route share
        texture that matches geometrically.
    """

    def __init__(
        self, seed: int, route_length_m: float = 400.0, street_width_m: float = 10.0, own_patterns: bool = False
    ) -> None:
        rng = np.random.default_rng(seed)
        aspect = 1.6
        height = route_length_m / (2 * (aspect + 1))
        width = aspect * height
        radius = min(street_width_m, height / 4)
        # rounding the corners shortens the route: rescale to the requested length
        scale = route_length_m / Route(width, height, radius).length
        self.route = Route(width * scale, height * scale, radius * scale)
        self.street_width = street_width_m
        self.seed = seed
        self.own_patterns = own_patterns
        self._walls: list[tuple[np.ndarray, np.ndarray, float, int, float]] = []  # a, b, height, building, s0
        self._building_params: list[dict[str, np.ndarray | float]] = []
        self._build(rng)
        # wall w runs from wall_a[w] to wall_b[w] (x, y), from the ground to wall_height[w]
        self.wall_a = np.array([w[0] for w in self._walls], dtype=np.float64)
        self.wall_b = np.array([w[1] for w in self._walls], dtype=np.float64)
        self.wall_height = np.array([w[2] for w in self._walls], dtype=np.float64)
        self.wall_building = np.array([w[3] for w in self._walls], dtype=np.int64)
        self.wall_s0 = np.array([w[4] for w in self._walls], dtype=np.float64)
        edge = self.wall_b - self.wall_a
        length = np.sqrt(edge[:, 0] * edge[:, 0] + edge[:, 1] * edge[:, 1])
        self.wall_axis = edge / length[:, None]  # the facade coordinate's direction
        # the normal faces the street (the walls are ordered so that it does)
        self.wall_normal = np.stack([self.wall_axis[:, 1], -self.wall_axis[:, 0], np.zeros(len(edge))], axis=1)
        self.ground_extent = max(self.route.width, self.route.height)
        self.facades = self._facades()

    # -- construction --------------------------------------------------------------------

    def _wall(self, a: np.ndarray, b: np.ndarray, height: float, building: int, s0: float) -> None:
        """A vertical rectangle from a to b (2-D points), 0 to ``height`` m; ``s0`` is the facade coordinate at a."""
        self._walls.append((a, b, height, building, s0))

    def _new_building(self, rng: np.random.Generator, start: float) -> int:
        hue = rng.uniform(0, 1)
        base = np.clip(0.35 + 0.45 * np.array([np.cos(2 * np.pi * (hue + k / 3)) for k in range(3)]) * rng.uniform(0.2, 0.6), 0.08, 0.95)
        self._building_params.append(
            dict(
                wall_rgb=base * rng.uniform(0.6, 1.1),
                shop_rgb=rng.uniform(0.1, 0.9, 3),
                trim_rgb=rng.uniform(0.0, 1.0, 3),
                window_spacing=rng.uniform(1.6, 3.4),
                window_width=rng.uniform(0.35, 0.7),
                window_height=rng.uniform(0.4, 0.7),
                sign_rgb=rng.uniform(0.0, 1.0, 3),
                sign_start=rng.uniform(0.0, 0.5),
                sign_length=rng.uniform(0.2, 0.5),
                brick=rng.uniform(0.03, 0.12),
                stripes=float(rng.integers(0, 3)),
                start=start,
            )
        )
        return len(self._building_params) - 1

    def _row(self, rng: np.random.Generator, offset: float, outer: bool) -> None:
        """A row of buildings along the route at lateral ``offset`` (left of travel > 0)."""
        length = self.route.length
        s_values = np.arange(0.0, length + 0.5, 0.5)
        pos, head = self.route.at(s_values)
        normal = np.stack([-head[:, 1], head[:, 0]], axis=1)
        points = pos + offset * normal
        s = 0.0
        while s < length:
            width = rng.uniform(5.0, 14.0)
            end = min(s + width, length)
            gap = outer and rng.uniform() < 0.12
            building = self._new_building(rng, s)
            height = rng.uniform(7.0, 22.0)
            i0, i1 = int(s / 0.5), int(end / 0.5)
            idx = np.arange(i0, max(i1, i0 + 1) + 1)
            idx = np.minimum(idx, len(points) - 1)
            seq = points[idx]
            if gap:  # a side street: this building stands back, seen down the gap
                seq = seq + np.sign(offset) * 25.0 * normal[idx]
            # the facade coordinate grows along a->b: with the route on the right row,
            # against it on the left row (a and b are swapped there to face the street)
            for k in range(len(seq) - 1):
                if offset < 0:
                    a, b, s0 = seq[k], seq[k + 1], s_values[idx[k]]
                else:
                    a, b, s0 = seq[k + 1], seq[k], -s_values[idx[k + 1]]
                if math.hypot(*(b - a)) > 1e-6:
                    self._wall(a, b, height, building, s0)
            s = end

    def _build(self, rng: np.random.Generator) -> None:
        half = self.street_width / 2
        self._row(rng, -half, outer=True)  # right of travel (counter-clockwise route: outside)
        self._row(rng, +half, outer=False)

    def _facades(self) -> Facades:
        params = self._building_params
        return Facades(**{key: np.array([p[key] for p in params]) for key in params[0]})

    # -- cameras ---------------------------------------------------------------------------

    def pose_at(self, s: float, lateral_m: float = 0.0, yaw_deg: float = 0.0, weave_m: float = 0.3) -> np.ndarray:
        """Camera-to-world pose at arc length ``s``; ``lateral_m`` > 0 moves left."""
        pos, head = self.route.at(np.array([s]))
        pos, head = pos[0], head[0]
        left = np.array([-head[1], head[0]])
        weave = weave_m * np.sin(2 * np.pi * s / 37.0)
        centre = pos + (lateral_m + weave) * left
        yaw = np.deg2rad(yaw_deg) + 0.04 * np.sin(2 * np.pi * s / 23.0)
        c, si = np.cos(yaw), np.sin(yaw)
        forward2 = np.array([c * head[0] - si * head[1], si * head[0] + c * head[1]])
        forward = np.r_[forward2, 0.0]
        down = np.array([0.0, 0.0, -1.0])
        right = np.cross(down, forward)
        pose = np.eye(4)
        pose[:3, :3] = np.stack([right, down, forward], axis=1)
        pose[:3, 3] = np.r_[centre, _CAMERA_HEIGHT]
        return pose

    # -- rendering ---------------------------------------------------------------------------

    def render(
        self,
        pose: np.ndarray,
        intrinsics: np.ndarray,
        width: int,
        height: int,
        lighting: Lighting,
        occluders: np.ndarray | None = None,
        noise_std: float = 0.0,
        noise_seed: int = 0,
        max_depth_m: float = 40.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """RGB uint8 (H, W, 3) and depth float32 (H, W) metres (0 = no return).

        :param pose: camera-to-world, upright (no roll or pitch), as :meth:`pose_at` gives.
        :param occluders: (K, 5) upright cylinders ``x, y, radius, height, colour seed``.
        """
        rotation, origin = np.asarray(pose, dtype=np.float64)[:3, :3], np.asarray(pose, dtype=np.float64)[:3, 3]
        right, forward = rotation[:, 0], rotation[:, 2]
        if not (np.array_equal(rotation[:, 1], [0.0, 0.0, -1.0]) and right[2] == 0 and forward[2] == 0):
            raise ValueError("StreetWorld.render takes upright cameras (no roll or pitch), as pose_at gives")
        fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
        x = (np.arange(width, dtype=np.float64) - cx) / fx
        y = (np.arange(height, dtype=np.float64) - cy) / fy
        # ray = x * right + y * down + forward (camera z = 1, so the ray parameter is the depth):
        # its horizontal part depends on the column only, its height on the row only
        column_dirs = np.stack([x * right[0] + forward[0], x * right[1] + forward[1]], axis=1)  # (W, 2)
        rise = -y  # (H,)
        dirs = np.empty((height, width, 3))
        dirs[..., :2] = column_dirs[None]
        dirs[..., 2] = rise[:, None]
        t, wall_of, on_ground = self._cast(origin, column_dirs, rise)
        points = origin + dirs * np.where(np.isfinite(t), t, 0.0)[..., None]
        colour = self._sky(dirs, lighting)
        wall = wall_of >= 0
        if wall.any():
            colour[wall] = self._facade_colour(points[wall], wall_of[wall], lighting)
        if on_ground.any():
            colour[on_ground] = self._ground_colour(points[on_ground], lighting)

        depth = t
        if occluders is not None and len(occluders):
            depth, colour = self._occlude(origin, dirs, depth, colour, occluders, lighting)
        # distance haze keeps far geometry from aliasing into noise
        haze = np.clip((np.where(np.isfinite(depth), depth, max_depth_m * 3) - 25.0) / 120.0, 0.0, 0.6)[..., None]
        colour = colour * (1 - haze) + lighting.sky_horizon * haze
        colour = np.clip(colour, 0.0, 1.0) ** (1.0 / lighting.gamma)
        image = colour * 255.0
        if noise_std > 0:
            image = image + np.random.default_rng(noise_seed).normal(0.0, noise_std, image.shape)
        rgb = np.clip(image + 0.5, 0, 255).astype(np.uint8)
        depth_out = np.where(np.isfinite(depth) & (depth <= max_depth_m), depth, 0.0).astype(np.float32)
        return rgb, depth_out

    def _cast(self, origin: np.ndarray, column_dirs: np.ndarray, rise: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Depth (H, W) (inf: sky), the wall each pixel sees (-1: none) and whether it sees the ground.

        :param column_dirs: (W, 2) the horizontal part of each column's rays.
        :param rise: (H,) the vertical part of each row's rays (per unit depth).
        """
        height, width = len(rise), len(column_dirs)
        dx, dy = column_dirs[:, 0:1], column_dirs[:, 1:2]
        edge = self.wall_b - self.wall_a
        ex, ey = edge[None, :, 0], edge[None, :, 1]
        wx, wy = self.wall_a[None, :, 0] - origin[0], self.wall_a[None, :, 1] - origin[1]
        # where column c's ray crosses wall w in plan view: origin + t d = a + s (b - a)
        denom = dx * ey - dy * ex
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (wx * ey - wy * ex) / denom
            s = (wx * dy - wy * dx) / denom
        crossed = (denom != 0) & (t > 0) & (s >= 0) & (s <= 1)
        columns, walls = np.nonzero(crossed)
        depths = t[columns, walls]
        order = np.lexsort((walls, depths, columns))  # per column, nearest first (ties: lower wall)
        columns, walls, depths = columns[order], walls[order], depths[order]
        counts = np.bincount(columns, minlength=width)
        rank = np.arange(len(columns)) - np.repeat(np.cumsum(counts) - counts, counts)
        k = int(counts.max()) if len(columns) else 0
        crossing_depth = np.full((width, k), np.inf)
        crossing_wall = np.zeros((width, k), dtype=np.int64)
        crossing_depth[columns, rank] = depths
        crossing_wall[columns, rank] = walls
        # a row's ray hits the first crossed wall it passes between the wall's foot and top
        z = origin[2] + crossing_depth[None] * rise[:, None, None]  # (H, W, k)
        hits = (z >= 0) & (z <= self.wall_height[crossing_wall][None]) & np.isfinite(crossing_depth)[None]
        first = np.argmax(hits, axis=2)[..., None] if k else np.zeros((height, width, 1), dtype=np.int64)
        on_wall = hits.any(axis=2) if k else np.zeros((height, width), dtype=bool)
        depth = np.where(on_wall, np.take_along_axis(np.broadcast_to(crossing_depth, (height, width, k)), first, 2)[..., 0]
                         if k else np.inf, np.inf)
        wall_of = np.where(on_wall, np.take_along_axis(np.broadcast_to(crossing_wall, (height, width, k)), first, 2)[..., 0]
                           if k else -1, -1)
        # below the horizon and short of every wall, the ray meets the ground (a square)
        with np.errstate(divide="ignore"):
            ground_depth = np.where(rise < 0, origin[2] / -rise, np.inf)[:, None]  # (H, 1)
        gx = origin[0] + ground_depth * dx[:, 0][None]
        gy = origin[1] + ground_depth * dy[:, 0][None]
        extent = self.ground_extent
        on_ground = ~on_wall & np.isfinite(ground_depth) & (np.abs(gx) <= extent) & (np.abs(gy) <= extent)
        depth = np.where(on_ground, ground_depth, depth)
        return depth, wall_of, on_ground

    def _pattern(self, *keys: np.ndarray) -> np.ndarray:
        """:func:`_hash01` of a surface pattern's cell keys (and of the world seed with ``own_patterns``)."""
        if self.own_patterns:
            keys = (np.full(np.broadcast(*keys).shape, self.seed, dtype=np.int64), *keys)
        return _hash01(*keys)

    def _sky(self, dirs: np.ndarray, lighting: Lighting) -> np.ndarray:
        elevation = dirs[..., 2] / np.sqrt(dirs[..., 0] * dirs[..., 0] + dirs[..., 1] * dirs[..., 1] + dirs[..., 2] * dirs[..., 2])
        blend = np.clip(elevation * 2.5, 0.0, 1.0)[..., None]
        return lighting.sky_horizon * (1 - blend) + lighting.sky_top * blend

    def _shade(self, albedo: np.ndarray, normals: np.ndarray, lighting: Lighting) -> np.ndarray:
        sun = lighting.sun  # an explicit sum, not a matrix product: BLAS rounds by the CPU
        diffuse = np.clip(normals[:, 0] * sun[0] + normals[:, 1] * sun[1] + normals[:, 2] * sun[2], 0.0, 1.0)[:, None]
        return albedo * (lighting.ambient_rgb + diffuse * lighting.sun_rgb)

    def _facade_colour(self, points: np.ndarray, walls: np.ndarray, lighting: Lighting) -> np.ndarray:
        f = self.facades
        b = self.wall_building[walls]
        normals = self.wall_normal[walls]
        # facade coordinate, continuous across the walls of a building
        a, axis = self.wall_a[walls], self.wall_axis[walls]
        s = self.wall_s0[walls] + ((points[:, 0] - a[:, 0]) * axis[:, 0] + (points[:, 1] - a[:, 1]) * axis[:, 1])
        z = points[:, 2]
        albedo = f.wall_rgb[b].copy()
        # brick-like noise: 0.25 x 0.12 m cells
        cell = self._pattern(b, np.floor(s / 0.25 + 0.5 * (np.floor(z / 0.12) % 2)), np.floor(z / 0.12))
        albedo *= (1.0 - f.brick[b] + 2 * f.brick[b] * cell)[:, None]
        # horizontal stripes between storeys
        stripe = (f.stripes[b] > 0) & (np.mod(z - _SHOP_HEIGHT, _STOREY) < 0.18 * f.stripes[b]) & (z > _SHOP_HEIGHT)
        albedo[stripe] = f.trim_rgb[b[stripe]]
        # windows on the upper storeys
        spacing = f.window_spacing[b]
        u = np.mod(s, spacing) / spacing
        w = np.mod(z - _SHOP_HEIGHT, _STOREY) / _STOREY
        window = (z > _SHOP_HEIGHT + 0.3) & (u > 0.5 - f.window_width[b] / 2) & (u < 0.5 + f.window_width[b] / 2)
        window &= (w > 0.25) & (w < 0.25 + f.window_height[b])
        window_id = self._pattern(b, np.floor(s / spacing), np.floor((z - _SHOP_HEIGHT) / _STOREY))
        glass = np.array([0.16, 0.2, 0.26]) + 0.18 * window_id[:, None]
        albedo[window] = glass[window]
        # shop front: a coloured band with a big display window and a sign above it
        shop = z < _SHOP_HEIGHT
        albedo[shop] = f.shop_rgb[b[shop]] * (0.85 + 0.3 * cell[shop, None])
        display = shop & (z > 0.5) & (z < 2.6) & (np.mod(s, 4.0) > 0.6)
        albedo[display] = np.array([0.12, 0.14, 0.16]) + 0.25 * self._pattern(b[display], np.floor(s[display] / 4.0))[:, None]
        sign_pos = np.mod(s / 11.0 + f.sign_start[b], 1.0)
        sign = (z > 2.75) & (z < 3.4) & (sign_pos < f.sign_length[b])
        letters = self._pattern(b, np.floor(s * 3.0)) > 0.45
        albedo[sign] = np.where(letters[sign, None], f.sign_rgb[b[sign]], 1.0 - f.sign_rgb[b[sign]])
        colour = self._shade(albedo, normals, lighting)
        if lighting.window_lit_fraction > 0:
            lit = window & (window_id < lighting.window_lit_fraction)
            colour[lit] = np.array([1.0, 0.85, 0.55]) * (0.7 + 0.3 * window_id[lit, None])
            glow = sign & (lighting.window_lit_fraction > 0.3)
            colour[glow] = albedo[glow] * 0.9
        return colour

    def _ground_colour(self, points: np.ndarray, lighting: Lighting) -> np.ndarray:
        x, y = points[:, 0], points[:, 1]
        coarse = self._pattern(np.floor(x / 1.5), np.floor(y / 1.5))
        fine = self._pattern(np.floor(x / 0.2), np.floor(y / 0.2))
        grey = 0.25 + 0.08 * coarse + 0.06 * fine
        albedo = np.stack([grey, grey, grey * 1.02], axis=1)
        # manhole covers and patches make the road locally distinctive
        patch = self._pattern(np.floor(x / 4.0) + 7, np.floor(y / 4.0) - 3) > 0.93
        albedo[patch] *= 0.6
        up = np.tile([0.0, 0.0, 1.0], (len(points), 1))
        return self._shade(albedo, up, lighting)

    def _occlude(
        self, origin: np.ndarray, dirs: np.ndarray, depth: np.ndarray, colour: np.ndarray,
        occluders: np.ndarray, lighting: Lighting,
    ) -> tuple[np.ndarray, np.ndarray]:
        ox, oy, oz = origin
        dx, dy, dz = dirs[..., 0], dirs[..., 1], dirs[..., 2]
        a = dx * dx + dy * dy
        for cx_, cy_, radius, height, shade_seed in occluders:
            px, py = ox - cx_, oy - cy_
            b = 2 * (px * dx + py * dy)
            c = px * px + py * py - radius * radius
            disc = b * b - 4 * a * c
            ok = disc >= 0
            t = np.where(ok, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * np.maximum(a, 1e-12)), np.inf)
            z = oz + t * dz
            hit = ok & (t > 0.05) & (z >= 0) & (z <= height) & (t < depth)
            if not hit.any():
                continue
            nx = (px + t * dx)[hit] / radius
            ny = (py + t * dy)[hit] / radius
            normals = np.stack([nx, ny, np.zeros_like(nx)], axis=1)
            rgb = _hash01(np.array([int(shade_seed), int(shade_seed) + 1, int(shade_seed) + 2]))
            stripes = 0.75 + 0.25 * (np.mod(z[hit], 0.6) < 0.3)
            colour[hit] = self._shade(rgb[None, :] * stripes[:, None], normals, lighting)
            depth = np.where(hit, t, depth)
        return depth, colour


def occluders_at(seed: int, time_s: float, route: Route, count: int) -> np.ndarray:
    """(count, 5) moving cylinders at ``time_s``: they walk or drive along the street."""
    if count <= 0:
        return np.zeros((0, 5))
    rng = np.random.default_rng(seed + 7919)
    s0 = rng.uniform(0, route.length, count)
    speed = rng.choice([-1.4, 1.4, 8.0, -6.0], size=count) * rng.uniform(0.7, 1.3, count)
    lane = rng.uniform(-3.5, 3.5, count)
    radius = np.where(np.abs(speed) > 3, rng.uniform(0.8, 1.1, count), rng.uniform(0.25, 0.4, count))
    height = np.where(np.abs(speed) > 3, rng.uniform(1.4, 2.2, count), rng.uniform(1.6, 1.9, count))
    pos, head = route.at(s0 + speed * time_s)
    left = np.stack([-head[:, 1], head[:, 0]], axis=1)
    xy = pos + lane[:, None] * left
    return np.column_stack([xy, radius, height, np.arange(count) * 3 + seed % 1000])
