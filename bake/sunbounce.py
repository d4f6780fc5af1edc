"""Compression of the sun-bounce stacks (docs/sun.md, item 5): one image per light the sun
can be in, each its column as it is (no base, no gain), encoded and checked as the client
decodes it; a light's refinement image is kept only where its coarse image alone would show
as displayed (the judge: bake.sundisplay). Neighbouring patches may share one image, their
solid-angle mean (bake.sunshare; docs/sun.md, "Shared images"), and what that costs each
patch as displayed is recorded.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bake.basisu import encode
from bake.compress import CompactStack
from bake.ktx2decoder import decode
from bake.quantize import quantized_png, refinement_png
from bake.rowstore import as_stack
from bake.sundisplay import (
    SUN_BOUNCE_DECODE_CHUNK,
    DisplayCheck,
    DisplaySkies,
    max_median,
)
from bake.sunshare import (
    SharedColumns,
    SharedImages,
    codec_texel_bounds,
    groups_within,
    share_entry,
)
from bake.sunwritten import ReadBack, read_back

# How many of a stack's sun-bounce images are tried in cheaper encodings before the rest
# (_cheaper_within).
CHEAPER_SAMPLE = 16
# Where plain UASTC's own error at single texels is over the bound (the models' faces: its
# 99th percentile per texel is 4-12 % there, dark texels), a cheaper encoding may not be
# held to the bound, which nothing meets: it may be at most this much worse than plain's
# own instead (1.15: UASTC with RDO lambda 0.1 is 10-14 % worse and 18 % smaller on the
# demo's lightmap; lambda 0.25 29-41 % worse; docs/benchmarks.md, "The phone's visit under
# 4 MB").
PLAIN_TEXEL_SLACK = 1.15


def compress_sun_bounce(image, name, out_dir, lights, settings, sky=None,
                        skies: DisplaySkies | None = None,
                        shared: SharedImages | None = None) -> CompactStack | None:
    """Compress a sun-bounce stack ``image`` (H, W, n, 3), whose columns outside ``lights``
    (the patches the sun can be in) are zero, into one image per light of ``lights``: its
    column, as it is (no base, no gain, no ``d - I``).

    The sun's bounce is one column at a time (the sun's patch ``p``: ``E_sun /
    solid_angle_p`` times column ``p``), so a client fetches that column's image alone, on
    demand, as it fetches a selected light's own image of an ordinary stack; a low-rank base
    would have to be downloaded whole, and the columns are not low rank anyway (docs/sun.md,
    item 5).

    Each image is encoded as the ordinary stacks' light images
    (:func:`bake.compress.compress_stack`): quantized to 8 bits with its own scale and
    offset, encoded at UASTC level ``settings.uastc_level`` and decoded. Where the coarse
    image alone is off by more than ``settings.sun_bounce_budget`` as displayed
    (:class:`DisplayCheck`: ``sky`` (H, W, n, 3), the same atlas's or view's sky stack,
    relit with ``skies``' clear sky for that patch, plus the sun's direct term estimated
    from the sky stack's and ``image``'s column, plus the bounce) it is encoded again at
    level ``settings.sun_bounce_level``, and where that is still off, what was lost is
    encoded as a refinement at level ``settings.refine_level``; without ``sky`` and
    ``skies``, or with the budget None, every light keeps its refinement. Every column is
    then decoded as the client decodes it and checked against the master
    (:func:`bake.sunwritten.read_back`): RMS error over the stack's valid texels relative to
    the column's mean there, and as displayed.

    With ``shared`` (:class:`SharedImages`) the lights of a group share one image, their
    group's (:class:`SharedColumns`): only the representatives are encoded and judged (each
    against its group's column, under its own display sky), and the entry lists every
    member (:func:`share_entry`), each with its own gain per channel against its own column
    (:func:`bake.sunwritten.read_back`).

    Writes ``ktx2/<name>.L<i>.ktx2`` for each light ``i`` of ``lights`` and
    ``ktx2/<name>.L<i>r.ktx2`` for those that keep a refinement. Returns the
    :class:`CompactStack` (entry ``{"k": 0, "lights", "error"}``: ``lights.ktx2`` one pattern
    per level any light has, ``scale[i]`` / ``offset[i]`` one entry per level light ``i`` has;
    ``error`` holds ``max`` and ``median`` over the columns, the ``worst_light``, the number
    of ``test_lights``, and when judged ``displayed``: ``max``, ``median``, ``worst_light``,
    ``budget`` and ``refined`` lights), or ``None`` when the stack is zero everywhere."""
    started = time.perf_counter()
    image = as_stack(image)
    H, W, n, _ = image.shape
    lights = np.asarray(lights, dtype=int)
    valid = image.valid
    if not valid.any() or len(lights) == 0:
        return None
    own = image  # each patch's own column: the direct term's estimate (DisplayCheck)
    budget = settings.sun_bounce_budget
    # One judge, one pass over the sky stack: with shared images it holds every drawn light,
    # the groups checked with it, the representatives' images judged with it and then every
    # member's error against its own column (read_back).
    judged = lights
    if shared is not None:
        drawn = set(lights.tolist())
        shared = SharedImages({rep: [q for q in members if q in drawn]
                               for rep, members in shared.groups.items() if rep in drawn},
                              shared.solid_angles_sr, shared.kind, shared.frequency)
        judged = sorted(drawn)
    check = (DisplayCheck(sky, skies, judged, bounce=own)
             if sky is not None and skies is not None else None)
    split_out = 0
    if shared is not None:
        if (check is not None and budget is not None
                and settings.sun_bounce_sharing == "within_budget"):
            grouped = len(shared.groups)
            shared = groups_within(shared, own, check, budget)
            split_out = len(shared.groups) - grouped
        image = SharedColumns(image, shared)
        lights = np.asarray(shared.representatives, dtype=int)
    texel_bounds = codec_texel_bounds(lights, budget, shared) if budget is not None else None
    try:
        result, judged_record = _compress_columns(image, name, out_dir, lights, settings,
                                                  check, budget, texel_bounds, started)
        entry = result.entry
        if shared is not None:
            share_entry(entry, shared, n)
            entry["shared"]["split_out"] = split_out
        # Every image decoded once, each against the column it was made of and, shared,
        # each member given its gain and judged against its own column (bake.sunwritten).
        measured = read_back(out_dir, entry, own, lights, check, shared)
        entry["error"].update(_error_record(lights, measured, judged_record))
        if shared is not None:
            entry["shared"]["gains"] = list(measured.gains)
            if check is not None:
                entry["error"]["displayed"]["shared"] = measured.shared_record(
                    check.lights, budget)
        return result
    finally:
        if check is not None:
            check.remove()


def _compress_columns(image, name, out_dir, lights, settings, check, budget, texel_bounds,
                      started):
    """:func:`compress_sun_bounce` once its stack (a :mod:`bake.rowstore` stack) and its
    check are ready; its columns read a chunk of lights at a time. ``texel_bounds``: {light:
    the bound at single texels on a cheaper codec} (:func:`bake.sunshare.codec_texel_bounds`).
    """
    H, W, n, _ = image.shape
    judged = check is not None and budget is not None
    # The selected lights' images' two levels (coarse at uastc_level, refinement at
    # refine_level), not the RMS stacks' cheaper refinement (rms_refine_level): a column's
    # refinement is noise-like, and level 1 cut the worst column's error for a few per cent
    # more bytes (docs/benchmarks.md, "Figures behind choices in the code").
    image_settings = settings
    (out_dir / "ktx2").mkdir(exist_ok=True)
    light_files = []
    refined: list[int] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        coarse_dir, refine_dir = tmp / "coarse", tmp / "refine"
        coarse_dir.mkdir()
        refine_dir.mkdir()
        coarse_q = {}
        for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
            chunk = [int(i) for i in lights[start : start + SUN_BOUNCE_DECODE_CHUNK]]
            for i, column in zip(chunk, image.columns(chunk), strict=True):
                coarse_q[i] = quantized_png(column, tmp / f"{name}.L{i:04d}.png")
        # The coarse image: UASTC at uastc_level, or a smaller encoding where one is within
        # the budget as displayed (_cheaper_within); the lights still over the budget are
        # encoded again at each later level of the ladder (the same 8-bit image: the same
        # scale and offset), and those over it after the last are refined against it
        # (docs/compact-assets.md, "The sun's bounce"). Not judged: the first level alone,
        # every light refined.
        ladder = coarse_levels(settings) if judged else coarse_levels(settings)[:1]
        first_settings, first_level = ladder[0]
        encode([q.path for q in coarse_q.values()], coarse_dir, first_settings, array=False,
               level=first_level)
        cheaper = _cheaper_within(lights, coarse_dir, name, coarse_q, image, check, budget,
                                  texel_bounds, settings, tmp) if judged else {}
        refine_q = {}
        over = [int(i) for i in lights if int(i) not in cheaper]
        for step, (step_settings, level) in enumerate(ladder):
            if step:
                step_dir = tmp / f"coarse{step}"
                step_dir.mkdir()
                encode([coarse_q[i].path for i in over], step_dir, step_settings,
                       array=False, level=level)
                for i in over:
                    shutil.move(step_dir / f"{name}.L{i:04d}.ktx2",
                                coarse_dir / f"{name}.L{i:04d}.ktx2")
            last = step == len(ladder) - 1
            over = _shown_coarse(over, coarse_dir, name, coarse_q, image,
                                 check if judged else None, budget,
                                 refine_q if last else None, tmp)
            if not over:
                break
        refined.extend(over)
        if refine_q:
            encode(
                [q.path for q in refine_q.values()], refine_dir, image_settings, array=False,
                level=image_settings.refine_level,
            )
        for i in lights:
            for folder, suffix in ((coarse_dir, ""), (refine_dir, "r")):
                if suffix and int(i) not in refine_q:
                    continue
                target = out_dir / "ktx2" / f"{name}.L{i:04d}{suffix}.ktx2"
                shutil.move(folder / f"{name}.L{i:04d}{suffix}.ktx2", target)
                light_files.append(target)
    encode_s = time.perf_counter() - started
    # [light][level], null for the lights the sun is never in (they have no images); a
    # light without a refinement has one level.
    scales: list = [None] * n
    offsets: list = [None] * n
    for i, q in coarse_q.items():
        levels = [q] + ([refine_q[i]] if i in refine_q else [])
        scales[i] = [level.scale_list for level in levels]
        offsets[i] = [level.offset_list for level in levels]
    patterns = [f"ktx2/{name}.L{{index:04d}}.ktx2"]
    if refine_q:
        patterns.append(f"ktx2/{name}.L{{index:04d}}r.ktx2")
    # "error" is filled once the images are read back (compress_sun_bounce), before "shared"
    # is added: the manifest's order.
    entry = {"k": 0, "lights": {"ktx2": patterns, "scale": scales, "offset": offsets},
             "error": {}}
    compact = CompactStack(entry, light_files, encode_s=encode_s)
    compact.light_bytes = sum(p.stat().st_size for p in light_files)
    judged_record = None
    if check is not None:
        judged_record = {
            "budget": budget,
            "refined": len(refined),
            "cheaper": {label: sum(v == label for v in cheaper.values())
                        for label, *_ in cheaper_encodings(settings)},
        }
    return compact, judged_record


def _error_record(lights, measured: ReadBack, judged_record: dict | None) -> dict:
    """The entry's ``error``: the images against the columns they were made of, and (with a
    judge) as displayed, with what the judge decided (``judged_record``)."""
    errors = measured.rms
    record = {
        "test_lights": int(len(lights)),
        "max": round(float(errors.max()), 6),
        "median": round(float(np.median(errors)), 6),
        "worst_light": int(lights[int(np.argmax(errors))]),
    }
    if judged_record is not None:
        displayed = measured.displayed
        record["displayed"] = {
            "max": round(float(displayed.max()), 6),
            "median": round(float(np.median(displayed)), 6),
            "worst_light": int(lights[int(np.argmax(displayed))]),
            "texel_p99": max_median(measured.texel),
            **judged_record,
        }
    return record


def view_settings(settings):
    """The settings a fixed view's sun-bounce stacks are compressed with: ``settings`` with
    plain UASTC whatever ``sun_bounce_encoding`` says. Even within the bound at single texels,
    ETC1S took the kiosk's real umbra 2.6 sRGB codes off an independent oracle where plain
    UASTC is 1.6 off (tests/web/test_web_kiosk_sun.py, tolerance 2.5), and the kiosk fetches
    its images over the site's own network, not a visitor's."""
    return replace(settings, sun_bounce_encoding="uastc")


def coarse_levels(settings) -> list[tuple]:
    """The coarse encodings a sun-bounce image goes through while it is over the budget as
    displayed, as ``(settings, UASTC level)`` for :func:`bake.basisu.encode`: UASTC at
    ``settings.uastc_level``, then at ``settings.sun_bounce_level`` when that differs (a
    build whose ``encoding`` is ``"etc1s"``: ETC1S alone)."""
    if settings.encoding == "etc1s":
        return [(settings, None)]
    ladder = [(settings, settings.uastc_level)]
    if settings.sun_bounce_level != settings.uastc_level:
        ladder.append((settings, settings.sun_bounce_level))
    return ladder


def cheaper_encodings(settings) -> list[tuple]:
    """The encodings a judged sun-bounce image tries before plain UASTC at
    ``settings.uastc_level``, in turn, as ``(label, settings, UASTC level, RDO lambda)`` for
    :func:`bake.basisu.encode`: with ``settings.sun_bounce_encoding`` ``"smallest"``, ETC1S
    (quality 255), then UASTC at that level with each of ``settings.sun_bounce_rdo_lambdas``;
    none for ``"uastc"`` or a build whose ``encoding`` is ``"etc1s"``."""
    if settings.sun_bounce_encoding != "smallest" or settings.encoding == "etc1s":
        return []
    out = [("etc1s", replace(settings, encoding="etc1s"), None, None)]
    for lam in settings.sun_bounce_rdo_lambdas:
        out.append((f"uastc rdo {lam:g}", settings, settings.uastc_level, lam))
    return out


def _cheaper_within(lights, coarse_dir: Path, name: str, coarse_q: dict, image, check,
                    budget, texel_bounds: dict, settings, tmp: Path) -> dict[int, str]:
    """The ``lights`` that keep a cheaper encoding than their plain UASTC image in
    ``coarse_dir``: for each of :func:`cheaper_encodings` in turn, the lights not yet kept
    whose image so encoded is smaller than the plain one and within ``budget`` as displayed
    (``check``), its RMS and at single texels (``texel_bounds[light]``); its file replaces
    the plain one there. Returns ``{light: label}``.

    ETC1S is 4-6 times smaller than UASTC on the models' faces and the views, UASTC with
    RDO about a third smaller; once the judge counts the sun's direct term they are within
    the RMS budget for part of the lights, but on the models' faces and the kiosk's view
    their blocky errors are several times plain UASTC's at single texels, and the bound
    refuses them; on the ground and the smooth stacks they fit. On the models' faces plain
    UASTC's own error at single texels is over the bound, and an encoding within
    :data:`PLAIN_TEXEL_SLACK` of it is kept (RDO with lambda 0.1). So a sample of
    :data:`CHEAPER_SAMPLE` lights spread over the sun's path is tried first, and the rest
    only where the sample kept one, with the encodings it kept (each try encodes and judges
    every image again). On
    smooth closed-form stacks (the hull planes' ``d``) plain UASTC's Zstandard-packed blocks
    are the smallest (docs/benchmarks.md, "The sun-bounce images in their smallest encoding
    within the budget")."""
    lights = [int(i) for i in lights]
    sample = lights[:: max(1, -(-len(lights) // CHEAPER_SAMPLE))]
    plain = PlainTexelErrors(coarse_dir, name, coarse_q, check)
    kept = _cheaper_of(sample, coarse_dir, name, coarse_q, image, check, budget,
                       texel_bounds, settings, tmp / "sample", plain)
    if kept:
        # The rest tries only the encodings the sample kept somewhere: on the models' faces
        # ETC1S and the larger lambdas never pass, and each try encodes and judges again.
        rest = [i for i in lights if i not in set(sample)]
        kept |= _cheaper_of(rest, coarse_dir, name, coarse_q, image, check, budget,
                            texel_bounds, settings, tmp / "rest", plain,
                            labels=set(kept.values()))
    return kept


class PlainTexelErrors:
    """Each light's plain UASTC image's own error at single texels
    (:meth:`DisplayCheck.texel_error` against its column), decoded from ``coarse_dir`` when
    first asked for and kept: what a cheaper encoding is held to where that is over the
    bound (:data:`PLAIN_TEXEL_SLACK`)."""

    def __init__(self, coarse_dir: Path, name: str, coarse_q: dict, check):
        self.coarse_dir, self.name, self.coarse_q, self.check = coarse_dir, name, coarse_q, check
        self.p99: dict[int, float] = {}

    def of(self, light: int, but_bounce: np.ndarray, column: np.ndarray) -> float:
        """Light ``light``'s, given what is displayed but its bounce (V, 3) and its column
        (H, W, 3), as the caller has them at hand."""
        if light not in self.p99:
            [decoded] = decode([self.coarse_dir / f"{self.name}.L{light:04d}.ktx2"])
            self.p99[light] = self.check.texel_error(
                light, but_bounce, column, self.coarse_q[light].value(decoded[0]))
        return self.p99[light]


def _cheaper_of(lights, coarse_dir: Path, name: str, coarse_q: dict, image, check, budget,
                texel_bounds: dict, settings, tmp: Path, plain: PlainTexelErrors,
                labels: set[str] | None = None) -> dict[int, str]:
    """:func:`_cheaper_within` for these ``lights``, all of them tried (``tmp``: a new folder
    for the encodings) with each of :func:`cheaper_encodings` (those in ``labels``, if
    given); ``plain``: the plain images' own errors at single texels."""
    file = f"{name}.L{{:04d}}.ktx2".format
    left = list(lights)
    kept: dict[int, str] = {}
    for step, (label, step_settings, level, rdo) in enumerate(cheaper_encodings(settings)):
        if not left:
            break
        if labels is not None and label not in labels:
            continue
        step_dir = tmp / f"cheaper{step}"
        step_dir.mkdir(parents=True)
        encode([coarse_q[i].path for i in left], step_dir, step_settings, array=False,
               level=level, rdo_lambda=rdo)
        smaller = [i for i in left
                   if (step_dir / file(i)).stat().st_size < (coarse_dir / file(i)).stat().st_size]
        over = set(_shown_coarse(smaller, step_dir, name, coarse_q, image, check, budget,
                                 None, tmp, texel_bounds=texel_bounds, plain=plain))
        for i in smaller:
            if i not in over:
                shutil.move(step_dir / file(i), coarse_dir / file(i))
                kept[i] = label
        left = [i for i in left if i not in kept]
    return kept


def _shown_coarse(lights, folder: Path, name: str, coarse_q: dict, image, check, budget,
                  refine_q: dict | None, tmp: Path, texel_bounds: dict | None = None,
                  plain: PlainTexelErrors | None = None) -> list[int]:
    """The ``lights`` whose coarse image in ``folder`` is off by more than ``budget`` as
    displayed (``check``: a :class:`DisplayCheck`; None: every light), or with
    ``texel_bounds`` ({light: bound}) by more than its bound at single texels
    (:meth:`DisplayCheck.texel_error`) and, with ``plain``, by more than
    :data:`PLAIN_TEXEL_SLACK` times its plain image's own, the masters read from ``image`` (a
    :mod:`bake.rowstore` stack). With ``refine_q``, the
    refinement image of each of them (what its coarse image lost) is written into ``tmp`` and
    listed there, as its chunk is decoded (not every decoded image held at once: memory)."""
    over = []
    for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
        chunk = [int(i) for i in lights[start : start + SUN_BOUNCE_DECODE_CHUNK]]
        decoded = decode([folder / f"{name}.L{i:04d}.ktx2" for i in chunk])
        shown = check.shown_but_bounce(chunk) if check is not None else None
        columns = image.columns(chunk)
        for j, i in enumerate(chunk):
            coarse = coarse_q[i].value(decoded[j][0])
            # The coarse image alone is enough where its error does not show.
            if check is not None:
                if texel_bounds is None:
                    shows = check.error(i, shown[j], columns[j], coarse) > budget
                else:
                    rms, p99 = check.errors(i, shown[j], columns[j], coarse)
                    shows = rms > budget or (
                        p99 > texel_bounds[i]
                        and (plain is None
                             or p99 > PLAIN_TEXEL_SLACK * plain.of(i, shown[j], columns[j])))
                if not shows:
                    continue
            over.append(i)
            if refine_q is not None:
                refine_q[i] = refinement_png(
                    columns[j] - coarse, tmp / f"{name}.L{i:04d}r.png", None
                )
        del decoded, shown, columns
    return over
