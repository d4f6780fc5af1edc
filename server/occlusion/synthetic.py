"""A synthetic site-camera video with exact ground truth, for tests, benchmarks and the kiosk
replays.

The site: a textured paved ground ``y = 0`` (tiles, joints, a lawn), a row of buildings and
trees on a backdrop far away, the sky. People are flat, articulated figures (capsules for head,
torso, arms, legs and shoes) standing upright on the ground, each in the vertical plane through
their feet that faces the camera, so their image size and position are perspective-exact; they
walk along straight lines, swing legs and arms, and may stand still for a while.

Light (``light_model = "broadband"``, the default) is drawn with a camera model other than the
detector's (server/occlusion/spectralcamera.py): broadband RGB sensitivities integrate
daylight spectra over 380-720 nm, and surfaces have smooth reflectance spectra (their RGB
coefficients on a partition of unity), so the camera sees ``M @ a`` with a full 3x3 matrix
``M`` per illuminant. The sky changes from ``sky_states[0]`` to ``sky_states[1]`` (clear, hazy,
thin cloud: the sun through Rayleigh and aerosol scattering, the skylight what they scatter)
while the daylight dims by ``brightness``:

- sunlit surfaces: the sun's beam on the ground plus the skylight;
- a person's cast shadow on the ground: the skylight alone (the direct component lost), so
  the shadow's darkening and colour follow from the spectra, not from the detector's formula;
- the camera's colour correction (white balance included) is fixed, calibrated for sunlit
  surfaces under the first sky (there a surface shows its coefficients exactly; under any
  other light a full 3x3 mix of them).

``light_model = "narrowband"`` draws the sequence as it was before 2026-11-25, with the
F-value's own model (Kakuta Eq. 11): a narrow-band camera at ``wavelengths_nm`` under Wien
illuminants, sunlit at ``t_lit_k``, shadows ``shadow_fraction`` of it at ``t_sky_k``. It is
kept only to compare the detector on both (benchmarks/bench_occlusion.py ``--synthetic``).

A pixel's linear value is then scaled by ``exposure``, clipped, encoded with the sRGB curve,
plus Gaussian sensor noise in codes, rounded to uint8 BGR. The shadow geometry is exact: a
ground point is shadowed when the ray from it toward the sun meets a person's figure.

Ground truth per frame (:class:`TruthFrame`): the person index image, the cast-shadow mask
(shadowed ground not hidden by a person), and per person the foot point, its depth along the
optical axis, and the foot's image point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from server.occlusion import spectralcamera as spectral
from server.occlusion.depth import PerspectiveCamera
from server.occlusion.walkers import Walker, inside_figure, pixel_box

C2_M_K = 1.4388e-2  # second radiation constant, m K


def wien_rgb(temperature_k: float, wavelengths_nm=(610.0, 540.0, 465.0)) -> np.ndarray:
    """(3,) RGB relative radiance of a Planckian illuminant under Wien's approximation at the
    camera's three wavelengths, normalised to G = 1."""
    lam = np.asarray(wavelengths_nm, dtype=np.float64) * 1e-9
    e = lam**-5.0 * np.exp(-C2_M_K / (lam * temperature_k))
    return e / e[1]


def make_camera(width: int, height: int, hfov_deg: float = 60.0, height_m: float = 2.6,
                pitch_deg: float = -9.0, yaw_deg: float = 0.0) -> PerspectiveCamera:
    """A site camera at ``(0, height_m, 0)`` looking north (-Z), pitched down by ``-pitch_deg``,
    turned ``yaw_deg`` toward the east. Square pixels, principal point at the image centre."""
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2.0)
    K = [[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]]
    p = math.radians(pitch_deg)
    z = np.array([0.0, math.sin(p), -math.cos(p)])
    x = np.array([1.0, 0.0, 0.0])
    y = np.cross(z, x)
    yaw = math.radians(yaw_deg)
    Ry = np.array([[math.cos(yaw), 0, -math.sin(yaw)], [0, 1, 0], [math.sin(yaw), 0,
                                                                    math.cos(yaw)]])
    M = np.eye(4)
    M[:3, :3] = Ry @ np.stack([x, y, z], axis=1)
    M[:3, 3] = [0.0, height_m, 0.0]
    return PerspectiveCamera(K, M, width, height)


def box_depth_image(camera: PerspectiveCamera, box_min_m, box_max_m) -> np.ndarray:
    """(H, W) float32 depth along the optical axis of an axis-aligned box, +inf off the box.

    A stand-in for a baked view's ``depth`` image: a virtual building as a box.
    """
    H, W = camera.height, camera.width
    v, u = np.mgrid[0:H, 0:W]
    d = camera.ray_directions(u.ravel() + 0.5, v.ravel() + 0.5)
    o = camera.origin_m
    lo, hi = np.asarray(box_min_m, float), np.asarray(box_max_m, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o) / d
        t2 = (hi - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (tmax >= tmin) & (tmax > 0)
    depth = np.where(hit, np.maximum(tmin, 0.0), np.inf)
    return depth.reshape(H, W).astype(np.float32)


# ------------------------------------------------------------------------------------ people


# ------------------------------------------------------------------------------------- truth


@dataclass
class TruthPerson:
    """Ground truth of one visible person in one frame (depth along the optical axis)."""

    index: int
    foot_world_m: tuple[float, float, float]
    depth_m: float
    foot_px: tuple[float, float]
    visible_px: int
    standing: bool


@dataclass
class TruthFrame:
    """One synthetic frame and its ground truth.

    Attributes
    ----------
    image : (H, W, 3) uint8 BGR
    person_index : (H, W) int16, index of the walker seen at each pixel, -1 for none
    shadow : (H, W) bool, cast shadow of a person on visible ground
    people : visible people, nearest last
    time_s : frame time
    """

    image: np.ndarray
    person_index: np.ndarray
    shadow: np.ndarray
    people: list[TruthPerson]
    time_s: float

    @property
    def person(self) -> np.ndarray:
        return self.person_index >= 0

    def in_front(self, virtual_depth_m: np.ndarray) -> np.ndarray:
        """(H, W) bool: person pixels nearer than the virtual surface (the ideal mask)."""
        depth = np.full(self.person_index.shape, np.inf, dtype=np.float32)
        for p in self.people:
            depth[self.person_index == p.index] = p.depth_m
        return self.person & (depth < virtual_depth_m)


# -------------------------------------------------------------------------------------- site


def _hash01(ix: np.ndarray, iz: np.ndarray, salt: int) -> np.ndarray:
    """A repeatable pseudo-random number in [0, 1) per integer cell."""
    h = (ix.astype(np.int64) * 73856093) ^ (iz.astype(np.int64) * 19349663) ^ (salt * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFF).astype(np.float64) / 65536.0


def _value_noise(x: np.ndarray, z: np.ndarray, cell_m: float, salt: int) -> np.ndarray:
    """Smooth noise in [0, 1): bilinear interpolation of per-cell random values."""
    gx, gz = x / cell_m, z / cell_m
    ix, iz = np.floor(gx), np.floor(gz)
    fx, fz = gx - ix, gz - iz
    fx, fz = fx * fx * (3 - 2 * fx), fz * fz * (3 - 2 * fz)
    v00, v10 = _hash01(ix, iz, salt), _hash01(ix + 1, iz, salt)
    v01, v11 = _hash01(ix, iz + 1, salt), _hash01(ix + 1, iz + 1, salt)
    return (v00 * (1 - fx) + v10 * fx) * (1 - fz) + (v01 * (1 - fx) + v11 * fx) * fz


def ground_reflectance(x_m: np.ndarray, z_m: np.ndarray) -> np.ndarray:
    """(..., 3) RGB reflectance of the site's ground at (x, z): paving of 0.8 m tiles with
    darker joints and a lawn to the west."""
    tile = 0.8
    ix, iz = np.floor(x_m / tile), np.floor(z_m / tile)
    jitter = 0.8 + 0.4 * _hash01(ix, iz, 1)
    warm = 0.9 + 0.2 * _hash01(ix, iz, 2)
    fx, fz = x_m / tile - ix, z_m / tile - iz
    joint = (np.minimum(fx, 1 - fx) < 0.03) | (np.minimum(fz, 1 - fz) < 0.03)
    grain = 0.88 + 0.24 * _value_noise(x_m, z_m, 0.12, 3)
    base = np.stack([0.36 * warm, 0.33 * np.ones_like(warm), 0.28 / warm], axis=-1)
    paving = base * (jitter * grain * np.where(joint, 0.55, 1.0))[..., None]
    lawn_n = 0.75 + 0.5 * _value_noise(x_m, z_m, 0.3, 4)
    lawn = np.stack([0.13 * lawn_n, 0.22 * lawn_n, 0.07 * lawn_n], axis=-1)
    edge = x_m + 0.6 * np.sin(z_m * 0.4)
    return np.where((edge < -7.5)[..., None], lawn, paving)


def backdrop_reflectance(x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """(..., 3) RGB reflectance of the far backdrop: buildings with windows, and trees."""
    bay = np.floor(x_m / 7.0)
    top = 4.0 + 7.0 * _hash01(bay, bay * 0 + 5, 6)
    tone = _hash01(bay, bay * 0 + 7, 8)
    wall = np.stack([0.45 + 0.2 * tone, 0.4 + 0.1 * tone, 0.33 - 0.05 * tone], axis=-1)
    wx, wy = (x_m % 1.6) / 1.6, (y_m % 2.2) / 2.2
    window = (wx > 0.3) & (wx < 0.7) & (wy > 0.35) & (wy < 0.8) & (y_m > 1.0)
    wall = np.where(window[..., None], wall * 0.3, wall)
    tree_n = _value_noise(x_m, y_m, 0.7, 9)
    tree = np.stack([0.08 * (0.6 + tree_n), 0.15 * (0.6 + tree_n), 0.05 * (0.6 + tree_n)], -1)
    is_tree = (_hash01(bay, bay * 0 + 11, 12) < 0.35) & (y_m < top + 1.5)
    refl = np.where(is_tree[..., None], tree, wall)
    return np.where((y_m < top)[..., None] | is_tree[..., None], refl, np.nan)


@dataclass
class SyntheticSite:
    """The generator; :meth:`frame` renders frame ``i`` with its ground truth.

    Parameters
    ----------
    camera : the site camera (:func:`make_camera`)
    walkers : the people
    fps : frames per second
    duration_s : length; daylight changes over it
    light_model : ``"broadband"`` (spectra through a broadband camera, the default) or
        ``"narrowband"`` (the detector's own model, the sequence before 2026-11-25)
    sky_states : (start, end) names in :data:`spectralcamera.SKY_STATES` (broadband)
    sun_azimuth_deg, sun_elevation_deg : direction toward the sun (azimuth from north to east)
    brightness : (start, end) factor on all daylight (both models), besides the sky's change
    wavelengths_nm : the narrow-band camera's channel centre wavelengths (R, G, B)
    t_lit_k : (start, end) colour temperature of sunlit surfaces (narrow-band)
    t_sky_k : colour temperature of the skylight in shadows (narrow-band)
    shadow_fraction : shadowed over sunlit illuminance (narrow-band)
    exposure : linear value of a white sunlit surface at the start, brightness 1
    noise_codes : standard deviation of the sensor noise, codes
    backdrop_z_m : the backdrop plane (buildings) at ``z = backdrop_z_m``
    """

    camera: PerspectiveCamera
    walkers: list[Walker]
    fps: float = 10.0
    duration_s: float = 12.0
    light_model: str = "broadband"
    sky_states: tuple[str, str] = ("clear", "clear")
    sun_azimuth_deg: float = 290.0
    sun_elevation_deg: float = 32.0
    brightness: tuple[float, float] = (1.0, 0.8)
    wavelengths_nm: tuple[float, float, float] = (610.0, 540.0, 465.0)
    t_lit_k: tuple[float, float] = (5600.0, 4800.0)
    t_sky_k: float = 11000.0
    shadow_fraction: float = 0.35
    exposure: float = 1.3
    noise_codes: float = 1.5
    backdrop_z_m: float = -45.0
    seed: int = 0
    _static: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.light_model not in ("broadband", "narrowband"):
            raise ValueError(f"light_model must be broadband or narrowband, got "
                             f"{self.light_model!r}")
        unknown = [s for s in self.sky_states if s not in spectral.SKY_STATES]
        if unknown:
            raise ValueError(f"unknown sky states {unknown}; known: {list(spectral.SKY_STATES)}")
        cam = self.camera
        H, W = cam.height, cam.width
        v, u = np.mgrid[0:H, 0:W]
        d = cam.ray_directions(u.ravel() + 0.5, v.ravel() + 0.5)
        self._static["dirs"] = d.reshape(H, W, 3)
        self._static["surface"], self._static["sky"], self._static["ground"] = (
            self._static_scene(2)
        )
        az, el = math.radians(self.sun_azimuth_deg), math.radians(self.sun_elevation_deg)
        self._static["sun"] = np.array(
            [math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)]
        )
        if self.light_model == "broadband":
            # The camera's fixed colour correction (white balance included), as a camera
            # calibrated once for sunlit surfaces under the first sky: there a surface shows
            # its coefficients ``a``; under any other light, a full 3x3 mix of them. The sky
            # pattern (max G 0.75) is as bright, relative to sunlit ground, as the narrow-band
            # model's.
            direct, diffuse = self._spectra(0.0)
            correct = np.linalg.inv(spectral.camera_matrix(direct + diffuse))
            self._static["white_balance"] = correct
            self._static["sky_gain"] = 0.9 / float((correct @ spectral.camera_matrix(diffuse))[1]
                                                   .sum())
        # sRGB encoding by table on finely quantised linear light (exact enough, fast).
        lin = np.linspace(0.0, 1.0, 1 << 14)
        code = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055) * 255
        self._static["encode"] = code.astype(np.float32)

    # The static scene is supersampled ss x ss per pixel so far texture is not aliased.
    def _static_scene(self, ss: int):
        """(surface reflectance x coverage (H, W, 3), sky x coverage (H, W, 3), ground point
        at each pixel centre (H, W, 3), NaN off the ground)."""
        cam = self.camera
        H, W = cam.height, cam.width
        offs = (np.arange(ss) + 0.5) / ss
        surface = np.zeros((H, W, 3))
        sky = np.zeros((H, W, 3))
        v, u = np.mgrid[0:H, 0:W]
        for oy in offs:
            for ox in offs:
                d = cam.ray_directions(u.ravel() + ox, v.ravel() + oy).reshape(H, W, 3)
                ground, pg, back, pb = self._hits(d)
                refl = np.full((H, W, 3), np.nan)
                refl[ground] = ground_reflectance(pg[ground][:, 0], pg[ground][:, 2])
                refl[back] = backdrop_reflectance(pb[back][:, 0], pb[back][:, 1])
                open_sky = np.isnan(refl[..., 0])
                # The sky: brighter and paler toward the horizon.
                elev = np.clip(d[..., 1] / np.linalg.norm(d, axis=-1), 0.0, 1.0)
                blue = np.stack([0.55 - 0.25 * elev, 0.75 - 0.2 * elev, 1.0 - 0.1 * elev], -1)
                sky += np.where(open_sky[..., None], blue, 0.0)
                surface += np.where(open_sky[..., None], 0.0, refl)
        surface /= ss * ss
        sky /= ss * ss
        ground, pg, _, _ = self._hits(self._static["dirs"])
        ground_pts = np.where(ground[..., None], pg, np.nan)
        return surface.astype(np.float32), sky.astype(np.float32), ground_pts

    def _hits(self, d: np.ndarray):
        """Which rays (H, W, 3) meet the ground before the backdrop, and where each meets."""
        o = self.camera.origin_m
        with np.errstate(divide="ignore", invalid="ignore"):
            s_ground = np.where(d[..., 1] < 0, -o[1] / d[..., 1], np.inf)
            s_back = np.where(d[..., 2] < 0, (self.backdrop_z_m - o[2]) / d[..., 2], np.inf)
        ground = s_ground < s_back
        back = ~ground & np.isfinite(s_back)
        pg = o + np.where(ground, s_ground, 0.0)[..., None] * d
        pb = o + np.where(back, s_back, 0.0)[..., None] * d
        return ground, pg, back, pb

    @property
    def frame_count(self) -> int:
        return int(round(self.duration_s * self.fps))

    def light(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(lit, shadow, sky)`` (3, 3) float32 camera matrices at time t: a surface of RGB
        reflectance coefficients ``a`` shows linear RGB ``M @ a`` (before ``exposure``) when
        sunlit, when in a person's cast shadow, and the sky's pattern when it is the sky."""
        a = min(max(t / self.duration_s, 0.0), 1.0)
        b = self.brightness[0] + a * (self.brightness[1] - self.brightness[0])
        b *= 1.0 + 0.04 * math.sin(2 * math.pi * t / 5.0)  # a passing thin cloud
        if self.light_model == "narrowband":
            t_lit = self.t_lit_k[0] + a * (self.t_lit_k[1] - self.t_lit_k[0])
            sky = wien_rgb(self.t_sky_k, self.wavelengths_nm)
            mats = (np.diag(wien_rgb(t_lit, self.wavelengths_nm)),
                    np.diag(self.shadow_fraction * sky), np.diag(0.9 * sky))
        else:
            direct, diffuse = self._spectra(a)
            white = self._static["white_balance"]
            mats = (white @ spectral.camera_matrix(direct + diffuse),
                    white @ spectral.camera_matrix(diffuse),
                    self._static["sky_gain"] * (white @ spectral.camera_matrix(diffuse)))
        return tuple((b * m).astype(np.float32) for m in mats)

    def _spectra(self, a: float) -> tuple[np.ndarray, np.ndarray]:
        """(direct, diffuse) (n,) spectral irradiance on the ground a share ``a`` of the way
        from the first sky state to the second (the spectra mixed linearly)."""
        first, last = (spectral.SKY_STATES[s].irradiance(self.sun_elevation_deg)
                       for s in self.sky_states)
        return tuple((1.0 - a) * f + a * g for f, g in zip(first, last, strict=True))

    def frame(self, i: int) -> TruthFrame:
        """Render frame ``i`` (time ``i / fps``) with its ground truth."""
        cam = self.camera
        H, W = cam.height, cam.width
        t = i / self.fps
        lit, shadow_light, skylight = self.light(t)
        refl = self._static["surface"]
        lin = refl @ lit.T + self._static["sky"] @ skylight.T
        person_index = np.full((H, W), -1, dtype=np.int16)
        person_depth = np.full((H, W), np.inf)
        shadow = np.zeros((H, W), dtype=bool)
        visible = [(k, w) for k, w in enumerate(self.walkers) if w.enter_s <= t < w.leave_s]
        truths = []
        o = cam.origin_m
        dirs = self._static["dirs"]
        ground = self._static["ground"]
        sun = self._static["sun"]
        figures = []
        for k, walker in visible:
            x, z = walker.position(t)
            foot = np.array([x, 0.0, z])
            n = np.array([o[0] - x, 0.0, o[2] - z])
            n /= np.linalg.norm(n)
            right = np.array([n[2], 0.0, -n[0]])
            parts = walker.capsules(t)
            figures.append((k, walker, foot, n, right, parts))
        # Shadows first (on the ground), then people over them. A body is about as wide seen
        # from the sun as from the camera, so the shadow is cast by the same silhouette in the
        # vertical plane that faces the sun.
        sun_h = np.array([sun[0], 0.0, sun[2]]) / math.hypot(sun[0], sun[2])
        sun_right = np.array([sun_h[2], 0.0, -sun_h[0]])
        for _k, walker, foot, _n, _right, parts in figures:
            hgt = walker.height_m
            corners = []
            for sx in (-0.6, 0.6):
                base = foot + sx * hgt * sun_right
                top = base + np.array([0.0, hgt * 1.0, 0.0])
                corners += [base, top - (top[1] / sun[1]) * sun]
            uv, z = cam.project(np.array(corners))
            # A corner behind the camera: its projection says nothing, test the whole frame.
            box = (0, 0, W, H) if np.any(z <= 0) else pixel_box(uv, 2, W, H)
            if box is None:
                continue
            x0, y0, x1, y1 = box
            g = ground[y0:y1, x0:x1]
            ok = np.isfinite(g[..., 0])
            g = np.nan_to_num(g)
            tt = ((foot - g) @ sun_h) / float(sun @ sun_h)
            q = g + tt[..., None] * sun
            hit, _, _ = inside_figure(parts, (q - foot) @ sun_right, q[..., 1])
            shadow[y0:y1, x0:x1] |= hit & ok & (tt > 0)
        lin[shadow] = refl[shadow] @ shadow_light.T
        for k, walker, foot, n, right, parts in figures:
            hgt = walker.height_m
            corners = [foot + sx * 0.6 * hgt * right + np.array([0, sy, 0])
                       for sx in (-1, 1) for sy in (0.0, hgt * 1.02)]
            uv, z = cam.project(np.array(corners))
            box = None if np.any(z <= 0) else pixel_box(uv, 1, W, H)
            if box is None:
                continue
            x0, y0, x1, y1 = box
            d = dirs[y0:y1, x0:x1]
            s = ((foot - o) @ n) / (d @ n)  # depth along the optical axis (d has z_cam = 1)
            p = o + s[..., None] * d
            hit, colour, shade = inside_figure(parts, (p - foot) @ right, p[..., 1])
            nearer = hit & (s < person_depth[y0:y1, x0:x1]) & (s > 0)
            person_depth[y0:y1, x0:x1][nearer] = s[nearer]
            person_index[y0:y1, x0:x1][nearer] = k
            lin[y0:y1, x0:x1][nearer] = ((colour[nearer] * shade[nearer, None]) @ lit.T).astype(
                np.float32)
            fuv, fz = cam.project(foot[None])
            fu, fv = fuv[:, 0], fuv[:, 1]
            truths.append(TruthPerson(k, tuple(float(c) for c in foot), float(fz[0]),
                                      (float(fu[0]), float(fv[0])), 0, walker.standing(t)))
        shadow &= person_index < 0
        for tp in truths:
            tp.visible_px = int(np.count_nonzero(person_index == tp.index))
        truths = [tp for tp in truths if tp.visible_px > 0]
        truths.sort(key=lambda tp: -tp.depth_m)
        image = self._expose(lin, i)
        return TruthFrame(image, person_index, shadow, truths, t)

    def _expose(self, lin_rgb: np.ndarray, i: int) -> np.ndarray:
        x = np.clip(lin_rgb * self.exposure, 0.0, 1.0)
        table = self._static["encode"]
        code = table[(x * (len(table) - 1) + 0.5).astype(np.int32)]
        rng = np.random.default_rng((self.seed, i))
        code += rng.standard_normal(code.shape, dtype=np.float32) * self.noise_codes
        rgb = np.clip(code + 0.5, 0, 255).astype(np.uint8)
        return np.ascontiguousarray(rgb[..., ::-1])

    def frames(self):
        for i in range(self.frame_count):
            yield self.frame(i)


def default_site(width: int = 480, height: int = 270, fps: float = 10.0, duration_s: float = 12.0,
                 seed: int = 0, empty_s: float = 1.0) -> SyntheticSite:
    """The standard sequence: ``empty_s`` of empty site, then four people.

    - 0 walks left to right 7 m away (in front of :data:`VIRTUAL_BOX`);
    - 1 walks right to left 19 m away (behind it);
    - 2, in dark neutral grey, walks in, stands still from 3 s to 9 s 9.5 m away, walks on;
    - 3 walks toward the camera from 26 m to 16 m, left of the virtual building.
    """
    cam = make_camera(width, height)
    e = empty_s
    walkers = [
        Walker((-7.0, -7.0), (1.3, 0.0), 1.78, shirt=(0.65, 0.12, 0.1),
               trousers=(0.1, 0.13, 0.32), enter_s=e),
        Walker((9.0, -19.0), (-1.1, 0.0), 1.70, shirt=(0.7, 0.65, 0.15),
               trousers=(0.3, 0.25, 0.2), skin=(0.35, 0.22, 0.16), enter_s=e + 0.5),
        Walker((-4.5, -9.5), (1.2, 0.0), 1.82, shirt=(0.12, 0.12, 0.12),
               trousers=(0.5, 0.45, 0.35), enter_s=e + 0.3, pauses_s=((3.0, 9.0),)),
        Walker((-6.0, -26.0), (0.0, 1.0), 1.65, shirt=(0.85, 0.8, 0.75),
               trousers=(0.15, 0.15, 0.15), hair=(0.3, 0.18, 0.08), enter_s=e + 1.0),
    ]
    return SyntheticSite(cam, walkers, fps=fps, duration_s=duration_s, seed=seed)


# A virtual building for the standard sequence: person 0 passes in front, person 1 behind.
VIRTUAL_BOX = ((-4.0, 0.0, -15.0), (3.0, 5.0, -11.0))
