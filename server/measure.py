"""Measuring the light vector ``r`` (n x RGB) from a fisheye sky frame (Sato Sec. 5, Kakuta 2.2.3).

Per frame the work is small and fixed: linearise with the inverse response curve (one 16-bit
table look-up per pixel, ``cv2.LUT``), bin in linear values to the working resolution (2 x 2
area means, once or more: OpenCV's SIMD path), both band by band over the image circle only,
and a few sparse products over the binned pixels in memory order (CSC). Everything that depends
only on the lens and the dome is precomputed once in :class:`PatchMatrix`.

How pixels cut by a patch edge are shared
-----------------------------------------
A light's value is the solid-angle weighted mean of the sky over its patch. Pixels wholly inside
one patch count for it with their solid angle. Sato averages "the pixels inside each projected
triangle"; but pixels cut by an edge hold a mix of two or three patches, and with a few hundred
patches they are a fifth of all pixels. Counting them by coverage (the plain area mean) is right
for a sky that is continuous across the edge, yet where the sky jumps at the edge (a sky that is
constant per patch, the test's known answer) it leaks several per cent between neighbours. A
least-squares unmixing ``(A^T W A) r = A^T W v`` is exact for the jump but biased for real,
textured skies (on the simulated cloudy sky it was off by up to 2.1 %, the plain mean and the
sharing below by 0.8 %). So a cut
pixel ``p`` is shared between its patches ``k`` in proportion to ``c_pk * x_ref(p,k)``: its
coverage times the value of the nearest whole pixel of patch ``k``. Where the sky is continuous
the reference values agree and this is the plain area mean; where it jumps at the edge they
differ and each patch gets its own part back exactly. Coverage comes from a jittered sub-pixel
grid (a regular grid biases every pixel along an edge that runs nearly along the pixel grid).

Pixels that are not wholly above the horizon and inside the lens's field of view are left out
(the ground, trees and the black border outside the image circle are not sky).

Units: a frame's linear value ``x = exposure * vignetting * L / photometric_factor`` for sky
radiance ``L`` in W/(m^2 sr); the measurement returns ``L`` per patch, i.e. the ``r_i`` of
DESIGN.md including the photometric factor of Sato Sec. 5.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from dataclasses import dataclass, replace

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from daylit.spherical import PatchLookup, centroid_direction
from server.fisheye import FisheyeCamera
from server.sunmeter import SunMeasurement, SunMeter

log = logging.getLogger("daylit.measure")

# Frames are binned (after linearising, by a power of two) to at most this many pixels of the
# image circle's bounding box: at 1 megapixel 320 x 240, a hundred or more pixels per light of
# a 400-light dome, which keeps the per-frame cost near one table look-up per full-resolution
# pixel. Twice as many pixels per side (4 times this) quarter the error at the patches' edges
# for 1.5 times the time (docs/benchmarks.md). Setting: [sky] max_working_pixels.
DEFAULT_WORKING_PIXELS = 1 << 17

# Pixels are classified in chunks of this many, so a 4-megapixel lens needs little memory.
_CHUNK_PIXELS = 1 << 18


# ---------------------------------------------------------------------------------- photometry


def inverse_response_table(spec, levels: int = 256) -> np.ndarray:
    """The inverse camera response as a table ``(levels, 3)`` float32: code -> linear in [0, 1].

    ``spec`` is ``"linear"``, ``"srgb"`` (IEC 61966-2-1, the usual default of webcams),
    ``"gamma:G"`` (``x = (code / max)^G``), or a list of ``levels`` numbers (one curve for all
    channels) or of ``levels`` RGB triples, e.g. from a Debevec-Malik or Robertson calibration.
    """
    code = np.arange(levels, dtype=np.float64) / (levels - 1)
    if isinstance(spec, str):
        if spec == "linear":
            curve = code
        elif spec == "srgb":
            curve = np.where(code <= 0.04045, code / 12.92, ((code + 0.055) / 1.055) ** 2.4)
        elif spec.startswith("gamma:"):
            try:
                g = float(spec.split(":", 1)[1])
            except ValueError:
                raise ValueError(f"response {spec!r}: gamma must be a number") from None
            if not 0.1 <= g <= 10.0:
                raise ValueError(f"response {spec!r}: gamma must be between 0.1 and 10")
            curve = code**g
        else:
            raise ValueError(f"unknown response {spec!r}: use linear, srgb, gamma:G or a table")
        return np.repeat(curve[:, None], 3, axis=1).astype(np.float32)
    table = np.asarray(spec, dtype=np.float64)
    if table.ndim == 1:
        table = np.repeat(table[:, None], 3, axis=1)
    if table.shape != (levels, 3):
        raise ValueError(f"a response table needs {levels} values or RGB triples: {table.shape}")
    if not np.all(np.isfinite(table)) or np.any(np.diff(table, axis=0) < 0):
        raise ValueError("a response table must be finite and non-decreasing")
    return (table / max(table[-1].max(), 1e-12)).astype(np.float32)


@dataclass
class Photometry:
    """How pixel codes become radiance (Sato Sec. 5).

    Attributes
    ----------
    response : str or list
        Inverse response curve, see :func:`inverse_response_table`.
    exposure : float
        Linear value of unit radiance (W/(m^2 sr)) at the camera's fixed setting; a frame
        that reports its own exposure (the simulated sky, auto-exposing cameras) overrides it.
    photometric_factor : RGB
        Multiplies the result: the calibration between camera units and the unit radiance of
        the baked basis (white balance included).
    vignetting : tuple of float
        Relative illumination ``g(theta) = 1 + a1 theta^2 + a2 theta^4 + ...`` (theta in radians
        from the optical axis); measured values are divided by it. Empty: none.
    saturation_level : float
        Fraction of full scale at or above which a code counts as clipped.
    """

    response: object = "srgb"
    exposure: float = 1.0
    photometric_factor: tuple[float, float, float] = (1.0, 1.0, 1.0)
    vignetting: tuple[float, ...] = ()
    saturation_level: float = 0.98

    def vignetting_gain(self, theta_rad: np.ndarray) -> np.ndarray:
        gain = np.ones_like(theta_rad)
        t2 = theta_rad * theta_rad
        power = np.ones_like(theta_rad)
        for a in self.vignetting:
            power = power * t2
            gain = gain + a * power
        return gain


# ---------------------------------------------------------------------------- the geometry


@dataclass
class PatchMatrix:
    """Precomputed pixel -> patch weights for one lens, image size and dome.

    Pixels wholly inside one patch ("whole") add ``w_p x_p`` to it through one sparse product.
    A pixel cut by patch edges ("cut") is shared between the patches it overlaps in proportion
    to ``c_pk * x_ref(p,k)``: its coverage times the value of the nearest whole pixel of that
    patch (see the module notes). Pairs ``(p, k)`` are stored sorted by pixel.

    Attributes
    ----------
    camera : FisheyeCamera
        The lens at the *working* resolution (after binning), whole frame.
    binning : int
        Frames are area-averaged by this factor (after linearisation) before measuring.
    crop : (x0, y0, x1, y1)
        The part of the full-resolution frame that holds every used pixel (a multiple of
        ``binning``); flat pixel indices below count row-major in this part at working
        resolution (P pixels).
    whole : (n, P) float32 CSC
        ``w_p / g_p`` (solid angle over vignetting gain) for whole pixels.
    pair_pixel, pair_ref, pair_group : (m,) int
        For each cut pair: its pixel, the reference pixel for its patch, and the index of its
        pixel among the cut pixels.
    pair_cover : (m,) float32
        Coverage fraction of the pair's patch in its pixel.
    cut_pixel : (g,) int
        The cut pixels.
    pairs_to_pixel : (g, m) float32 CSR
        Coverage of each pair, summed per cut pixel.
    pairs_to_light : (n, m) float32 CSC
        ``c_pk w_p / g_p`` (coverage times solid angle over vignetting) from each pair to its
        patch: ``pairs_to_light @ x[pair_pixel]`` is the plain coverage-weighted sum.
    norm : (n,) float64
        ``sum_p w_p c_pk``: the solid angle each light is measured over, sr.
    whole_light : (P,) int32
        The light of each whole pixel, -1 for cut and unused pixels (with ``pair_pixel`` and
        ``pair_light``, names the lights that clipped pixels fall on).
    pair_light : (m,) int32
        The light of each cut pair.
    covered : (n,) bool
        Lights that have pixels; the others copy ``fill_from``.
    fill_from : (n,) int
        For every light, the covered light whose value it takes (itself when covered).
    strips : ((r0, r1, c0, c1), ...)
        Horizontal bands of the crop at full resolution (multiples of ``binning``), each cut
        to the columns that hold used pixels: 8-bit frames are linearised and binned band by
        band, which skips the corners outside the image circle and keeps each band's 16-bit
        values in the cache between the look-up and the binning.
    """

    camera: FisheyeCamera
    binning: int
    crop: tuple[int, int, int, int]
    whole: sp.csr_matrix
    pair_pixel: np.ndarray
    pair_ref: np.ndarray
    pair_group: np.ndarray
    pair_cover: np.ndarray
    cut_pixel: np.ndarray
    pairs_to_pixel: sp.csr_matrix
    pairs_to_light: sp.csr_matrix
    norm: np.ndarray
    whole_light: np.ndarray
    pair_light: np.ndarray
    covered: np.ndarray
    fill_from: np.ndarray
    pixels_used: int
    build_s: float
    strips: tuple[tuple[int, int, int, int], ...] = ()

    @property
    def count(self) -> int:
        return int(self.whole.shape[0])

    @classmethod
    def build(
        cls,
        camera: FisheyeCamera,
        dome_vertices: np.ndarray,
        supersample: int = 6,
        vignetting: Photometry | None = None,
        max_working_pixels: int = DEFAULT_WORKING_PIXELS,
        sky_mask: np.ndarray | None = None,
    ) -> PatchMatrix:
        """Classify every pixel against the dome.

        Parameters
        ----------
        camera : FisheyeCamera
            The lens at the frames' full resolution.
        dome_vertices : (n, 3, 3) float
            The manifest's light triangles (site frame).
        supersample : int
            Sub-pixel grid ``s x s`` for pixels cut by a patch edge.
        vignetting : Photometry, optional
            Supplies the vignetting gain folded into the weights.
        max_working_pixels : int
            Frames larger than this are binned by an integer factor first.
        sky_mask : (H, W) array, optional
            Full-resolution mask, nonzero where the camera sees open sky (excludes trees,
            masts, the camera's own housing).
        """
        t0 = time.perf_counter()
        tris = np.asarray(dome_vertices, dtype=np.float64)
        n = tris.shape[0]
        binning = _binning_for(camera, max_working_pixels)
        cam = _binned(camera, binning)
        W, H = cam.width, cam.height
        lookup = PatchLookup(tris)
        edge_normals = lookup.edge_normals  # (n, 3, 3), pointing into each patch
        mask_small = None
        if sky_mask is not None:
            if sky_mask.shape[:2] != (camera.height, camera.width):
                raise ValueError("sky mask size differs from the frames")
            m = (np.asarray(sky_mask) > 0).astype(np.float32)
            mask_small = cv2.resize(
                m[: H * binning, : W * binning], (W, H), interpolation=cv2.INTER_AREA
            )
        s = max(1, int(supersample))
        offsets = (np.arange(s) + 0.5) / s - 0.5
        sub = np.stack(np.meshgrid(offsets, offsets), axis=-1).reshape(-1, 2)  # (s^2, 2)
        max_theta = math.radians(cam.max_theta_deg)
        rng = np.random.default_rng(0)  # fixed: the same lens always gets the same matrix

        whole_pix, whole_light = [], []
        cut_pix, cut_light, cut_cover = [], [], []
        weight = np.zeros(W * H)  # solid angle of each used pixel over its vignetting gain
        omega_all = np.zeros(W * H)
        for start in range(0, W * H, _CHUNK_PIXELS):
            flat = np.arange(start, min(start + _CHUNK_PIXELS, W * H))
            px = np.stack([flat % W, flat // W], axis=-1).astype(np.float64)
            d, _ = cam.unproject(px)
            theta = np.arccos(np.clip((d @ cam.site_from_camera)[:, 2], -1, 1))
            # Footprint size from the pixel's neighbours: solid angle and an angular radius.
            du = cam.unproject(px + [0.5, 0.0])[0] - cam.unproject(px - [0.5, 0.0])[0]
            dv = cam.unproject(px + [0.0, 0.5])[0] - cam.unproject(px - [0.0, 0.5])[0]
            omega = np.linalg.norm(np.cross(du, dv), axis=-1)
            radius = 0.6 * np.sqrt((du * du).sum(-1) + (dv * dv).sum(-1))  # half diagonal + 20%
            inside = (d[:, 1] >= np.sin(radius)) & (theta + radius <= max_theta)
            if mask_small is not None:
                inside &= mask_small.ravel()[flat] >= 1.0 - 1e-6
            gain = np.ones(flat.size)
            if vignetting is not None and vignetting.vignetting:
                gain = vignetting.vignetting_gain(theta)
            flat, d, radius, px = flat[inside], d[inside], radius[inside], px[inside]
            weight[flat] = (omega / gain)[inside]
            omega_all[flat] = omega[inside]
            if flat.size == 0:
                continue
            patch = lookup(d)
            margin = np.einsum("mej,mj->me", edge_normals[patch], d).min(axis=1)
            is_whole = margin >= np.sin(radius)
            whole_pix.append(flat[is_whole])
            whole_light.append(patch[is_whole])
            cut = np.flatnonzero(~is_whole)
            if cut.size:
                # Jittered strata: a regular grid would bias every pixel along an edge that
                # runs nearly along the pixel grid by the same fraction.
                jitter = (rng.random((cut.size, sub.shape[0], 2)) - 0.5) / s
                sub_px = px[cut][:, None, :] + sub[None] + jitter
                sub_dirs, _ = cam.unproject(sub_px.reshape(-1, 2))
                # Most samples fall in the centre's patch: test that first, look up the rest.
                home = np.repeat(patch[cut], sub.shape[0])
                in_home = np.einsum("mej,mj->me", edge_normals[home], sub_dirs).min(axis=1) >= 0
                sub_patch = home.copy()
                away = np.flatnonzero(~in_home)
                sub_patch[away] = lookup(sub_dirs[away])
                key = np.repeat(flat[cut], sub.shape[0]) * n + sub_patch
                uniq, counts = np.unique(key[sub_patch >= 0], return_counts=True)
                cut_pix.append(uniq // n)
                cut_light.append(uniq % n)
                cut_cover.append(counts / sub.shape[0])

        def cat(parts, dtype):
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

        wp, wl = cat(whole_pix, np.int64), cat(whole_light, np.int64)
        cp, cl, cc = cat(cut_pix, np.int64), cat(cut_light, np.int64), cat(cut_cover, np.float64)
        norm = np.bincount(wl, omega_all[wp], minlength=n) + np.bincount(cl, omega_all[cp] * cc, n)
        # Crop to the used pixels: less to linearise and bin per frame.
        used = np.concatenate([wp, cp])
        if used.size == 0:
            raise ValueError("no light of the dome is seen by this camera (check its calibration)")
        ux, uy = used % W, used // W
        x0, y0, x1, y1 = int(ux.min()), int(uy.min()), int(ux.max()) + 1, int(uy.max()) + 1
        cw = x1 - x0

        def local(flat):
            return (flat // W - y0) * cw + (flat % W - x0)

        wp, cp = local(wp), local(cp)
        P = cw * (y1 - y0)
        order = np.lexsort((cl, cp))  # pairs grouped by pixel
        cp, cl, cc = cp[order], cl[order], cc[order]
        cut_weight = weight.reshape(H, W)[y0:y1, x0:x1].ravel()
        # Column-major: the products walk the frame's pixels (and pairs) in memory order and
        # add into the small (n, 3) result, about 1.6 times faster than row-major here.
        whole = sp.csc_matrix((cut_weight[wp], (wl, wp)), shape=(n, P), dtype=np.float32)
        m = cp.size
        pairs_to_light = sp.csc_matrix(
            (cut_weight[cp] * cc, (cl, np.arange(m))), shape=(n, m), dtype=np.float32
        )
        cut_pixel, pair_group = np.unique(cp, return_inverse=True)
        pairs_to_pixel = sp.csr_matrix(
            (cc, (pair_group, np.arange(m))), shape=(cut_pixel.size, m), dtype=np.float32
        )
        pair_ref = _reference_pixels(cp, cl, wp, wl, cw)
        whole_light = np.full(P, -1, dtype=np.int32)
        whole_light[wp] = wl
        covered = norm > 0
        if not covered.any():
            raise ValueError("no light of the dome is seen by this camera (check its calibration)")
        # Lights the lens cannot see take the value of the nearest light it can.
        centroids = centroid_direction(tris)
        seen = np.flatnonzero(covered)
        nearest = seen[np.argmax(centroids @ centroids[seen].T, axis=1)]
        fill_from = np.where(covered, np.arange(n), nearest)
        used_map = np.zeros(P, dtype=bool)
        used_map[wp] = True
        used_map[cp] = True
        strips = _strips(used_map.reshape(y1 - y0, cw), binning)
        return cls(
            strips=strips,
            camera=cam,
            binning=binning,
            crop=(x0 * binning, y0 * binning, x1 * binning, y1 * binning),
            whole=whole,
            pair_pixel=cp,
            pair_ref=pair_ref,
            pair_group=pair_group.astype(np.int64),
            pair_cover=cc.astype(np.float32),
            cut_pixel=cut_pixel,
            pairs_to_pixel=pairs_to_pixel,
            pairs_to_light=pairs_to_light,
            norm=norm,
            whole_light=whole_light,
            pair_light=cl.astype(np.int32),
            covered=covered,
            fill_from=fill_from,
            pixels_used=int(np.count_nonzero(omega_all)),
            build_s=time.perf_counter() - t0,
        )

    def apply(self, linear: np.ndarray) -> np.ndarray:
        """Mean value of each patch ``(n, 3)`` of a linear image of the crop at working size."""
        x = linear.reshape(-1, 3)
        total = self.whole @ x
        if self.pair_pixel.size:
            # Share each cut pixel in proportion to coverage x the value just inside each patch
            # (the coverage is in both matrices' weights).
            inside = np.take(x, self.pair_ref, axis=0)
            inside += np.float32(1e-7)
            share = np.take(x, self.cut_pixel, axis=0)
            share /= self.pairs_to_pixel @ inside
            inside *= np.take(share, self.pair_group, axis=0)
            total += self.pairs_to_light @ inside
        out = np.zeros((self.count, 3))
        seen = self.covered
        out[seen] = total[seen] / self.norm[seen, None]
        return out[self.fill_from]

    def lights_at_pixels(self, flat_pixels: np.ndarray) -> np.ndarray:
        """Indices of lights that any of the given working-image pixels cover."""
        if flat_pixels.size == 0:
            return np.zeros(0, dtype=np.int64)
        hit = np.zeros(self.count, dtype=bool)
        lights = self.whole_light[flat_pixels]
        hit[lights[lights >= 0]] = True
        marked = np.zeros(self.whole_light.size, dtype=bool)
        marked[flat_pixels] = True
        hit[self.pair_light[marked[self.pair_pixel]]] = True
        return np.flatnonzero(hit)


def _strips(used: np.ndarray, b: int, full_rows: int = 64) -> tuple:
    """Bands of about ``full_rows`` full-resolution rows over the working-size map of used
    pixels ``used`` (h, w), each ``(r0, r1, c0, c1)`` in full-resolution pixels of the crop,
    narrowed to the columns that hold used pixels; bands without any are left out."""
    rows = max(1, full_rows // b)
    out = []
    for r in range(0, used.shape[0], rows):
        cols = np.flatnonzero(used[r:r + rows].any(axis=0))
        if cols.size:
            r1 = min(used.shape[0], r + rows)
            out.append((r * b, r1 * b, int(cols[0]) * b, (int(cols[-1]) + 1) * b))
    return tuple(out)


def _binned(camera: FisheyeCamera, b: int) -> FisheyeCamera:
    """The lens as seen in frames binned ``b x b`` (pixel ``u'`` averages ``b u' ... b u' + b -
    1``): exactly ``1 / b`` the scale, also when the frame's size is not a multiple of ``b``
    (the rest of the rows and columns are left out)."""
    K = camera.K.copy()
    K[0, 0] /= b
    K[0, 1] /= b
    K[1, 1] /= b
    K[0, 2] = (K[0, 2] + 0.5) / b - 0.5  # pixel centres: u' + 0.5 = (u + 0.5) / b
    K[1, 2] = (K[1, 2] + 0.5) / b - 0.5
    return replace(camera, width=camera.width // b, height=camera.height // b, K=K)


def _binning_for(camera: FisheyeCamera, max_working_pixels: int) -> int:
    """The binning factor: the smallest power of two ``b`` for which the part of the frame that
    sees the sky (the bounding box of the image circle above the horizon), binned ``b x b``,
    has at most ``max_working_pixels`` pixels.

    Powers of two because OpenCV averages 2 x 2 blocks with SIMD code: two 2 x 2 steps take a
    fifth of the time of one 4 x 4 or 3 x 3 step (docs/benchmarks.md).
    """
    step = max(1, min(camera.width, camera.height) // 256)
    xs = np.arange(step / 2.0, camera.width, step)
    ys = np.arange(step / 2.0, camera.height, step)
    gx, gy = np.meshgrid(xs, ys)
    d, ok = camera.unproject(np.stack([gx.ravel(), gy.ravel()], axis=-1))
    sky = ok & (d[:, 1] >= 0.0)
    if sky.any():
        u, v = gx.ravel()[sky], gy.ravel()[sky]
        width = min(camera.width, u.max() - u.min() + 2 * step)
        height = min(camera.height, v.max() - v.min() + 2 * step)
    else:
        width, height = camera.width, camera.height
    b = 1
    while width * height / (b * b) > max_working_pixels:
        b *= 2
    return b


def _reference_pixels(
    cut_pix: np.ndarray, cut_light: np.ndarray, whole_pix: np.ndarray, whole_light: np.ndarray,
    width: int, neighbours: int = 64,
) -> np.ndarray:
    """For each cut pair, the nearest whole pixel of the same patch (itself if none is near)."""
    ref = cut_pix.copy()
    if cut_pix.size == 0 or whole_pix.size == 0:
        return ref
    tree = cKDTree(np.stack([whole_pix % width, whole_pix // width], axis=-1))
    k = min(neighbours, whole_pix.size)
    dist, idx = tree.query(np.stack([cut_pix % width, cut_pix // width], axis=-1), k=k)
    idx = idx.reshape(cut_pix.size, -1)
    dist = dist.reshape(cut_pix.size, -1)
    match = (whole_light[idx] == cut_light[:, None]) & (dist <= 8.0)
    found = match.any(axis=1)
    first = np.argmax(match, axis=1)
    ref[found] = whole_pix[idx[found, first[found]]]
    return ref


# ------------------------------------------------------------------------------ measuring


@dataclass
class Measurement:
    """One frame's light vector.

    Attributes
    ----------
    radiance : (n, 3) float32
        Mean radiance of each patch, W/(m^2 sr) times the photometric factor; with a sun
        meter, of the sky *without* the sun's disc (its pixels replaced from around it).
    saturated : (n,) bool
        Lights with clipped pixels (outside the sun's replaced region); their value is a
        lower bound.
    capture_time_s : float
        Unix time of the exposure.
    saturated_pixels : int
        Clipped working pixels in the frame, outside the sun's replaced region.
    sun : SunMeasurement or None
        The sun (None without a sun meter).
    sun_ms : float
        Time spent on the sun, milliseconds.
    """

    radiance: np.ndarray
    saturated: np.ndarray
    capture_time_s: float
    saturated_pixels: int = 0
    sun: SunMeasurement | None = None
    sun_ms: float = 0.0


@dataclass
class Frame:
    """A sky image from a source.

    ``image`` is (H, W, 3) uint8 or uint16 camera codes, or float32 linear values; ``bgr`` says
    whether the channels come in OpenCV's order. ``exposure`` (linear value of unit radiance)
    overrides the configured one when the source knows it. ``hdr``: a float frame without a
    white point (EXR, merged brackets): no value counts as clipped, unless ``clip_level`` is
    given: then values at or above it do (a merged bracket: where even its shortest exposure
    clipped, the value is only a lower bound). ``sky_time_s``: the time the sky is at, for the
    sun's position (None: ``capture_time_s``; the simulated sky sets its simulated time).
    """

    image: np.ndarray
    capture_time_s: float
    bgr: bool = True
    exposure: float | None = None
    truth: object = None  # the simulated sky's known answer, for tests; None for real frames
    hdr: bool = False
    sky_time_s: float | None = None
    clip_level: float | None = None


class FrameError(ValueError):
    """A frame that cannot be measured (wrong size, type or shape); it is skipped."""


class SkyMeter:
    """Turns frames into :class:`Measurement` s for one lens, dome and photometry.

    A matrix is built for each frame size met (logged once per size) and kept: up to
    ``MATRIX_SIZES`` sizes, the least recently used dropped beyond. :meth:`has_matrix` tells
    the pipeline whether a frame's size is new, so it can build that size's matrix on a
    worker thread while it goes on measuring frames of the known sizes.
    """

    MATRIX_SIZES = 4

    def __init__(
        self,
        dome_vertices: np.ndarray,
        photometry: Photometry | None = None,
        camera: FisheyeCamera | None = None,
        fov_deg: float = 180.0,
        supersample: int = 6,
        max_working_pixels: int = DEFAULT_WORKING_PIXELS,
        sky_mask: np.ndarray | None = None,
        sun: SunMeter | None = None,
    ):
        self.sun = sun
        self._cameras: dict[tuple[int, int], FisheyeCamera] = {}
        self.dome_vertices = np.asarray(dome_vertices, dtype=np.float64)
        self.photometry = photometry or Photometry()
        self.camera = camera
        self.fov_deg = fov_deg
        self.supersample = supersample
        self.max_working_pixels = max_working_pixels
        self.sky_mask = sky_mask
        self.matrix: PatchMatrix | None = None  # the one used last
        self._matrices: collections.OrderedDict[tuple[int, int], PatchMatrix] = \
            collections.OrderedDict()  # (width, height) px -> matrix, least recent first
        self._matrices_lock = threading.Lock()
        self.matrix_builds = 0
        self._luts: dict[object, np.ndarray] = {}
        self._binned_codes: np.ndarray | None = None
        self._binned_for: PatchMatrix | None = None  # the matrix _binned_codes is for
        self._factor = np.asarray(self.photometry.photometric_factor, dtype=np.float64)

    def camera_for(self, width: int, height: int) -> FisheyeCamera:
        """The calibrated lens, or an ideal equidistant one centred on a frame of this size
        (the same object for the same size)."""
        cached = self._cameras.get((width, height))
        if cached is None:
            cached = self._cameras[(width, height)] = self._camera_for(width, height)
        return cached

    def _camera_for(self, width: int, height: int) -> FisheyeCamera:
        if self.camera is None:
            return FisheyeCamera.equidistant(width, height, self.fov_deg)
        if (self.camera.width, self.camera.height) == (width, height):
            return self.camera
        if abs(width / self.camera.width - height / self.camera.height) < 1e-3:
            return self.camera.scaled_to(width, height)  # same sensor, other resolution
        raise FrameError(
            f"frame is {width}x{height} but the calibration is for "
            f"{self.camera.width}x{self.camera.height}"
        )

    def has_matrix(self, width: int, height: int) -> bool:
        """True if frames of this size (px) are measured without building a matrix first."""
        return (width, height) in self._matrices

    @property
    def matrix_count(self) -> int:
        return len(self._matrices)

    def prepare(self, width: int, height: int) -> PatchMatrix:
        """The matrix for frames of this size (px), built (seconds for large frames) and kept
        the first time. Thread-safe; raises :class:`FrameError` for a size the calibration
        does not fit."""
        key = (width, height)
        with self._matrices_lock:
            m = self._matrices.get(key)
            if m is not None:
                self._matrices.move_to_end(key)
                self.matrix = m
                return m
        camera = self.camera_for(width, height)
        log.info("building the measuring matrix for %dx%d frames (%d other sizes kept)",
                 width, height, len(self._matrices))
        m = PatchMatrix.build(
            camera,
            self.dome_vertices,
            supersample=self.supersample,
            vignetting=self.photometry,
            max_working_pixels=self.max_working_pixels,
            sky_mask=self.sky_mask,
        )
        log.info("measuring matrix for %dx%d frames built in %.1f s (measured at %dx%d, %d "
                 "pixels)", width, height, m.build_s, m.camera.width, m.camera.height,
                 m.pixels_used)
        with self._matrices_lock:
            self.matrix_builds += 1
            self._matrices[key] = m
            while len(self._matrices) > self.MATRIX_SIZES:
                self._matrices.popitem(last=False)
            self.matrix = m
        return m

    def _lut(self, levels: int) -> np.ndarray:
        if levels not in self._luts:
            self._luts[levels] = inverse_response_table(self.photometry.response, levels)
        return self._luts[levels]

    def _lut16(self) -> np.ndarray:
        """8-bit code -> 16-bit linear value for ``cv2.LUT``: (1, 256) when every channel has
        the same curve (a one-channel look-up over the interleaved image), else (1, 256, 3)."""
        if "lut16" not in self._luts:
            table = self._lut(256)
            lut = np.round(table * 65535).astype(np.uint16)
            if np.all(table == table[:, :1]):
                self._luts["lut16"] = lut[:, 0].reshape(1, 256)
            else:
                self._luts["lut16"] = lut.reshape(1, 256, 3)
        return self._luts["lut16"]

    @staticmethod
    def _clipped_pixels(crop: np.ndarray, rows: np.ndarray, threshold: float,
                        b: int) -> np.ndarray:
        """Flat working-size indices of the b x b blocks of ``crop`` with a channel at or above
        ``threshold``; ``rows``: the crop's rows that hold such values (the sun: a few)."""
        h, w = crop.shape[:2]
        wb = w // b
        rows = rows[rows < (h // b) * b]
        if rows.size == 0:
            return np.zeros(0, dtype=np.int64)
        block_rows = np.unique(rows // b)
        picked = (block_rows[:, None] * b + np.arange(b)).ravel()
        band = crop[picked, : wb * b].reshape(block_rows.size, b, wb * b * 3)
        peak = band[:, 0]
        for k in range(1, b):  # the largest value of each block's rows...
            peak = np.maximum(peak, band[:, k])
        peak = peak.reshape(block_rows.size, wb, b * 3).max(axis=2)  # ...and of its columns
        ys, xs = np.nonzero(peak >= threshold)
        return block_rows[ys].astype(np.int64) * wb + xs

    def clip_threshold(self, image: np.ndarray, hdr: bool = False,
                       clip_level: float | None = None) -> float:
        """The raw value at or above which a channel counts as clipped (inf: never). An HDR
        float frame clips only at its own ``clip_level`` (a merged bracket), if it has one."""
        level = self.photometry.saturation_level
        if image.dtype == np.uint8:
            return math.ceil(level * 255)
        if image.dtype == np.uint16:
            return math.ceil(level * 65535)
        if hdr:
            return math.inf if clip_level is None else float(clip_level)
        return level

    def to_linear(self, raw: np.ndarray) -> np.ndarray:
        """Codes (..., 3) -> linear float32 through the inverse response; floats unchanged."""
        if raw.dtype == np.uint8:
            return self._lut(256)[raw, np.arange(3)]
        if raw.dtype == np.uint16:
            return self._lut(65536)[raw, np.arange(3)]
        return raw.astype(np.float32)

    def linearize(self, image: np.ndarray, m: PatchMatrix, hdr: bool = False,
                  clip_level: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The crop's linear image at working size (float32, unit: full scale = ``scale``),
        and the flat working-size indices of pixels with a clipped channel (for ``hdr`` float
        frames none, or those at or above their ``clip_level``).

        8-bit frames go through a 16-bit table (``cv2.LUT``) and are binned in 16 bits: the
        cheapest exact path (a 16-bit linear value resolves even code 1 of an sRGB camera).
        Clipped pixels are found from the maximum of each row (one pass over the codes), then
        only in the few row blocks that hold one.
        """
        if image.ndim != 3 or image.shape[2] != 3:
            raise FrameError(f"expected an H x W x 3 image, got shape {image.shape}")
        x0, y0, x1, y1 = m.crop
        crop = image[y0:y1, x0:x1]
        h, w = crop.shape[:2]
        b = m.binning
        threshold = self.clip_threshold(image, hdr, clip_level)
        if image.dtype == np.uint8:
            linear = self._linearize_codes(crop, m)  # already binned
            b = 1
            scale = 65535.0
        elif image.dtype == np.uint16:
            linear = self._lut(65536)[crop, np.arange(3)]
            scale = 1.0
        elif image.dtype in (np.float32, np.float64):
            linear = crop.astype(np.float32)
            if not np.all(np.isfinite(linear)):
                raise FrameError("frame has non-finite values")
            scale = 1.0
        else:
            raise FrameError(f"unsupported pixel type {image.dtype}")
        if math.isinf(threshold):
            hot_rows = np.zeros(0, dtype=np.int64)
        else:
            hot_rows = np.flatnonzero(crop.reshape(h, w * 3).max(axis=1) >= threshold)
        while linear.shape[0] > h // b:  # 2 x 2 area means (b is a power of two): exact
            linear = cv2.resize(linear, (linear.shape[1] // 2, linear.shape[0] // 2),
                                interpolation=cv2.INTER_AREA)
        if scale != 1.0:
            linear = np.multiply(linear, np.float32(1.0 / scale), dtype=np.float32)
        else:
            linear = linear.astype(np.float32, copy=False)
            if np.shares_memory(linear, image):  # the sun's disc is replaced in place
                linear = linear.copy()
        clipped = self._clipped_pixels(crop, hot_rows, threshold, m.binning)
        return linear, clipped

    def _linearize_codes(self, crop: np.ndarray, m: PatchMatrix) -> np.ndarray:
        """8-bit codes -> 16-bit linear values, binned to working size, band by band
        (``m.strips``); pixels outside the bands are 0 (no light uses them)."""
        lut = self._lut16()
        b = m.binning
        h, w = crop.shape[:2]
        out = self._binned_codes
        if out is None or out.shape != (h // b, w // b, 3) or self._binned_for is not m:
            # Zero outside m's bands: a buffer of another frame size may have other bands.
            out = self._binned_codes = np.zeros((h // b, w // b, 3), np.uint16)
            self._binned_for = m
        rows = crop.reshape(h, w * 3)
        for r0, r1, c0, c1 in m.strips:
            if lut.ndim == 2:  # one curve for all channels: a 1-channel look-up
                band = cv2.LUT(rows[r0:r1, 3 * c0:3 * c1], lut).reshape(r1 - r0, c1 - c0, 3)
            else:
                band = cv2.LUT(np.ascontiguousarray(crop[r0:r1, c0:c1]), lut)
            while band.shape[0] > (r1 - r0) // b:  # 2 x 2 area means: exact
                band = cv2.resize(band, (band.shape[1] // 2, band.shape[0] // 2),
                                  interpolation=cv2.INTER_AREA)
            out[r0 // b:r1 // b, c0 // b:c1 // b] = band
        return out

    def measure(self, frame: Frame) -> Measurement:
        """Measure one frame. Raises :class:`FrameError` for frames that cannot be used."""
        image = frame.image
        if not isinstance(image, np.ndarray) or image.ndim != 3:
            raise FrameError("frame is not an H x W x 3 image")
        exposure = frame.exposure if frame.exposure is not None else self.photometry.exposure
        if not exposure or exposure <= 0 or not math.isfinite(exposure):
            raise FrameError(f"frame exposure {exposure!r} is not a positive number")
        h, w = image.shape[:2]
        m = self.prepare(w, h)
        linear, clipped = self.linearize(image, m, frame.hdr, frame.clip_level)
        sun, sun_ms = None, 0.0
        if self.sun is not None:
            t0 = time.perf_counter()
            sky_time_s = frame.capture_time_s if frame.sky_time_s is None else frame.sky_time_s
            sun, replaced = self.sun.measure(
                image, sky_time_s, self.camera_for(w, h), m, linear, self.to_linear,
                self.photometry, exposure, frame.bgr,
                self.clip_threshold(image, frame.hdr, frame.clip_level))
            if replaced is not None and clipped.size:
                clipped = clipped[~replaced[clipped]]  # the sun's clipped pixels are gone
            sun_ms = 1e3 * (time.perf_counter() - t0)
        radiance = m.apply(linear)
        if frame.bgr:
            radiance = radiance[:, ::-1]
        radiance = np.maximum(radiance, 0.0) * (self._factor / exposure)
        saturated = np.zeros(m.count, dtype=bool)
        if clipped.size:
            saturated[m.lights_at_pixels(clipped)] = True
            # A light that the lens cannot see but copies a clipped one is clipped too.
            saturated |= saturated[m.fill_from]
        return Measurement(
            radiance=radiance.astype(np.float32),
            saturated=saturated,
            capture_time_s=frame.capture_time_s,
            saturated_pixels=int(clipped.size),
            sun=sun,
            sun_ms=sun_ms,
        )


# --------------------------------------------------------------------------- time filtering


@dataclass
class TemporalFilter:
    """Exponential smoothing plus a change threshold for the streamed vector and the sun.

    Parameters
    ----------
    time_constant_s : float
        Each new measurement moves the smoothed vector (and the sun's normal irradiance) by
        ``1 - exp(-dt / tau)``; 0 turns smoothing off. A few seconds hides sensor noise;
        clouds over the sun still come through.
    change_threshold : float
        A new vector is sent only when some light's value has moved by more than this fraction
        of the sky's mean radiance ``L`` since the last vector sent (or its flags changed), or
        the sun's normal irradiance by more than this fraction of ``pi L`` (the horizontal
        irradiance of a uniform sky of that radiance: the sun is weighed against the sky's
        own light), or the sun's direction by more than ``sun_direction_threshold_deg``.
    max_interval_s : float
        Send anyway after this long, so clients see that the server is alive.
    sun_direction_threshold_deg : float
        The sun's direction is not smoothed (the newest is kept); a move larger than this
        since the last vector sent is sent.
    """

    time_constant_s: float = 2.0
    change_threshold: float = 0.002
    max_interval_s: float = 5.0
    sun_direction_threshold_deg: float = 0.05
    value: np.ndarray | None = None
    sun: np.ndarray | None = None  # (3,) smoothed normal irradiance, W/m^2; None: no sun meter
    sun_direction: np.ndarray | None = None  # (3,) the newest, unit (zeros: none)
    _time_s: float = 0.0
    _sent: np.ndarray | None = None
    _sent_sun: np.ndarray | None = None
    _sent_sun_direction: np.ndarray | None = None
    _sent_time_s: float = -math.inf
    _sent_flags: object = None

    def reset(self) -> None:
        self.value = None
        self.sun = None
        self.sun_direction = None
        self._sent = None
        self._sent_sun = None
        self._sent_sun_direction = None
        self._sent_time_s = -math.inf
        self._sent_flags = None

    def update(self, radiance: np.ndarray, time_s: float,
               sun_irradiance: np.ndarray | None = None,
               sun_direction: np.ndarray | None = None) -> np.ndarray:
        """Fold in one measurement (n, 3) taken at ``time_s``, and the sun's normal irradiance
        (3,) W/m^2 and direction (3,) when there is a sun meter; returns the smoothed vector."""
        radiance = np.asarray(radiance, dtype=np.float64)
        fresh = self.value is None or self.value.shape != radiance.shape
        if fresh:
            self.value = radiance.copy()
            alpha = 1.0
        else:
            dt = max(0.0, time_s - self._time_s)
            tau = self.time_constant_s
            alpha = 1.0 - math.exp(-dt / tau) if tau > 0 else 1.0
            self.value += alpha * (radiance - self.value)
        if sun_irradiance is not None:
            e = np.asarray(sun_irradiance, dtype=np.float64).reshape(3)
            if self.sun is None or fresh:
                self.sun = e.copy()
            else:
                self.sun += alpha * (e - self.sun)
            self.sun_direction = (np.zeros(3) if sun_direction is None else
                                  np.asarray(sun_direction, dtype=np.float64).reshape(3))
        self._time_s = time_s
        return self.value

    def should_send(self, now_s: float, flags: object = None) -> bool:
        """Whether the current value differs enough from the last one sent."""
        if self.value is None:
            return False
        if self._sent is None or flags != self._sent_flags:
            return True
        if now_s - self._sent_time_s >= self.max_interval_s:
            return True
        scale = max(float(np.mean(np.abs(self._sent))), 1e-9)
        if float(np.max(np.abs(self.value - self._sent))) > self.change_threshold * scale:
            return True
        if self.sun is None:
            return False
        if self._sent_sun is None or self._sent_sun_direction is None:
            return True
        if float(np.max(np.abs(self.sun - self._sent_sun))) > \
                self.change_threshold * math.pi * scale:
            return True
        had, has = bool(np.any(self._sent_sun_direction)), bool(np.any(self.sun_direction))
        if had != has:  # the sun rose or set
            return True
        if not has:
            return False
        cos = float(np.clip(self.sun_direction @ self._sent_sun_direction, -1.0, 1.0))
        return math.degrees(math.acos(cos)) > self.sun_direction_threshold_deg

    def mark_sent(self, now_s: float, flags: object = None) -> None:
        self._sent = None if self.value is None else self.value.copy()
        self._sent_sun = None if self.sun is None else self.sun.copy()
        self._sent_sun_direction = (None if self.sun_direction is None
                                    else self.sun_direction.copy())
        self._sent_time_s = now_s
        self._sent_flags = flags
