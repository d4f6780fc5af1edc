"""The judge of a sun-bounce image as displayed (docs/sun.md, "Judged with the sun's direct
term"): what the client shows with the sun in a patch (:class:`DisplaySkies`: a clear sky
with the sun at the patch's centre; :class:`DisplayCheck`: the sky stack relit with it, the
sun's direct term and the bounce) and the RMS error over its mean that a decoded column
makes. bake.sunbounce compresses the images and asks this judge which need a refinement.
Moved out of bake/sunbounce.py on 2026-12-06 (the two jobs had grown past 500 lines).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bake.rowstore import RowFile, as_stack, valid_blocks

SUN_BOUNCE_DECODE_CHUNK = 16  # light images decoded at a time (memory: the lightmap is large)
DISPLAY_SKY_SAMPLES_PER_SIDE = 6  # the display skies' patch integration (as the test skies')


@dataclass
class DisplaySkies:
    """What a sun-bounce image is judged against: for each light ``p`` of ``lights``, a clear
    sky with the sun at the patch's centre. Its sun and sky brightness are pvlib's
    Ineichen-Perez clear sky for that elevation (``daylit.sun.clear_sky_irradiance``): the
    sky has the CIE clear sky's shape (``daylit.sky.clear_sky``, type 12) scaled to put the
    model's DHI on an open horizontal surface, so that the sky dims as the sun sets (the CIE
    sky's zenith radiance is a constant: it judged the low sun's images against too bright a
    sky, and the high sun's against too dim a one, by up to a factor 2-3 against Radiance's
    gendaylit; docs/benchmarks.md, "The sun-bounce images as displayed"). ``r`` (L, n, 3)
    W/(m^2 sr) the sky without the sun's disc (what the client relights the sky stacks
    with), ``weight`` (L, 3) W/(m^2 sr) ``E_sun / solid_angle_p`` (what the client multiplies
    column ``p`` by). Row ``j`` belongs to light ``lights[j]``."""

    lights: np.ndarray  # (L,) int
    r: np.ndarray  # (L, n, 3)
    weight: np.ndarray  # (L, 3)

    @classmethod
    def of_dome(cls, dome_vertices: np.ndarray, solid_angles_sr: np.ndarray, lights,
                site_elevation_m: float = 0.0, day_of_year: float = 80.0) -> DisplaySkies:
        """The skies for ``lights`` of a dome (``dome_vertices`` (n, 3, 3) unit vectors,
        ``solid_angles_sr`` (n,)) at a site this high, on this day (the equinox's by
        default: the sun's normal irradiance varies 3 % over the year)."""
        from daylit import sky as skies
        from daylit.sun import clear_sky_irradiance, sun_colour

        lights = np.asarray(lights, dtype=int)
        centres = dome_vertices.mean(axis=1)
        centres /= np.linalg.norm(centres, axis=1, keepdims=True)  # the manifest's centroids
        # The open horizontal surface's irradiance per unit radiance of each patch.
        up = np.array([0.0, 1.0, 0.0])
        cosine_weighted = skies.patch_mean_radiance(
            _Cosine(up), dome_vertices, DISPLAY_SKY_SAMPLES_PER_SIDE
        )[:, 0] * solid_angles_sr
        r = np.zeros((len(lights), len(dome_vertices), 3))
        weight = np.zeros((len(lights), 3))
        for j, p in enumerate(lights):
            az, el = skies.azimuth_elevation_from_direction(centres[p][None, :])
            el = max(float(el[0]), 0.5)  # a patch centre at the horizon: a sun just above it
            dni, dhi = clear_sky_irradiance(90.0 - el, day_of_year, site_elevation_m)
            shape = skies.patch_mean_radiance(
                skies.clear_sky(float(az[0]), el), dome_vertices,
                samples_per_side=DISPLAY_SKY_SAMPLES_PER_SIDE, include_sun=False,
            )
            horizontal = float((cosine_weighted @ shape).mean())
            r[j] = shape * float(dhi[0]) / max(horizontal, 1e-30)
            weight[j] = float(dni[0]) * sun_colour(el) / solid_angles_sr[p]
        return cls(lights, r, weight)

    def row(self, light: int) -> int:
        return int(np.searchsorted(self.lights, light))


class _Cosine:
    """A "sky" whose radiance is the cosine to ``normal`` (clamped), grey: its patch means
    times the solid angles are each patch's cosine-weighted solid angle."""

    sun = None

    def __init__(self, normal):
        self.normal = np.asarray(normal, float)

    def radiance(self, dirs):
        return np.repeat(np.clip(dirs @ self.normal, 0.0, None)[:, None], 3, axis=1)


class DisplayCheck:
    """The error a decoded sun-bounce column makes in what the client shows, for one stack:
    the sky stack ``sky`` (H, W, n, 3, the same atlas's or view's, an array or a
    :class:`bake.rowstore.StackStore`) relit with the display sky, plus the sun's direct
    term, plus the sun's bounce (the master column), over the receiver texels (the sky
    stack's non-zero ones): RMS error over the mean of that displayed value.

    The sun's direct term (drawn apart by the client, from its shadow map) is estimated from
    the stacks themselves when ``bounce`` (the sun-bounce stack, H, W, n, 3, each patch's own
    column, not shared) is given: the sky stack's column ``p`` holds the sun's direct light
    and its bounce for patch ``p``, so ``max(sky_p - bounce_p, 0)`` times the display sky's
    weight ``E_sun / solid_angle_p`` is the direct term with the sun spread over its patch.
    Only its mean over the receiver texels enters the error (the client draws the direct term
    itself, exactly: it adds nothing to the numerator), and a mean does not see that the
    patch's shadow edges are soft where the client's are sharp (docs/sun.md, "Judged with the
    sun's direct term"). Without ``bounce`` the direct term is left out (as before
    2026-12-06: every error then larger, the judge stricter than what a visitor sees).

    The relit sky stack of every light of ``lights`` is made in one pass over the sky
    stack's rows (for each block of rows, a matrix product per chunk of lights and
    channel) and kept, (len(lights), V, 3) float64: in memory, or beside a stack on disk."""

    def __init__(self, sky, skies: DisplaySkies, lights, bounce=None):
        sky = as_stack(sky)
        self.valid = sky.valid
        self.skies = skies
        self.lights = [int(i) for i in lights]
        V = int(self.valid.sum())
        # (len(lights),) the direct term's mean over the receiver texels and channels, W/m^2
        # per sr of display radiance as the relit sky (0 without ``bounce``).
        self.direct_mean = np.zeros(len(self.lights))
        direct_sum = np.zeros((len(self.lights), 3))
        stacks = [sky] if bounce is None else [sky, as_stack(bounce)]
        if sky.work is not None:
            self.shown = RowFile.create(sky.work / f"sky-shown-{id(self)}.npy",
                                        (len(self.lights) * V, 3), np.float64)
        else:
            self.shown = np.empty((len(self.lights) * V, 3), dtype=np.float64)
        self.V = V
        for t, block in valid_blocks(stacks, self.valid):
            if bounce is not None:
                direct = block[0][:, self.lights, :] - block[1][:, self.lights, :]
                direct_sum += np.clip(direct, 0.0, None).sum(axis=0, dtype=np.float64)
                del direct
            # (3, b, n) per channel, contiguous: a chunk of lights is one matrix product each.
            per_channel = np.stack([block[0][..., c] for c in range(3)])
            del block
            for start in range(0, len(self.lights), SUN_BOUNCE_DECODE_CHUNK):
                chunk = self.lights[start : start + SUN_BOUNCE_DECODE_CHUNK]
                sky_rows = [self.skies.row(p) for p in chunk]
                out = np.empty((len(chunk), per_channel.shape[1], 3), dtype=np.float64)
                for c in range(3):
                    out[:, :, c] = (
                        per_channel[c] @ self.skies.r[sky_rows, :, c].T.astype(np.float32)
                    ).T
                for j in range(len(chunk)):
                    at = (start + j) * V + t
                    if isinstance(self.shown, RowFile):
                        self.shown.write(at, out[j])
                    else:
                        self.shown[at : at + len(out[j])] = out[j]
        if V:
            weights = self.skies.weight[[self.skies.row(p) for p in self.lights]]
            self.direct_mean = (direct_sum * weights).mean(axis=1) / V

    def sky_shown(self, lights) -> np.ndarray:
        """(len(lights), V, 3) the sky stack relit with each light's display sky."""
        out = []
        for p in lights:
            j = self.lights.index(int(p))
            if isinstance(self.shown, RowFile):
                out.append(self.shown.read(j * self.V, (j + 1) * self.V))
            else:
                out.append(self.shown[j * self.V : (j + 1) * self.V])
        return np.stack(out) if out else np.zeros((0, self.V, 3))

    def remove(self) -> None:
        if isinstance(self.shown, RowFile):
            self.shown.remove()

    def error(self, light: int, sky_shown: np.ndarray, master, decoded) -> float:
        """RMS error over the mean of the displayed value with the sun in ``light``'s patch
        (the relit sky, the direct term's mean, the bounce), when its column is ``decoded``
        instead of ``master`` (both (H, W, 3)); ``sky_shown`` (V, 3) from
        :meth:`sky_shown`."""
        weight = self.skies.weight[self.skies.row(light)]
        truth = master[self.valid].astype(np.float64) * weight
        err = (decoded[self.valid].astype(np.float64) * weight) - truth
        shown = float((sky_shown + truth).mean()) + float(
            self.direct_mean[self.lights.index(int(light))])
        return float(np.sqrt((err**2).mean()) / max(shown, 1e-30))
