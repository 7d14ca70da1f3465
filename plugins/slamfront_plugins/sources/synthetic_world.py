"""A procedural street world rendered on the CPU with Open3D's ray caster.

The world is a closed street (a rounded rectangle) lined on both sides by buildings.
Every building gets its own facade, drawn from a seeded random generator: wall colour,
window grid, shop front, signs, brick-like noise. Side-street gaps in the outer row show
a second row of buildings further away. The camera drives along the street; a second
traversal of the same route can differ in illumination (day, dusk, night with lit
windows), viewpoint (a lateral offset and a yaw offset) and moving occluders (people
and vehicles as upright cylinders). Everything is a pure function of the world seed and the
frame's parameters, so frames are deterministic and can be rendered in any order.

World frame: x east, y north, z up, metres. Camera frame: OpenCV (x right, y down,
z forward). Poses are camera-to-world 4x4 matrices.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import open3d as o3d

Illumination = Literal["day", "dusk", "night"]

_WALL, _GROUND = 0, 1
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
    return v / np.linalg.norm(v)


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
        pos = np.zeros((len(s), 2))
        head = np.zeros((len(s), 2))
        offset = 0.0
        for leg, start, direction in zip(legs, starts, directions):
            on_leg = (s >= offset) & (s < offset + leg)
            t = s[on_leg] - offset
            pos[on_leg] = start + t[:, None] * direction
            head[on_leg] = direction
            offset += leg
            on_arc = (s >= offset) & (s < offset + quarter)
            angle0 = np.arctan2(direction[1], direction[0]) - np.pi / 2
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
    """The static scene: geometry in a ray-casting scene plus facade parameters.

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
        self._triangles: list[np.ndarray] = []
        self._tri_kind: list[int] = []
        self._tri_building: list[int] = []
        self._tri_origin: list[np.ndarray] = []
        self._tri_axis: list[np.ndarray] = []
        self._tri_s0: list[float] = []
        self._building_params: list[dict[str, np.ndarray | float]] = []
        self._build(rng)
        self.scene = o3d.t.geometry.RaycastingScene(nthreads=0)
        vertices = np.concatenate(self._triangles).astype(np.float32)
        faces = np.arange(len(vertices), dtype=np.uint32).reshape(-1, 3)
        self.scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(faces))
        self.tri_kind = np.array(self._tri_kind, dtype=np.int32)
        self.tri_building = np.array(self._tri_building, dtype=np.int64)
        self.tri_origin = np.array(self._tri_origin, dtype=np.float64)
        self.tri_axis = np.array(self._tri_axis, dtype=np.float64)
        self.tri_s0 = np.array(self._tri_s0, dtype=np.float64)
        self.facades = self._facades()

    # -- construction --------------------------------------------------------------------

    def _quad(self, a: np.ndarray, b: np.ndarray, z0: float, z1: float, building: int, s0: float) -> None:
        """A vertical rectangle from a to b (2-D points); ``s0`` is the facade coordinate at a."""
        p = [np.r_[a, z0], np.r_[b, z0], np.r_[b, z1], np.r_[a, z1]]
        axis = np.r_[(b - a) / np.linalg.norm(b - a), 0.0]
        for tri in ((p[0], p[1], p[2]), (p[0], p[2], p[3])):
            self._triangles.append(np.array(tri))
            self._tri_kind.append(_WALL)
            self._tri_building.append(building)
            self._tri_origin.append(p[0])
            self._tri_axis.append(axis)
            self._tri_s0.append(s0)

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
                if np.linalg.norm(b - a) > 1e-6:
                    self._quad(a, b, 0.0, height, building, s0)
            s = end

    def _ground(self, extent: float) -> None:
        corners = np.array([[-extent, -extent, 0.0], [extent, -extent, 0.0], [extent, extent, 0.0], [-extent, extent, 0.0]])
        for tri in ((corners[0], corners[1], corners[2]), (corners[0], corners[2], corners[3])):
            self._triangles.append(np.array(tri))
            self._tri_kind.append(_GROUND)
            self._tri_building.append(-1)
            self._tri_origin.append(np.zeros(3))
            self._tri_axis.append(np.array([1.0, 0.0, 0.0]))
            self._tri_s0.append(0.0)

    def _build(self, rng: np.random.Generator) -> None:
        half = self.street_width / 2
        self._row(rng, -half, outer=True)  # right of travel (counter-clockwise route: outside)
        self._row(rng, +half, outer=False)
        self._ground(max(self.route.width, self.route.height))

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

        :param occluders: (K, 5) upright cylinders ``x, y, radius, height, colour seed``.
        """
        fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        cam_dirs = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1)
        rotation, origin = pose[:3, :3], pose[:3, 3]
        dirs = cam_dirs @ rotation.T  # z-component 1 in the camera: t_hit is depth
        rays = np.concatenate([np.broadcast_to(origin, dirs.shape), dirs], axis=-1).astype(np.float32)
        hit = self.scene.cast_rays(o3d.core.Tensor(rays))
        t = hit["t_hit"].numpy().astype(np.float64)
        prim = hit["primitive_ids"].numpy().astype(np.int64)
        normals = hit["primitive_normals"].numpy().astype(np.float64)
        valid = np.isfinite(t)
        prim = np.where(valid, prim, 0)
        points = origin + dirs * np.where(valid, t, 0.0)[..., None]
        colour = self._sky(dirs, lighting)

        kind = np.where(valid, self.tri_kind[prim], -1)
        wall = kind == _WALL
        ground = kind == _GROUND
        if wall.any():
            colour[wall] = self._facade_colour(points[wall], prim[wall], normals[wall], lighting)
        if ground.any():
            colour[ground] = self._ground_colour(points[ground], lighting)

        depth = np.where(valid, t, np.inf)
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

    def _pattern(self, *keys: np.ndarray) -> np.ndarray:
        """:func:`_hash01` of a surface pattern's cell keys (and of the world seed with ``own_patterns``)."""
        if self.own_patterns:
            keys = (np.full(np.broadcast(*keys).shape, self.seed, dtype=np.int64), *keys)
        return _hash01(*keys)

    def _sky(self, dirs: np.ndarray, lighting: Lighting) -> np.ndarray:
        elevation = dirs[..., 2] / np.linalg.norm(dirs, axis=-1)
        blend = np.clip(elevation * 2.5, 0.0, 1.0)[..., None]
        return lighting.sky_horizon * (1 - blend) + lighting.sky_top * blend

    def _shade(self, albedo: np.ndarray, normals: np.ndarray, lighting: Lighting) -> np.ndarray:
        diffuse = np.clip(normals @ lighting.sun, 0.0, 1.0)[:, None]
        return albedo * (lighting.ambient_rgb + diffuse * lighting.sun_rgb)

    def _facade_colour(self, points: np.ndarray, prim: np.ndarray, normals: np.ndarray, lighting: Lighting) -> np.ndarray:
        f = self.facades
        b = self.tri_building[prim]
        # facade coordinate, continuous across the quads of a building
        s = self.tri_s0[prim] + np.einsum("ij,ij->i", points - self.tri_origin[prim], self.tri_axis[prim])
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
