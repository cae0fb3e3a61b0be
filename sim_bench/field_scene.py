"""Synthetic field scenes and the arm-camera renderer.

Model: the field is flat (z = 0). Its appearance is an orthographic ground texture built on
demand in 256×256 tiles at a level of detail of 0.5·2^l mm per pixel (soil noise, stones, straw,
dead leaves, plants with their own soft shadows, large cast shadows), all defined in field
coordinates. `render` chooses the level from the finest ground sampling distance of the view,
assembles the tiles covering the footprint R^FoV_w and warps the mosaic into the image with the
composed homography H(x_e)·A (A: mosaic pixel → field point), so a ground point X appears at
exactly `PinholeCamera.ground_to_pixel(T, X)`. Lighting (exposure, white balance, vignetting),
defocus/motion blur, sensor noise and JPEG are applied in image space, seeded by the scene seed
and the pose, so `render` is a pure function of (scene, pose, camera).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

import cv2
import numpy as np

from capm_field.camera import PinholeCamera

from .noise import hash_u01
from .plants import WEED_KINDS, Plant, make_plant
from .soil import CELL, SoilStyle, cell_objects, draw_parts, ground_fields, soft_polygon_alpha

BASE_RES = 0.0005  # m per texture pixel at level 0
TILE = 256
MAX_LEVEL = 7
MAX_MOSAIC_PX = 4_500_000
MAX_RANGE = 8.0  # m: ground beyond this (horizontal) distance from the camera is haze
SKY_BGR = (235, 215, 200)


@dataclass(frozen=True)
class Lighting:
    exposure: float = 1.0
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)  # BGR gains
    sun: tuple[float, float] = (0.3, 0.2)  # ground shadow offset per metre of height
    vignette: float = 0.15
    blur_sigma: float = 0.0  # px, defocus
    motion_px: float = 0.0  # px, motion blur length
    noise_sigma: float = 2.0  # DN at mid grey
    jpeg_quality: int | None = None

    @staticmethod
    def random(rng: np.random.Generator) -> "Lighting":
        sun_ang = rng.uniform(0, 2 * np.pi)
        slope = rng.uniform(0.1, 1.5)
        return Lighting(
            exposure=float(rng.uniform(0.6, 1.35)),
            white_balance=tuple(float(v) for v in np.r_[rng.uniform(0.85, 1.18), 1.0, rng.uniform(0.85, 1.18)]),
            sun=(slope * math.cos(sun_ang), slope * math.sin(sun_ang)),
            vignette=float(rng.uniform(0, 0.35)),
            blur_sigma=float(rng.choice([0.0, rng.uniform(0.3, 1.8)])),
            motion_px=float(rng.choice([0.0, 0.0, 0.0, rng.uniform(1, 5)])),
            noise_sigma=float(rng.uniform(0.5, 6.0)),
            jpeg_quality=None if rng.random() < 0.6 else int(rng.integers(60, 95)),
        )


@dataclass(frozen=True)
class Weed:
    """A weed with its true biological centre (MPOI X̄_w) and the prescan TROI (X_w, r_w)."""

    kind: str
    centre: np.ndarray
    troi_centre: np.ndarray
    troi_radius: float
    plant: Plant


@dataclass(frozen=True)
class CastShadow:
    """A large soft shadow on the ground (robot, arm, crop canopy), convex polygon in field metres."""

    polygon: np.ndarray
    softness: float = 0.02
    strength: float = 0.5


@dataclass
class FieldScene:
    seed: int
    soil: SoilStyle
    lighting: Lighting
    weeds: list[Weed]
    plants: list[Plant]  # every plant drawn, weeds' plants included, in painter's order
    shadows: list[CastShadow] = field(default_factory=list)
    _tiles: OrderedDict = field(default_factory=OrderedDict, repr=False)
    _index: dict = field(default_factory=dict, repr=False)
    cache_tiles: int = 400

    # ---- construction ----------------------------------------------------------------------
    @classmethod
    def generate(
        cls,
        seed: int,
        weeds: list | None = None,
        count: int = 0,
        area: tuple[float, float, float, float] = (0.0, 0.0, 3.0, 3.0),
        kinds: tuple[str, ...] = WEED_KINDS,
        troi_radius: tuple[float, float] = (0.2, 0.3),
        crop_rows: bool = False,
        row_spacing: float = 0.75,
        distractors_per_m2: float = 0.0,
        shadows: int = 0,
        clutter: bool = True,
        lighting: Lighting | None = None,
        soil: SoilStyle | None = None,
        clear_zones: list[tuple[np.ndarray, float]] = (),
    ) -> "FieldScene":
        """A deterministic scene from `seed`.

        weeds: explicit list of (x, y, kind) / (x, y, kind, size) tuples or dicts with keys
        x, y, kind and optional size, troi_centre, troi_radius; otherwise `count` weeds of `kinds`
        are placed at random in `area` (x0, y0, x1, y1). The TROI of a weed defaults to the
        plant's area centroid (what a low-resolution prescan sees) with radius r_w drawn from
        `troi_radius` and grown if needed so the TROI holds the whole plant. `count=0` and no
        `weeds` gives a bare-soil scene. Crop plants stay out of every TROI and of `clear_zones`
        ((centre, radius) discs), as a prescan would not put a TROI on a crop.
        """
        rng = np.random.default_rng(seed)
        soil = soil or SoilStyle.random(rng)
        if not clutter:
            soil = SoilStyle(soil.colour_a, soil.colour_b, soil.moisture, soil.clod, 0.0, 0.0, 0.0)
        lighting = lighting or Lighting.random(rng)
        specs = []
        for w in weeds or []:
            if isinstance(w, dict):
                specs.append(dict(w))
            else:
                specs.append(dict(x=w[0], y=w[1], kind=w[2], size=w[3] if len(w) > 3 else None))
        x0, y0, x1, y1 = area
        placed = [np.array([s["x"], s["y"]], float) for s in specs]
        for _ in range(count):
            for _try in range(50):
                p = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1)])
                if all(np.linalg.norm(p - q) > 0.3 for q in placed):
                    break
            placed.append(p)
            specs.append(dict(x=p[0], y=p[1], kind=str(rng.choice(kinds)), size=None))
        out_weeds = []
        weed_plants: list[Plant] = []
        for s in specs:
            plant = make_plant(s["kind"], rng, (s["x"], s["y"]), s.get("size"))
            tc = s.get("troi_centre")
            tc = plant.area_centroid() + rng.normal(0, 0.1 * plant.extent, 2) if tc is None else np.asarray(tc, float)
            r = s.get("troi_radius")
            if r is None:
                r = max(rng.uniform(*troi_radius), float(np.max(np.linalg.norm(np.concatenate([p.poly for p in plant.parts]) - tc, axis=1))) * 1.05)
            weed_plants.append(plant)
            out_weeds.append(Weed(plant.kind, plant.centre, tc, float(r), plant))
        plants: list[Plant] = []
        if crop_rows:
            ang = rng.uniform(0, np.pi)
            d = np.array([math.cos(ang), math.sin(ang)])
            n = np.array([-d[1], d[0]])
            off = rng.uniform(0, row_spacing)
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            span = math.hypot(x1 - x0, y1 - y0) / 2 + 0.5
            for k in range(-int(span / row_spacing) - 1, int(span / row_spacing) + 2):
                for s in np.arange(-span, span, rng.uniform(0.15, 0.3)):
                    c = np.array([cx, cy]) + n * (k * row_spacing + off) + d * (s + rng.uniform(-0.03, 0.03))
                    p = make_plant("crop", rng, c)
                    # a prescan would not put a TROI on a crop plant: keep crops out of every TROI
                    zones = [(w.troi_centre, w.troi_radius) for w in out_weeds] + list(clear_zones)
                    clear = all(np.linalg.norm(c - np.asarray(z)) > r + p.extent + 0.02 for z, r in zones)
                    if clear and x0 - 0.5 < c[0] < x1 + 0.5 and y0 - 0.5 < c[1] < y1 + 0.5:
                        plants.append(p)
        for _ in range(rng.poisson(distractors_per_m2 * (x1 - x0) * (y1 - y0))):
            c = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1)])
            plants.append(make_plant("seedling", rng, c, rng.uniform(0.004, 0.012)))
        plants += weed_plants  # weeds drawn last (on top)
        cast = []
        for _ in range(shadows):
            c = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1)])
            k = int(rng.integers(3, 7))
            ang = np.sort(rng.uniform(0, 2 * np.pi, k))
            R = rng.uniform(0.1, 0.6)
            cast.append(CastShadow(c + R * np.c_[np.cos(ang), np.sin(ang)], rng.uniform(0.005, 0.05), rng.uniform(0.3, 0.65)))
        return cls(seed, soil, lighting, out_weeds, plants, cast)

    @classmethod
    def bare(cls, seed: int, **kw) -> "FieldScene":
        """A scene with soil, stones and residue but no plants."""
        kw.setdefault("count", 0)
        return cls.generate(seed, weeds=[], **kw)

    # ---- texture tiles ---------------------------------------------------------------------
    def tile(self, level: int, ix: int, iy: int) -> np.ndarray:
        """Ground texture tile (TILE×TILE×3 uint8, BGR). Row index grows with field y."""
        key = (level, ix, iy)
        t = self._tiles.get(key)
        if t is not None:
            self._tiles.move_to_end(key)
            return t
        t = self._make_tile(level, ix, iy)
        self._tiles[key] = t
        while len(self._tiles) > self.cache_tiles:
            self._tiles.popitem(last=False)
        return t

    def _plant_index(self) -> dict:
        if not self._index:
            idx: dict = {}
            for i, p in enumerate(self.plants):
                x0, y0, x1, y1 = p.bbox
                m = 0.05  # shadow margin
                for cx in range(math.floor((x0 - m) / CELL), math.floor((x1 + m) / CELL) + 1):
                    for cy in range(math.floor((y0 - m) / CELL), math.floor((y1 + m) / CELL) + 1):
                        idx.setdefault((cx, cy), []).append(i)
            self._index.update(idx)
        return self._index

    def _make_tile(self, level: int, ix: int, iy: int) -> np.ndarray:
        res = BASE_RES * 2**level
        S = TILE * res
        X0, Y0 = ix * S, iy * S
        xs = X0 + (np.arange(TILE) + 0.5) * res
        ys = Y0 + (np.arange(TILE) + 0.5) * res
        img, tex = ground_fields(self.seed, self.soil, xs, ys, res)
        sun = np.asarray(self.lighting.sun, float)
        m = 0.08  # largest object reach beyond its cell
        cells = [
            (cx, cy)
            for cx in range(math.floor((X0 - m) / CELL), math.floor((X0 + S + m) / CELL) + 1)
            for cy in range(math.floor((Y0 - m) / CELL), math.floor((Y0 + S + m) / CELL) + 1)
        ]
        objs = [p for c in sorted(cells) for p in cell_objects(self.seed, self.soil, *c)]
        draw_parts(img, X0, Y0, res, objs, sun, tex)
        idx = self._plant_index()
        ids = sorted({i for c in cells for i in idx.get(c, ())})
        for i in ids:
            draw_parts(img, X0, Y0, res, self.plants[i].parts, sun, tex)
        for sh in self.shadows:
            P = np.asarray(sh.polygon, float)
            reach = 0.5 * sh.softness + res
            if P[:, 0].max() + reach < X0 or P[:, 0].min() - reach > X0 + S or P[:, 1].max() + reach < Y0 or P[:, 1].min() - reach > Y0 + S:
                continue
            a = soft_polygon_alpha(P, sh.softness, xs, ys)
            if a.any():
                img *= (1 - sh.strength * a)[..., None] * np.float32([1.08, 1.0, 0.94])
        return np.clip(img, 0, 255).astype(np.uint8)

    # ---- rendering ---------------------------------------------------------------------------
    def render(self, T_field_cam: np.ndarray, camera: PinholeCamera) -> np.ndarray:
        return render(self, T_field_cam, camera)


def _ground_points(camera: PinholeCamera, T: np.ndarray, uv: np.ndarray) -> np.ndarray:
    return camera.pixel_to_ground(T, uv)


def choose_level(camera: PinholeCamera, T: np.ndarray) -> tuple[int, np.ndarray] | None:
    """Texture level and the field bbox (x0, y0, x1, y1) of the visible ground, or None if none."""
    w, h = camera.width, camera.height
    gu, gv = np.meshgrid(np.linspace(-0.5, w - 0.5, 9), np.linspace(-0.5, h - 0.5, 7))
    uv = np.c_[gu.ravel(), gv.ravel()]
    g0 = _ground_points(camera, T, uv)
    gx = _ground_points(camera, T, uv + [1.0, 0.0])
    gy = _ground_points(camera, T, uv + [0.0, 1.0])
    cpos = T[:2, 3]
    ok = np.isfinite(g0).all(1) & np.isfinite(gx).all(1) & np.isfinite(gy).all(1)
    ok &= np.linalg.norm(g0 - cpos, axis=1) < MAX_RANGE
    if not ok.any():
        return None
    ex, ey = gx - g0, gy - g0
    gsd = np.sqrt(np.abs(ex[:, 0] * ey[:, 1] - ex[:, 1] * ey[:, 0]))[ok]
    level = int(np.clip(math.floor(math.log2(max(gsd.min(), 1e-9) / BASE_RES) + 0.3), 0, MAX_LEVEL))
    # bbox: sample the border densely; clip rays beyond MAX_RANGE
    pts = camera.footprint(T, max_range=MAX_RANGE * 1.5)
    d = pts - cpos
    n = np.linalg.norm(d, axis=1, keepdims=True)
    pts = cpos + d * np.minimum(1.0, MAX_RANGE / np.maximum(n, 1e-9))
    return level, np.r_[pts.min(0), pts.max(0)]


def _needed_tiles(camera: PinholeCamera, T: np.ndarray, level: int, i0: int, j0: int, ni: int, nj: int) -> np.ndarray:
    """(nj, ni) bool: the tiles of the mosaic that the warp will actually sample.

    Image pixels on an 8-px grid (plus the far borders) are mapped to texels through H⁻¹; every
    tile within the local grid spacing (+2 texels for the bilinear footprint) of one is needed.
    The other tiles (outside the view but inside the footprint's bounding box) are never built.
    Views reaching the horizon build every tile.
    """
    res = BASE_RES * 2**level
    w, h = camera.width, camera.height
    us = np.r_[np.arange(-0.5, w - 0.5, 8.0), w - 0.5]
    vs = np.r_[np.arange(-0.5, h - 0.5, 8.0), h - 0.5]
    uu, vv = np.meshgrid(us, vs)
    g = camera.pixel_to_ground(T, np.c_[uu.ravel(), vv.ravel()]).reshape(len(vs), len(us), 2)
    P = g / res - 0.5  # global texel coordinates
    if not np.isfinite(P).all():
        return np.ones((nj, ni), bool)
    d = np.zeros(P.shape[:2])
    dx = np.linalg.norm(np.diff(P, axis=1), axis=2)
    dy = np.linalg.norm(np.diff(P, axis=0), axis=2)
    d[:, :-1] = np.maximum(d[:, :-1], dx)
    d[:, 1:] = np.maximum(d[:, 1:], dx)
    d[:-1, :] = np.maximum(d[:-1, :], dy)
    d[1:, :] = np.maximum(d[1:, :], dy)
    if d.max() >= TILE / 2:
        return np.ones((nj, ni), bool)
    P, m = P.reshape(-1, 2), d.ravel() + 2.0
    need = np.zeros((nj, ni), bool)
    for sx in (-1, 1):
        for sy in (-1, 1):
            ti = np.floor((P[:, 0] + sx * m) / TILE).astype(np.int64) - i0
            tj = np.floor((P[:, 1] + sy * m) / TILE).astype(np.int64) - j0
            sel = (ti >= 0) & (ti < ni) & (tj >= 0) & (tj < nj)
            need[tj[sel], ti[sel]] = True
    return need


def _mosaic(scene: FieldScene, level: int, bbox: np.ndarray, need: np.ndarray | None = None, fill=(0, 0, 0)) -> tuple[np.ndarray, np.ndarray]:
    """Tiles under `bbox` at `level` as one image (tiles not in `need` are filled with `fill`)."""
    res = BASE_RES * 2**level
    S = TILE * res
    i0, j0 = math.floor(bbox[0] / S), math.floor(bbox[1] / S)
    i1, j1 = math.floor(bbox[2] / S), math.floor(bbox[3] / S)
    M = np.empty(((j1 - j0 + 1) * TILE, (i1 - i0 + 1) * TILE, 3), np.uint8)
    for j in range(j0, j1 + 1):
        for i in range(i0, i1 + 1):
            blk = M[(j - j0) * TILE : (j - j0 + 1) * TILE, (i - i0) * TILE : (i - i0 + 1) * TILE]
            if need is None or need[j - j0, i - i0]:
                blk[:] = scene.tile(level, i, j)
            else:
                blk[:] = fill
    # mosaic pixel (col, row) → field point, pixel centres at integers
    A = np.array([[res, 0, i0 * S + 0.5 * res], [0, res, j0 * S + 0.5 * res], [0, 0, 1.0]])
    return M, A


def render(scene: FieldScene, T_field_cam: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """The BGR uint8 image (h, w, 3) the camera at T_field_cam sees; ground geometry exact w.r.t. H."""
    T = np.asarray(T_field_cam, float)
    w, h = camera.width, camera.height
    sel = choose_level(camera, T) if T[2, 3] > 1e-4 else None
    if sel is None:
        img = np.empty((h, w, 3), np.uint8)
        img[:] = SKY_BGR if T[2, 3] > 0 else (20, 20, 20)
        return img
    level, bbox = sel
    while True:
        res = BASE_RES * 2**level
        npx = (bbox[2] - bbox[0] + 2 * TILE * res) * (bbox[3] - bbox[1] + 2 * TILE * res) / res**2
        if npx <= MAX_MOSAIC_PX or level >= MAX_LEVEL:
            break
        level += 1
    haze = np.asarray(scene.soil.colour_a, float) * 0.5 + np.asarray(scene.soil.colour_b, float) * 0.5
    S = TILE * BASE_RES * 2**level
    i0, j0 = math.floor(bbox[0] / S), math.floor(bbox[1] / S)
    ni, nj = math.floor(bbox[2] / S) - i0 + 1, math.floor(bbox[3] / S) - j0 + 1
    need = _needed_tiles(camera, T, level, i0, j0, ni, nj)
    M, A = _mosaic(scene, level, bbox, need, tuple(int(v) for v in np.clip(haze, 0, 255)))
    Himg = camera.homography(T) @ A
    border = tuple(float(v) for v in haze)
    Rz = (T[:3, :3] @ np.linalg.inv(camera.K))[2]
    if camera.distorted:
        # each raw pixel samples the mosaic where the ideal pinhole camera sees its ray
        iu, iv = _ideal_grid(camera)
        Hi = np.linalg.inv(Himg)
        den = Hi[2, 0] * iu + Hi[2, 1] * iv + Hi[2, 2]
        mx = ((Hi[0, 0] * iu + Hi[0, 1] * iv + Hi[0, 2]) / den).astype(np.float32)
        my = ((Hi[1, 0] * iu + Hi[1, 1] * iv + Hi[1, 2]) / den).astype(np.float32)
        img = cv2.remap(M, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=border)
        img[(Rz[0] * iu + Rz[1] * iv + Rz[2]) > -1e-3] = SKY_BGR
        return _camera_effects(scene, T, img)
    img = cv2.warpPerspective(M, Himg, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=border)
    # rays that miss the ground (above the horizon) see sky
    if max(Rz[0] * u + Rz[1] * v + Rz[2] for u in (-0.5, w - 0.5) for v in (-0.5, h - 0.5)) > -1e-9:
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        img[(Rz[0] * uu + Rz[1] * vv + Rz[2]) > -1e-3] = SKY_BGR
    return _camera_effects(scene, T, img)


_IDEAL: dict = {}


def _ideal_grid(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of the ideal pinhole image seen by each raw pixel of a distorting camera (h, w each; cached)."""
    key = (camera.width, camera.height, camera.K.tobytes(), np.asarray(camera.dist, float).tobytes())
    if key not in _IDEAL:
        uu, vv = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
        ideal = camera.lens.undistort(np.c_[uu.ravel(), vv.ravel()])
        _IDEAL.clear()
        _IDEAL[key] = (ideal[:, 0].reshape(uu.shape), ideal[:, 1].reshape(uu.shape))
    return _IDEAL[key]


def _camera_effects(scene: FieldScene, T: np.ndarray, img: np.ndarray) -> np.ndarray:
    L = scene.lighting
    h, w = img.shape[:2]
    key = np.frombuffer(np.round(T[:3, :], 6).tobytes(), np.uint32)
    fseed = int(hash_u01(scene.seed, 77, int(key.sum() & 0x7FFFFFFF), int(key[::3].sum() & 0x7FFFFFFF)) * 2**31)
    rng = np.random.default_rng([scene.seed & 0xFFFFFFFF, fseed])
    gains = L.exposure * rng.uniform(0.93, 1.07) * np.asarray(L.white_balance)
    f = img.astype(np.float32)
    if L.vignette > 0:
        f = cv2.multiply(f, _vignette(w, h, L.vignette), scale=1.0)
    f = cv2.multiply(f, tuple(float(g) for g in gains) + (0.0,))
    if L.blur_sigma > 0.25:
        f = cv2.GaussianBlur(f, (0, 0), L.blur_sigma)
    if L.motion_px >= 1:
        k = np.zeros((int(L.motion_px) | 1, int(L.motion_px) | 1), np.float32)
        k[k.shape[0] // 2, :] = 1
        R = cv2.getRotationMatrix2D(((k.shape[1] - 1) / 2, (k.shape[0] - 1) / 2), float(rng.uniform(0, 180)), 1.0)
        k = cv2.warpAffine(k, R, k.shape[::-1])
        f = cv2.filter2D(f, -1, k / max(k.sum(), 1e-6))
    if L.noise_sigma > 0:
        # shot + read noise; the pattern is a random crop of a cached normal field (cheap)
        n = _noise_field(h, w)
        dy, dx = rng.integers(0, 64, 2)
        n = n[dy : dy + h, dx : dx + w]
        sd = cv2.sqrt(cv2.max(f, 0.0) * np.float32(1 / 128) + np.float32(0.15))
        f += cv2.multiply(n, sd, scale=float(L.noise_sigma) * (1 if rng.random() < 0.5 else -1))
    out = np.clip(f, 0, 255).astype(np.uint8)
    if L.jpeg_quality:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(L.jpeg_quality)])
        if ok:
            out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return out


_VIG: dict = {}
_NOISE: dict = {}


def _noise_field(h: int, w: int) -> np.ndarray:
    if (h, w) not in _NOISE:
        _NOISE.clear()
        _NOISE[(h, w)] = np.random.default_rng(12345).standard_normal((h + 64, w + 64, 3), dtype=np.float32)
    return _NOISE[(h, w)]


def _vignette(w: int, h: int, k: float) -> np.ndarray:
    key = (w, h, round(k, 3))
    if key not in _VIG:
        x = (np.arange(w, dtype=np.float32) - (w - 1) / 2) / (w / 2)
        y = (np.arange(h, dtype=np.float32) - (h - 1) / 2) / (w / 2)
        _VIG.clear()
        v = 1 - k * (x[None, :] ** 2 + y[:, None] ** 2) / 1.3
        _VIG[key] = cv2.merge([v, v, v])
    return _VIG[key]
