"""Equirectangular sky maps: reading them (OpenEXR) and turning them into a light vector.

A map is linear RGB radiance in W/(m^2 sr), twice as wide as high, in the site frame (+X east,
+Y up, -Z north; :func:`daylit.sky.direction_from_azimuth_elevation`):

- row ``i`` of ``H`` spans elevations from ``90 - 180 i / H`` down to ``90 - 180 (i + 1) / H``
  degrees: row 0 touches the zenith, the last row the nadir;
- column ``j`` of ``W = 2 H`` spans azimuths from ``360 j / W`` to ``360 (j + 1) / W`` degrees,
  clockwise from north: column 0 starts at north, column ``W / 4`` at east.

Each pixel stands for a constant radiance over its own patch of the sphere. The light vector
``r_i`` is then the exact solid-angle weighted mean of the map over dome patch ``i``: every
pixel is split into ``s x s`` sub-cells (enough for about 1024 rows in all, so a sub-cell is
under 0.2 degrees), each sub-cell goes to the patch holding its centre
(:class:`daylit.spherical.PatchLookup`) with its exact solid angle
``d_azimuth * (sin(el_top) - sin(el_bottom))``. The lower hemisphere is ignored, as the dome
has no patches there.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from daylit.sky import direction_from_azimuth_elevation
from daylit.spherical import PatchLookup

SUB_ROWS_TARGET = 1024  # rows of sub-cells over the whole map, pole to pole
MAX_SUBDIVISION = 8
_LOOKUP_BATCH = 1 << 16


class EnvMapError(ValueError):
    """A sky map that cannot be read or does not follow the conventions above."""


def read_equirect_exr(path: Path | str) -> np.ndarray:
    """An equirectangular RGB map from an OpenEXR file: ``(H, W, 3)`` float64, W/(m^2 sr).

    Raises :class:`EnvMapError` (naming the file and what to do) if the file is missing or
    unreadable, lacks R, G and B channels, is not twice as wide as high, or holds negative or
    non-finite values.
    """
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise EnvMapError(f"{path}: no such file; give an equirectangular OpenEXR sky map")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            channels = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    except Exception as exc:  # OpenEXR raises bare RuntimeErrors with its own words
        raise EnvMapError(f"{path}: not a readable OpenEXR file ({exc})") from None
    missing = [c for c in "RGB" if c not in channels]
    if missing:
        raise EnvMapError(
            f"{path}: needs R, G and B channels (linear radiance), found "
            f"{sorted(channels)}; save the map as an RGB EXR"
        )
    image = np.stack([channels[c] for c in "RGB"], axis=-1).astype(np.float64)
    check_equirect(image, str(path))
    return image


def check_equirect(image: np.ndarray, name: str = "sky map") -> None:
    """Raise :class:`EnvMapError` unless ``image`` is an ``(H, 2H, 3)`` map of finite,
    non-negative radiances."""
    if image.ndim != 3 or image.shape[2] != 3:
        raise EnvMapError(f"{name}: an RGB map needs shape (H, W, 3), got {image.shape}")
    h, w = image.shape[:2]
    if h < 2 or w != 2 * h:
        raise EnvMapError(
            f"{name}: an equirectangular map is twice as wide as high, got {w} x {h} pixels; "
            "resample it to 2:1 (e.g. 1024 x 512)"
        )
    if not np.all(np.isfinite(image)):
        raise EnvMapError(f"{name}: holds NaN or infinite values; fix or clamp them")
    if np.any(image < 0.0):
        raise EnvMapError(f"{name}: holds negative radiances; a sky map is linear and >= 0")


def subdivision(height: int) -> int:
    """Sub-cells per pixel side for a map ``height`` rows high (1 to 8)."""
    return int(np.clip(-(-SUB_ROWS_TARGET // height), 1, MAX_SUBDIVISION))


def pixel_directions(height: int) -> tuple[np.ndarray, np.ndarray]:
    """A map ``height`` rows high (width ``2 height``): its pixel centres' unit directions
    (H, 2H, 3) and their solid angles (H, 2H) sr (the conventions above)."""
    el_edges_deg = 90.0 - 180.0 * np.arange(height + 1) / height
    el_deg = 0.5 * (el_edges_deg[:-1] + el_edges_deg[1:])
    az_deg = 360.0 * (np.arange(2 * height) + 0.5) / (2 * height)
    el, az = np.meshgrid(el_deg, az_deg, indexing="ij")
    band_sr = (np.pi / height) * (np.sin(np.radians(el_edges_deg[:-1]))
                                  - np.sin(np.radians(el_edges_deg[1:])))
    return direction_from_azimuth_elevation(az, el), np.repeat(band_sr[:, None], 2 * height, 1)


def equirect_light_vector(image: np.ndarray, patch_vertices: np.ndarray) -> np.ndarray:
    """The light vector of a map: solid-angle weighted mean radiance per patch, ``(n, 3)``.

    Parameters
    ----------
    image : (H, 2H, 3) float, linear RGB radiance in W/(m^2 sr) (conventions above)
    patch_vertices : (n, 3, 3) float, the dome's unit patch vertices (manifest order)
    """
    image = np.asarray(image, dtype=np.float64)
    check_equirect(image)
    h, w = image.shape[:2]
    s = subdivision(h)
    rows = (h * s + 1) // 2  # sub-rows reaching at least down to the horizon
    el_edges_deg = 90.0 - 180.0 * np.arange(rows + 1) / (h * s)
    el_centre_deg = 0.5 * (el_edges_deg[:-1] + el_edges_deg[1:])
    band_sr = (2.0 * np.pi / (w * s)) * (
        np.sin(np.radians(el_edges_deg[:-1])) - np.sin(np.radians(el_edges_deg[1:]))
    )
    az_centre_deg = 360.0 * (np.arange(w * s) + 0.5) / (w * s)
    lookup = PatchLookup(patch_vertices)
    n = len(patch_vertices)
    total = np.zeros((n, 3))
    weight = np.zeros(n)
    rows_per_batch = max(1, _LOOKUP_BATCH // (w * s))
    for start in range(0, rows, rows_per_batch):
        sub_rows = np.arange(start, min(rows, start + rows_per_batch))
        el, az = np.meshgrid(el_centre_deg[sub_rows], az_centre_deg, indexing="ij")
        patch = lookup(direction_from_azimuth_elevation(az, el).reshape(-1, 3))
        sr = np.repeat(band_sr[sub_rows], w * s)
        radiance = image[sub_rows // s][:, np.arange(w * s) // s].reshape(-1, 3)
        keep = patch >= 0
        weight += np.bincount(patch[keep], weights=sr[keep], minlength=n)
        for c in range(3):
            total[:, c] += np.bincount(
                patch[keep], weights=(sr * radiance[:, c])[keep], minlength=n
            )
    if np.any(weight <= 0.0):
        raise EnvMapError(f"a {w} x {h} map leaves some dome patches without a sample")
    return total / weight[:, None]


def write_equirect_exr(path: Path | str, image: np.ndarray) -> None:
    """Write an ``(H, 2H, 3)`` radiance map as a float32 RGB OpenEXR (tests, tools)."""
    import OpenEXR

    from daylit.stackio import write_exr

    image = np.asarray(image, dtype=np.float32)
    check_equirect(image)
    channels = {c: np.ascontiguousarray(image[:, :, k]) for k, c in enumerate("RGB")}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    write_exr(path, header, channels)
