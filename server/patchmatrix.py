"""The patch matrix: which pixels of one lens, at one frame size, measure which light of the
dome, and with what weight; precomputed once, then applied to each frame's linear image.

How pixels cut by a patch edge are shared
-----------------------------------------
A light's value is the solid-angle weighted mean of the sky over its patch. Pixels wholly inside
one patch count for it with their solid angle. Sato averages "the pixels inside each projected
triangle"; but pixels cut by an edge hold a mix of two or three patches, and with a few hundred
patches they are a fifth of all pixels. Counting them by coverage (the plain area mean) is right
for a sky that is continuous across the edge, yet where the sky jumps at the edge (a sky that is
constant per patch, the test's known answer) it leaks between neighbours. A least-squares
unmixing ``(A^T W A) r = A^T W v`` is exact for the jump but biased for real, textured skies
(docs/benchmarks.md, "Figures behind choices in the code"). So a cut
pixel ``p`` is shared between its patches ``k`` in proportion to ``c_pk * x_ref(p,k)``: its
coverage times the value of the nearest whole pixel of patch ``k``. Where the sky is continuous
the reference values agree and this is the plain area mean; where it jumps at the edge they
differ and each patch gets its own part back exactly. Coverage comes from a jittered sub-pixel
grid (a regular grid biases every pixel along an edge that runs nearly along the pixel grid).

Pixels that are not wholly above the horizon and inside the lens's field of view are left out
(the ground, trees and the black border outside the image circle are not sky).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from daylit.spherical import PatchLookup, centroid_direction
from server.binning import DEFAULT_WORKING_PIXELS, band_strips, binned_camera, binning_for
from server.fisheye import FisheyeCamera
from server.photometry import Photometry

# Pixels are classified in chunks of this many, so a 4-megapixel lens needs little memory.
_CHUNK_PIXELS = 1 << 18


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
        binning = binning_for(camera, max_working_pixels)
        cam = binned_camera(camera, binning)
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
        # add into the small (n, 3) result, faster than row-major here (docs/benchmarks.md,
        # "Figures behind choices in the code").
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
        strips = band_strips(used_map.reshape(y1 - y0, cw), binning)
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

