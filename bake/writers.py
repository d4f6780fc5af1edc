"""The bake's write stage, one atlas or fixed view at a time: its stacks assembled from the
traced arrays (direct plus the bounce smoothed within each surface, gutters filled), written
as EXR masters and (through :class:`bake.compressor.Compressor`) compact textures, with the
sun-bounce stacks, the views' masks and depth; and the build's atomic swap into place.
Stacks are (H, W, n, 3) float32 irradiance or radiance per unit light radiance.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from bake.contact import (
    NEAR_SIGMA_TEXELS,
    continue_into_buried,
    continued_labels,
    extrapolate_direct,
    near_contact,
)
from bake.denoise import (
    MAX_CHANNELS,
    fill_from_nearest,
    smooth_within_labels,
    surface_labels,
)
from bake.dome import Dome
from bake.errors import BakeError
from bake.raytrace import Geometry
from bake.rowstore import StackStore, release_freed_memory
from bake.scene import Site
from bake.tracework import TracedResults, lookup_result
from bake.views import mask_image, radiance_image, virtual_depth_image
from daylit.stackio import CHANNEL_PATTERN, write_exr, write_stack_exr_by_rows

BOUNCE_SIGMA_TEXELS = 1.5  # smoothing of the indirect bounce within a surface (texels, pixels)
# An atlas's bounce is smoothed with a local linear fit (bake.denoise: no bias at a surface's
# edges, where the bounce beside a sunlit wall changes fastest); views keep the plain mean.
BOUNCE_ORDER = 1
# Lights of an atlas stack assembled at a time: at most one of the smoothing's channel blocks
# (three channels a light), fewer on a large atlas (:data:`ASSEMBLY_BYTES`).
LIGHT_BLOCK = MAX_CHANNELS // 3
# Bytes of one block of an atlas stack as it is assembled, (H, W, b, 3) float32: the block's
# traced arrays, its bounce image and the smoothing's copies are each about this size.
ASSEMBLY_BYTES = 256 << 20


@dataclass
class SunBounce:
    """What the sun-bounce stacks need (docs/sun.md, item 5): the lights the sun can be in
    (``compression.selectable_lights``, set once the compressor knows them), the dome's
    upward irradiance per light and the ground's albedo (the closed-form bounce of a hull
    plane's ``d``); ``enabled`` is False when the scene traces no bounce."""

    enabled: bool
    up: np.ndarray  # (n,)
    albedo: np.ndarray  # (3,)
    stack_names: list  # <atlas or view>.sun_bounce.<stack>, the report's rows
    lights: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    @classmethod
    def of(cls, site: Site, dome: Dome, atlases: dict) -> SunBounce:
        enabled = site.settings.bounce_rays > 0
        names = [
            f"{a.id}.sun_bounce.{stack}" for a in atlases.values() for stack in a.stacks
        ] + [
            f"{view.name}.sun_bounce.{stack}" for view in site.views for stack in ("O", "S")
        ] if enabled else []
        return cls(enabled, dome.cosine_weighted_sr, np.asarray(site.ground.albedo), names)

    def image(self, a, config, smoothed, coverage, block: slice = slice(None)) -> np.ndarray:
        """The one-bounce part of an atlas stack's lights ``block`` (of the n: (H, W, b, 3),
        b the block's lights), exactly as :func:`_atlas_image` adds it (``smoothed``: those
        lights' bounce as :func:`smooth_bounce` gave it, (H, W, b, 3); gutters filled here),
        for the lights the sun can be in; zero in the other columns (light i stays column
        i - block.start). The smoothing is done once for both: it treats each light's column
        on its own (Gaussian blurs and per-texel arithmetic), so its columns are those a
        smoothing of the sun's columns alone gave, bit for bit
        (tests/bake/test_sun_bounce.py); so is every step here, hence a stack made by blocks
        of lights is the stack made whole.
        ``"none"`` (a hull plane's ``d``) has the open ground's bounce in closed form,
        ``albedo E_up_i (1 - n_y) / 2`` (:meth:`Estimator.basis`)."""
        start, stop, _ = block.indices(len(self.up))
        lights = self.lights[(self.lights >= start) & (self.lights < stop)]
        columns = lights - start
        if config == "none":
            lower = 0.5 * (1.0 - a.normals[:, 1])
            part = a.to_image(
                (
                    lower[:, None, None]
                    * self.up[None, lights, None]
                    * self.albedo[None, None, :]
                ).astype(np.float32)
            )
        else:
            part = smoothed[:, :, columns]  # a copy: the gutters are filled in it
        part = _dilate(part, coverage, rings=3)
        image = np.zeros((a.height, a.width, stop - start, 3), dtype=np.float32)
        image[:, :, columns] = part
        return image

    def view_image(self, view, hits, smoothed: np.ndarray,
                   block: slice = slice(None)) -> np.ndarray:
        """The one-bounce part of a fixed view's O or S stack's lights ``block`` (H, W, b, 3)
        radiance, exactly as :func:`write_view` adds it: ``albedo / pi`` times the bounce
        ``smoothed`` (P, b, 3, from :func:`view_smoothed`) at the pixels that see a surface,
        for the lights the sun can be in; zero in the other columns, on the sky and on the
        open ground past the site (its radiance in the view is the dome's direct light
        alone, no bounce)."""
        start, stop, _ = block.indices(len(self.up))
        columns = self.lights[(self.lights >= start) & (self.lights < stop)] - start
        image = np.zeros((view.height * view.width, stop - start, 3), dtype=np.float32)
        image[hits.surface[:, None], columns[None, :]] = (
            hits.albedo[:, None, :] / np.pi * smoothed[:, columns]
        )
        return image.reshape(view.height, view.width, stop - start, 3)


def write_atlas(a, traced: TracedResults, staging: Path, compressor, sun_bounce,
                work: Path | None = None) -> dict:
    """Assemble an atlas's stacks (direct plus smoothed bounce, gutters filled), write their
    EXR masters and compact textures; then its sun-bounce stacks (the bounce alone, the
    sun's lights only: :class:`SunBounce`); returns the atlas's manifest entry.

    No step holds every light of a stack (issue 20): each stack is assembled by blocks of
    lights (:func:`atlas_light_block`), each block read from the traced chunks and written
    to disk in ``work`` (default: ``work`` beside ``staging``) as a
    :class:`bake.rowstore.StackStore`, which the EXR master, the sun's bounce and the
    compression read back by rows of texels (docs/benchmarks.md, "The write stage's
    memory")."""
    entry = {
        "id": a.id,
        "role": a.role,
        "width": a.width,
        "height": a.height,
        "texel_m": round(a.texel_m, 9),
        "stacks": {},
        "receivers": [r.manifest_entry() for r in a.receivers],
    }
    if a.d_reference:
        entry["d_reference"] = a.d_reference
    work = (staging.parent / "work" if work is None else Path(work)) / a.id
    coverage = a.coverage()
    labels = a.label_image()
    n = len(sun_bounce.up)
    stores, sun_entries = {}, {}
    try:
        for stack, config in a.stacks.items():
            store, sun_store = _assemble(a, stack, config, traced, n, coverage, labels,
                                         sun_bounce, work)
            stores[stack] = store
            rel = f"exr/{a.id}.{stack}.exr"
            _write_master(staging / rel, store)
            entry["stacks"][stack] = {
                "master": rel,
                "quantity": "irradiance",
                "channels": CHANNEL_PATTERN,
            }
            if sun_store is not None:
                # Written and compressed at once, judged as displayed with its sky stack
                # (bake.sunbounce), here while both are on disk.
                sun_entries.update(
                    _write_sun_bounce({stack: sun_store}, a.id, "exr", "irradiance", staging,
                                      compressor, {stack: store})
                )
                sun_store.remove()
        # Shadowing atlases show I / d: their two stacks are compressed together for it (the
        # compressor empties ``stores`` as it takes them).
        for stack, compact in compressor.run(dict(stores), a.id, staging).items():
            entry["stacks"][stack]["compact"] = compact
    finally:
        for store in stores.values():
            store.remove()
        shutil.rmtree(work, ignore_errors=True)
        release_freed_memory()
    if sun_entries:
        entry["sun_bounce"] = sun_entries
    return entry


def _assemble(a, stack, config, traced, n, coverage, labels, sun_bounce, work: Path):
    """One atlas stack and its sun-bounce stack (None without one) as
    :class:`StackStore` s in ``work``, made by blocks of lights: the traced arrays of a
    block are read from the chunks, their bounce smoothed, the gutters filled (every step
    treats each light on its own: the same values as the stack made whole)."""
    name = f"{a.id}.{stack}"
    names = {config, "bounce:" + config}
    blocks = light_blocks(n, atlas_light_block(a.height, a.width))
    # The buried texels are those no light reaches: one pass over the direct light first.
    seen = np.zeros(a.count, dtype=bool)
    if config != "none":
        for block in blocks:
            direct, bounce = lookup_result(traced.load(a.id, block, {config}), name, config)
            direct = extrapolate_direct(a, direct)
            seen |= direct.reshape(len(direct), -1).max(axis=1) > 0.0
            del direct
    open_labels = _open_labels(a, labels, seen, config)
    store = StackStore(work / stack, a.height, a.width, n)
    sun_store = None
    bounce_labels = _bounce_labels(a, open_labels)
    plans: dict = {}  # the smoothing's fit weights, the same for every block
    for block in blocks:
        direct, bounce = lookup_result(traced.load(a.id, block, names), name, config)
        if config != "none":  # texels moved onto contact lines: their chord (bake.contact)
            direct = extrapolate_direct(a, direct)
        with_sun = sun_bounce.enabled and (bounce is not None or config == "none")
        if with_sun and sun_store is None:
            sun_store = StackStore(work / f"sun_bounce.{stack}", a.height, a.width, n)
        # Smoothed once, for the stack and its sun-bounce stack (it took a quarter of the
        # write stage's time when done for each: docs/benchmarks.md).
        smoothed = (
            None if bounce is None
            else smooth_bounce(a.to_image(bounce), *bounce_labels, plans=plans)
        )
        del bounce
        store.write_block(block, _atlas_image(a, config, direct, smoothed, coverage,
                                              open_labels, plans.setdefault("direct", {})))
        del direct
        if with_sun:
            sun_store.write_block(block, sun_bounce.image(a, config, smoothed, coverage, block))
        del smoothed
        release_freed_memory()
    return store, sun_store


def _write_master(path: Path, store: StackStore) -> None:
    """A stack's EXR master from its store, a band of lines at a time."""
    h, w, n = store.height, store.width, store.n
    write_stack_exr_by_rows(
        path, h, w, n, lambda y0, y1: store.rows(y0 * w, y1 * w).reshape(y1 - y0, w, n, 3)
    )


def atlas_light_block(height: int, width: int) -> int:
    """Lights of an atlas stack assembled at a time: as many as keep one block's image
    (H, W, b, 3) float32 within :data:`ASSEMBLY_BYTES` (the smoothing holds several), at
    least one and at most :data:`LIGHT_BLOCK`."""
    return int(np.clip(ASSEMBLY_BYTES // (height * width * 3 * 4), 1, LIGHT_BLOCK))


def light_blocks(n: int, size: int | None = None) -> list[slice]:
    """The lights 0..n-1 in blocks of ``size`` (default :data:`LIGHT_BLOCK`)."""
    size = LIGHT_BLOCK if size is None else min(size, LIGHT_BLOCK)
    return [slice(i, min(i + size, n)) for i in range(0, n, size)]


def _atlas_image(a, config, direct, smoothed, coverage, labels, plan=None) -> np.ndarray:
    """An atlas stack (H, W, n, 3): direct plus the bounce ``smoothed`` (H, W, n, 3, from
    :func:`smooth_bounce`, or None), gutters filled. ``labels`` from :func:`_open_labels`
    (buried texels -2); ``plan`` kept for the stack's blocks (:func:`continue_into_buried`)."""
    # Buried texels along contact lines hold the visible side's light continued (bake.contact).
    image = continue_into_buried(_rgb(a.to_image(direct), config), labels, plan=plan)
    if smoothed is not None:
        image += smoothed
    return _dilate(image, coverage, rings=3)


def _open_labels(a, labels: np.ndarray, seen, config: str) -> np.ndarray:
    """The atlas's surface labels (H, W) with its *buried* texels (inside another solid: no
    light from any patch of the dome reaches them, e.g. the ground under a building: not
    ``seen``, (count,) bool over the atlas's texels) marked ``-2 - label``: the bounce's
    smoothing leaves them out (:func:`smooth_bounce`)."""
    if config == "none":
        return labels  # nothing casts: nothing is buried
    seen = a.to_image(seen)
    out = labels.copy()
    buried = (labels >= 0) & ~seen
    out[buried] = -2 - labels[buried]
    return out


def _bounce_labels(a, labels: np.ndarray) -> tuple:
    """``labels`` from :func:`_open_labels` with the texels moved onto contact lines marked
    buried too (their bounce was traced at the contact line, not at their centre: kept out
    of the smoothing, bake.contact), and those texels as (rows, columns) or None."""
    contact = getattr(a, "contact", None)
    if not contact or len(contact["texel"]) == 0:
        return labels, None
    out = labels.copy()
    x, y = a.texels[contact["texel"], 0], a.texels[contact["texel"], 1]
    moved = out[y, x] >= 0
    out[y[moved], x[moved]] = -2 - out[y[moved], x[moved]]
    return out, (y[moved], x[moved])


def smooth_bounce(image: np.ndarray, labels: np.ndarray, moved=None,
                  plans: dict | None = None) -> np.ndarray:
    """An atlas's traced bounce (H, W, ...) smoothed within each surface by a local linear
    fit (:data:`BOUNCE_ORDER`) over its open texels, with a narrower kernel near contact
    lines; texels ``moved`` onto contact lines ((rows, columns), marked buried in
    ``labels``: :func:`_bounce_labels`) keep their traced bounce, smoothed along their strip
    only (96 rays leave a texel's bounce about 10 % noisy); other buried texels
    (label ``-2 - label``, :func:`_open_labels`) next to open ones hold the fit continued,
    the rest the value of the nearest of those, so bilinear filtering at a wall's foot reads
    the open side's bounce only (bake.contact, bake.denoise)."""
    plans = {} if plans is None else plans  # fit weights kept for the same labels' blocks
    smoothed = smooth_within_labels(image, labels, BOUNCE_SIGMA_TEXELS, order=BOUNCE_ORDER,
                                    plan=plans.setdefault("open", {}))
    near = near_contact(labels)
    if near.any():
        fine = smooth_within_labels(image, labels, NEAR_SIGMA_TEXELS, order=BOUNCE_ORDER,
                                    plan=plans["open"], only=near)
        smoothed[near] = fine[near]
    smoothed = continue_into_buried(smoothed, labels, plan=plans.setdefault("continued", {}))
    keep = continued_labels(labels)
    if moved is not None:
        # The moved texels form strips along the contact lines: their bounce, traced there,
        # is smoothed along each strip only (a strip per surface), never with the open side.
        surface = np.where(labels <= -2, -2 - labels, labels)
        strips = np.full(labels.shape, -1, dtype=labels.dtype)
        strips[moved] = surface[moved]
        along = smooth_within_labels(image, strips, BOUNCE_SIGMA_TEXELS, order=BOUNCE_ORDER,
                                     plan=plans.setdefault("strips", {}))
        smoothed[moved] = along[moved]
        keep[moved] = True
    surface = np.where(labels <= -2, -2 - labels, labels)
    return fill_from_nearest(smoothed, surface, keep)


def _rgb(direct: np.ndarray, config: str) -> np.ndarray:
    """Direct light with RGB last, (..., n, 3): a traced configuration's is grey, (..., n),
    and is repeated for R, G, B; ``"none"``'s already has RGB (:meth:`Estimator.basis`)."""
    return direct if config == "none" else np.repeat(direct[..., None], 3, axis=-1)


def write_view(
    view, hits: dict, traced: TracedResults, geometry, dome, site, staging: Path, compressor,
    sun_bounce=None,
) -> dict:
    """Assemble a view's O and S (direct plus smoothed bounce), mask and virtual depth, write
    them and the compact textures, and their sun-bounce stacks (the bounce alone, the sun's
    lights only: :meth:`SunBounce.view_image`, for the kiosk's sun: docs/sun.md); returns the
    view's manifest entry."""
    entry = {
        "id": view.name,
        "width": view.width,
        "height": view.height,
        "K": [[round(float(x), 9) for x in row] for row in view.K],
        "world_from_camera": [[round(float(x), 9) for x in row] for row in view.world_from_camera],
        "camera_convention": "opencv",
        "stacks": {},
    }
    up = dome.cosine_weighted_sr
    n = len(up)
    work = staging.parent / "work" / view.name
    blocks = light_blocks(n, atlas_light_block(view.height, view.width))
    sun_entries = {}
    try:
        for stack, config in (("O", "all"), ("S", "real")):
            # By blocks of lights, as an atlas's stacks (every step treats each light on its
            # own: the same values as the stack made whole).
            store = StackStore(work / stack, view.height, view.width, n)
            sun_store = None
            for block in blocks:
                results = traced.load(view.name, block, {config, "bounce:" + config})
                direct, bounce = lookup_result(results, f"{view.name}.{stack}", config)
                del results
                E = _rgb(direct, config)
                if bounce is not None:
                    smoothed = view_smoothed(view, hits[stack], bounce, geometry)
                    E += smoothed
                    if sun_bounce is not None and sun_bounce.enabled:
                        if sun_store is None:
                            sun_store = StackStore(work / f"sun_bounce.{stack}", view.height,
                                                   view.width, n)
                        sun_store.write_block(
                            block, sun_bounce.view_image(view, hits[stack], smoothed, block)
                        )
                    del smoothed
                store.write_block(
                    block, radiance_image(view, hits[stack], E, up[block], site.ground.albedo)
                )
                del E, direct, bounce
            rel = f"views/{view.name}.{stack}.exr"
            _write_master(staging / rel, store)
            if sun_store is not None:  # judged as displayed with its sky stack
                sun_entries.update(_write_sun_bounce(
                    {stack: sun_store}, view.name, "views", "radiance", staging, compressor,
                    {stack: store}, view=True))
                sun_store.remove()
            entry["stacks"][stack] = {
                "master": rel,
                "quantity": "radiance",
                "channels": CHANNEL_PATTERN,
                "compact": compressor.run({stack: store}, view.name, staging)[stack],
            }
            store.remove()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if sun_entries:
        entry["sun_bounce"] = sun_entries
    entry["mask"] = f"views/{view.name}.mask.png"
    _write_png(staging / entry["mask"], mask_image(view, hits["O"]))
    entry["depth"] = f"views/{view.name}.depth.exr"
    _write_depth(staging / entry["depth"], virtual_depth_image(view, hits["O"]))
    return entry


def view_smoothed(view, hits, bounce: np.ndarray, geometry: Geometry) -> np.ndarray:
    """The bounce at a view's hit points (P, n, 3), smoothed in image space within the flat
    surface each pixel sees."""
    h, w = view.height, view.width
    image = np.zeros((h * w,) + bounce.shape[1:], dtype=np.float32)
    image[hits.surface] = bounce
    labels = np.full(h * w, -1, dtype=np.int64)
    labels[hits.surface] = surface_labels(geometry.part[hits.faces], hits.normals)
    smoothed = smooth_within_labels(
        image.reshape((h, w) + bounce.shape[1:]), labels.reshape(h, w), BOUNCE_SIGMA_TEXELS
    )
    return smoothed.reshape((h * w,) + bounce.shape[1:])[hits.surface]


def _dilate(image: np.ndarray, coverage: np.ndarray, rings: int) -> np.ndarray:
    """Fill up to ``rings`` texels around covered ones with their covered neighbours' mean,
    so bilinear filtering at chart borders never blends in empty texels."""
    covered = coverage.copy()
    h, w = covered.shape
    for _ in range(rings):
        grown = cv2.dilate(covered.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        ring = np.argwhere(grown & ~covered)
        if len(ring) == 0:
            break
        total = np.zeros((len(ring),) + image.shape[2:], dtype=np.float64)
        count = np.zeros(len(ring))
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)):
            y = np.clip(ring[:, 0] + dy, 0, h - 1)
            x = np.clip(ring[:, 1] + dx, 0, w - 1)
            ok = covered[y, x]
            total[ok] += image[y[ok], x[ok]]
            count += ok
        image[ring[:, 0], ring[:, 1]] = (
            total / count.reshape((-1,) + (1,) * (total.ndim - 1))
        ).astype(image.dtype)
        covered = grown
    return image


def _write_png(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):
        raise BakeError(f"could not write {path}")


def _write_depth(path: Path, depth: np.ndarray) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIPS_COMPRESSION, "type": OpenEXR.scanlineimage}
    write_exr(path, header, {"Z": np.ascontiguousarray(depth, dtype=np.float32)})


def swap_into_place(staging: Path, out_dir: Path) -> None:
    """Replace ``out_dir`` by ``staging`` with renames only (same file system)."""
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    old = None
    if out_dir.exists():
        old = out_dir.parent / f".{out_dir.name}.old-{os.getpid()}"
        os.replace(out_dir, old)
    os.replace(staging, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _write_sun_bounce(sun_images: dict, owner: str, folder: str, quantity: str, staging: Path,
                      compressor, sky_images: dict, view: bool = False) -> dict:
    """Write and compress an atlas's or a view's sun-bounce stacks (``sun_images``: stack ->
    :class:`StackStore`, emptied as they are written) as
    ``<folder>/<owner>.sun_bounce.<stack>.exr`` masters and their compact images, each
    judged as displayed with its sky stack (``sky_images``: stack -> :class:`StackStore`;
    ``view``: a fixed view's, :meth:`Compressor.run_sun_bounce`); the manifest entries of the
    stacks that are not zero everywhere."""
    entries = {}
    for stack in list(sun_images):
        image = sun_images.pop(stack)
        name = f"{owner}.sun_bounce.{stack}"
        rel = f"{folder}/{name}.exr"
        _write_master(staging / rel, image)
        compact = compressor.run_sun_bounce(image, name, staging, master=rel,
                                            sky=sky_images.get(stack), view=view)
        if compact is not None:
            entries[stack] = {
                "master": rel,
                "quantity": quantity,
                "channels": CHANNEL_PATTERN,
                "compact": compact,
            }
    return entries
