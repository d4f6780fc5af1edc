"""Compression of the sun-bounce stacks (docs/sun.md, item 5): one image per light the sun
can be in, each its column as it is (no base, no gain), encoded and checked as the client
decodes it.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from bake.basisu import encode
from bake.compact_reader import CompactReader
from bake.compress import CompactStack
from bake.ktx2decoder import decode
from bake.quantize import quantized_png, refinement_png

SUN_BOUNCE_DECODE_CHUNK = 16  # light images decoded at a time (memory: the lightmap is large)


def compress_sun_bounce(image, name, out_dir, lights, settings) -> CompactStack | None:
    """Compress a sun-bounce stack ``image`` (H, W, n, 3), whose columns outside ``lights``
    (the patches the sun can be in) are zero, into one image per light of ``lights``: its
    column, as it is (no base, no gain, no ``d - I``).

    The sun's bounce is one column at a time (the sun's patch ``p``: ``E_sun /
    solid_angle_p`` times column ``p``), so a client fetches that column's image alone, on
    demand, as it fetches a selected light's own image of an ordinary stack; a low-rank base
    would have to be downloaded whole, and the columns are not low rank anyway (docs/sun.md,
    item 5).

    Each image is encoded exactly as the ordinary stacks' light images
    (:func:`bake.compress.compress_stack`): quantized to 8 bits with its own scale and
    offset, encoded at UASTC level ``settings.uastc_level``, decoded, and what was lost
    encoded again as a refinement at level ``settings.refine_level``. Every column is then
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
    # refine_level), not the RMS stacks' cheaper refinement (rms_refine_level): a column's
    # refinement is noise-like, and level 1 cut the worst column's error for a few per cent
    # more bytes (docs/benchmarks.md, "Figures behind choices in the code").
    image_settings = settings
    (out_dir / "ktx2").mkdir(exist_ok=True)
    light_files = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        coarse_dir, refine_dir = tmp / "coarse", tmp / "refine"
        coarse_dir.mkdir()
        refine_dir.mkdir()
        coarse_q = [
            quantized_png(image[:, :, i], tmp / f"{name}.L{i:04d}.png") for i in lights
        ]
        encode([q.path for q in coarse_q], coarse_dir, image_settings, array=False)
        refine_q = []
        for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
            chunk = lights[start : start + SUN_BOUNCE_DECODE_CHUNK]
            decoded = decode([coarse_dir / f"{name}.L{i:04d}.ktx2" for i in chunk])
            for j, i in enumerate(chunk):
                coarse = coarse_q[start + j].value(decoded[j][0])
                refine_q.append(
                    refinement_png(image[:, :, i] - coarse, tmp / f"{name}.L{i:04d}r.png", None)
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
