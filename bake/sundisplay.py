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
TEXEL_PERCENTILE = 99.0  # DisplayCheck.texel_error's
# The error at single texels (DisplayCheck.texel_error, its 99th percentile) a choice that
# trades fidelity for bytes may make (sharing a group's image, a codec cheaper than plain
# UASTC), per unit of the RMS budget: the 99th percentile of |e| for an error spread as a
# normal one at the budget's RMS (2.576 sigma). An RMS budget alone lets a choice spend it
# on a few texels (blocky codecs in shade, a neighbour's bounce pattern on the ground); plain
# UASTC images are not held to it: they are what the choices are measured against.
TEXEL_BOUND_PER_BUDGET = 2.576


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
    stack's non-zero ones). Two measures: the RMS error over the mean of that displayed
    value (:meth:`error`, the budget's), and the error at single texels, each over the
    value displayed there (:meth:`texel_error`, its 99th percentile).

    The sun's direct term (drawn apart by the client, from its shadow map) is estimated from
    the stacks themselves when ``bounce`` (the sun-bounce stack, H, W, n, 3, each patch's own
    column, not shared) is given: the sky stack's column ``p`` holds the sun's direct light
    and its bounce for patch ``p``, so ``max(sky_p - bounce_p, 0)`` times the display sky's
    weight ``E_sun / solid_angle_p`` is the direct term with the sun spread over its patch.
    It adds to what is displayed, not to the error (the client draws it itself, exactly);
    its soft shadow edges, where the client's are sharp, move a texel's displayed value
    near an edge, not the mean (docs/sun.md, "Judged with the sun's direct term"). Without
    ``bounce`` the direct term is left out (as before 2026-12-06: every error then larger,
    the judge stricter than what a visitor sees).

    What is displayed but the bounce (the relit sky plus the direct term) is made for every
    light of ``lights`` in one pass over the sky stack's rows (for each block of rows, a
    matrix product per channel for every light at once) and kept, (len(lights), V, 3) float64:
    in memory, or beside a stack on disk."""

    def __init__(self, sky, skies: DisplaySkies, lights, bounce=None):
        sky = as_stack(sky)
        self.valid = sky.valid
        # The valid texels' flat indices: a gather by them is a third of a boolean mask's
        # time on an atlas, and the judge gathers two images per call.
        self.valid_index = np.flatnonzero(self.valid)
        self.skies = skies
        self.lights = [int(i) for i in lights]
        V = int(self.valid.sum())
        stacks = [sky] if bounce is None else [sky, as_stack(bounce)]
        if sky.work is not None:
            self.shown = RowFile.create(sky.work / f"sky-shown-{id(self)}.npy",
                                        (len(self.lights) * V, 3), np.float64)
        else:
            self.shown = np.empty((len(self.lights) * V, 3), dtype=np.float64)
        self.V = V
        rows = [self.skies.row(p) for p in self.lights]
        weights = self.skies.weight[rows]  # (L, 3)
        # Each channel's display skies, (n, L) float32: one matrix product per block of rows
        # and channel relights every light at once.
        relight = [np.ascontiguousarray(self.skies.r[rows, :, c].T, dtype=np.float32)
                   for c in range(3)]
        for t, block in valid_blocks(stacks, self.valid):
            direct = None
            if bounce is not None:
                direct = np.take(block[0], self.lights, axis=1)
                direct -= np.take(block[1], self.lights, axis=1)
                np.clip(direct, 0.0, None, out=direct)
            # (3, b, n) per channel, contiguous for the products.
            per_channel = np.stack([block[0][..., c] for c in range(3)])
            del block
            # Every light's rows of this block at once: (L, b, 3) float64, b bounded by the
            # block (bake.rowstore.row_block), not by the site (about 65 MB at 194 lights).
            out = np.empty((len(self.lights), per_channel.shape[1], 3), dtype=np.float64)
            for c in range(3):
                out[:, :, c] = (per_channel[c] @ relight[c]).T
            del per_channel
            if direct is not None:
                out += direct.transpose(1, 0, 2) * weights[:, None, :]
            for j in range(len(self.lights)):
                at = j * V + t
                if isinstance(self.shown, RowFile):
                    self.shown.write(at, out[j])
                else:
                    self.shown[at : at + len(out[j])] = out[j]

    def shown_but_bounce(self, lights) -> np.ndarray:
        """(len(lights), V, 3) what is displayed with the sun in each light's patch but its
        bounce: the sky stack relit with the light's display sky plus the sun's direct
        term."""
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

    def _displayed(self, light: int, but_bounce: np.ndarray, master, decoded):
        """(V, 3) the displayed value with the sun in ``light``'s patch and the error
        ``decoded`` instead of ``master`` (both (H, W, 3)) makes in it;
        ``but_bounce`` (V, 3) from :meth:`shown_but_bounce`."""
        weight = self.skies.weight[self.skies.row(light)]
        truth = np.multiply(self._at_valid(master), weight, dtype=np.float64)
        err = np.multiply(self._at_valid(decoded), weight, dtype=np.float64)
        err -= truth
        return but_bounce + truth, err

    def _at_valid(self, image: np.ndarray) -> np.ndarray:
        """(V, 3) ``image`` (H, W, 3) at the valid texels, in row-major order (as
        ``image[self.valid]``)."""
        return np.take(image.reshape(-1, 3), self.valid_index, axis=0)

    def error(self, light: int, but_bounce: np.ndarray, master, decoded) -> float:
        """RMS error over the mean of the displayed value with the sun in ``light``'s patch
        (the relit sky, the direct term, the bounce), when its column is ``decoded`` instead
        of ``master`` (both (H, W, 3)); ``but_bounce`` (V, 3) from
        :meth:`shown_but_bounce`."""
        shown, err = self._displayed(light, but_bounce, master, decoded)
        return _rms_over_mean(shown, err)

    def texel_error(self, light: int, but_bounce: np.ndarray, master, decoded) -> float:
        """The error at single texels that :meth:`error`'s mean hides: the 99th percentile,
        over the receiver texels and channels, of ``|error|`` over the value displayed there,
        that value floored at a tenth of its mean (a texel in deep shade is not judged
        against nothing; as benchmarks/sun_bounce_display.py's judge)."""
        shown, err = self._displayed(light, but_bounce, master, decoded)
        return _texel_p99(shown, err)

    def errors(self, light: int, but_bounce: np.ndarray, master, decoded
               ) -> tuple[float, float]:
        """(:meth:`error`, :meth:`texel_error`), the displayed value made once."""
        shown, err = self._displayed(light, but_bounce, master, decoded)
        return _rms_over_mean(shown, err), _texel_p99(shown, err)


def _rms_over_mean(shown: np.ndarray, err: np.ndarray) -> float:
    return float(np.sqrt((err**2).mean()) / max(float(shown.mean()), 1e-30))


def _texel_p99(shown: np.ndarray, err: np.ndarray) -> float:
    if not len(shown):
        return 0.0
    floor = max(0.1 * float(shown.mean()), 1e-30)
    return float(np.percentile(np.abs(err) / np.maximum(shown, floor), TEXEL_PERCENTILE))


def max_median(values: np.ndarray) -> dict:
    """``{"max", "median"}`` of ``values``, rounded as the manifest records errors."""
    return {"max": round(float(values.max()), 6), "median": round(float(np.median(values)), 6)}
