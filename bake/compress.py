"""Compact basis stacks: a low-rank base plus the selected lights' own images, as KTX2.
This module's job is each stack's compression as a whole: factor, quantize, encode, refine,
write and verify (the parts are bake.lowrank, bake.quantize, bake.basisu and
bake.compact_reader; the skies, bake.testskies; the rule, daylit.selection).

A stack ``B`` (texels x n lights, per RGB channel) is not low rank under a clear sky: the sun's
patch holds most of the light and every patch casts its own shadows, so plain truncation needs
k close to n (docs/compact-assets.md). The sky *without* its few brightest patches is smooth
and very low rank. So each stack is stored as

    B r  ~  U V^T r'  +  sum_{i in A(r)} r_i B_i,      r' = r with the lights of A(r) zeroed

- ``U V^T`` is the prior-weighted rank-k approximation of bake.lowrank.
- ``A(r)`` are the ``m`` brightest selectable lights of the current vector
  (daylit.selection; by default ``m = 1``, the sun's patch under a clear sky) among the
  lights this site's skies can select (:func:`bake.testskies.selectable_lights`: the sun's
  yearly path, about half the dome). Their own basis images ``B_i`` are stored one texture
  per light; a client downloads only the few it needs (the sun moves one patch in tens of
  minutes). Keeping ``B_i`` itself rather than the residual ``B_i - U V^T e_i`` matters: with
  residuals the sun's huge ``r_i`` multiplies a low-rank term and then cancels it, and the
  quantization noise of both survives (docs/compact-assets.md).
- ``k`` is the smallest rank whose error stays within a share of the budget on the test skies
  (uniform, CIE overcast, clear skies along the site's real sun path); after encoding, the
  decoded composite is checked against the EXR masters on the same skies.

Since the client draws the sun itself (protocol version 2, docs/sun.md; the kiosk too,
web/src/kiosksun.js) every stack, the atlases' and the fixed views', is relit with the sky
*without* the sun's disc, and so are the test skies (:func:`bake.testskies.test_skies`): that
sky has no point-like light, and no light is selected (``m = 0``, no light images; the base
alone).

Each of the k base layers and each light image is quantized to 8 bits per channel with its own
scale and offset (bake.quantize) and encoded with ``basisu`` (bake.basisu): UASTC by default,
ETC1S for the later base layers.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bake.basisu import encode
from bake.compact_reader import CompactReader, stored_v, write_v
from bake.compresssettings import Settings
from bake.ktx2decoder import decode
from bake.lowrank import (
    Factors,
    Spectrum,
    factors,
    prior_sqrt,
    rms_rank,
)
from bake.quantize import quantized_png, refinement_png
from bake.refinement import (
    BaseResiduals,
    RatioRefinement,
    layers_to_refine,
    layers_to_refine_within,
)
from bake.stackerrors import record_errors, selected_by_any, within_budget
from bake.testskies import TestSky, prior_skies, selectable_lights, test_skies
from bake.uastclayers import UastcLayers
from daylit.selection import Selection

# The types a stack's V is tried in, in order (settle_v_dtype): int8 with a scale per column
# since 2026-12-07 (manifest version 5), float16 with a power-of-two scale, float32.
V_DTYPE_LADDER = ("int8", "float16-le", "float32-le")


@dataclass
class CompactStack:
    """What was written for one stack, as the manifest lists it, plus figures for the report."""

    entry: dict
    files: list[Path] = field(default_factory=list)
    factors: Factors | None = None  # what was encoded (kept for checks and tests)
    base_bytes: int = 0
    light_bytes: int = 0
    encode_s: float = 0.0


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
    etc1s_tries: list[int | None] | None = None,
) -> CompactStack:
    """Factor, quantize, encode and verify one stack ``image`` (H, W, n, 3), or None when
``valid`` and ``spectrum`` are given (everything is then read from the spectrum: a caller
that let go of the image holds one stack's valid texels, not its whole (H, W, n, 3) too).

    With a ``spectrum`` whose gain is not all ones (shadowing atlases, see
    :func:`bake.stackkinds.compress_ratio_pair`), every texel is divided by its gain ``g``
    before factoring and encoding and the client multiplies back: quantization error is then
    relative to the texel's own level, as fine in a shadow as in the sun, which the per-texel
    shadow ratio needs. Other stacks are judged by their RMS error and keep ``g = 1`` (no gain
    texture).

    ``valid`` (H, W) selects the texels that count (default: those with any value), with
    ``spectrum`` their precomputed :class:`Spectrum` (and gain); ``min_k`` raises the rank
    and ``rank`` fixes it (no RMS criterion);
    ``refine_all`` refines every base layer; ``gain_file`` is the gain entry of an already
    written gain texture to share (the two stacks of a shadowing pair use one, so it cancels
    exactly in ``I / d``); ``verify`` checks the decoded composite against the master on the
    test skies (a pair checks itself);
    ``refine_mask`` (H, W) limits refinement to where it matters (default: everywhere);
    ``ratio`` (a stack of a shadowing pair) also refines the base layers the per-texel shadow
    ratio needs refined, and measures the RMS rule against the pair's ``d``;
    ``etc1s_tries`` (a stack judged by its RMS error alone:
    :func:`bake.stackkinds.compress_rms_stack`) the first ETC1S layers to try in order, as
    :func:`bake.stackkinds.rms_etc1s_tries` lists them: the first split whose decoded
    composite is within ``settings.budget`` on every test sky is written, else the last
    (default: ``settings.etc1s_from_layer`` alone). The UASTC layers and their candidate
    refinements are encoded once for every split (bake.uastclayers), each split's composite
    judged from the decoded bytes as the client sums them; the written files are checked to
    decode to those bytes; a split over the budget is judged up to its first sky over it.

    Writes under ``out_dir``:

    - ``ktx2/<name>.gain.ktx2``: the gain, coarse and refinement layers (if any, and unless
      shared);
    - ``ktx2/<name>.base.ktx2``: a 2D array of the first base layers (all k with
      ``settings.etc1s_from_layer`` None or ETC1S encoding), then refinement layers;
    - ``ktx2/<name>.etc1s.ktx2``: the other base layers, an ETC1S array (its entry's
      ``etc1s``; its layers follow the first array's in ``layers``);
    - ``ktx2/<name>.L<i>.ktx2`` and ``ktx2/<name>.L<i>r.ktx2``: light ``i``'s own
      (normalized) image and its refinement, for each selectable light ``i``;
    - ``v/<name>.V.bin``: V, n x k, row-major: int8, each column divided by its own scale
      (the entry's ``v.scales``, bake.compact_reader.column_scales), since 2026-12-07
      (manifest version 5; float16 divided by a power of two in version 4); float16 or
      float32 where int8 put the stack over the budget on a test sky and they did better
      (:func:`settle_v_dtype`).

    Refinement (two-stage quantization): a texture is encoded, decoded, and what the codec
    and the 8-bit quantization lost is encoded again with its own, much smaller range. The
    decoded value is the sum of both. Every light image and the gain are refined; base layers
    of a stack judged by its RMS error alone (no ``ratio``) the fewest that keep the decoded
    composite within ``settings.rms_refine_target`` of the budget on every test sky
    (:func:`bake.refinement.layers_to_refine_within`; None: the per-layer rule), of a shadowing
    pair's stack where their loss would weigh on a test sky (above a tenth of the budget, or
    more than ``RATIO_UNREFINED`` in the ratio at some texel).
    """
    started = time.perf_counter()
    if image is None:  # the texels are in the spectrum (which the caller let go of the image)
        (H, W), n = valid.shape, spectrum.M.shape[1]
    else:
        H, W, n, _ = image.shape
    if valid is None:
        valid = np.any(image != 0.0, axis=(2, 3))
    if spectrum is None:
        spectrum = Spectrum.of(image[valid], np.ones(int(valid.sum()), np.float32), S)
    normalized_gain = not np.all(spectrum.gain == 1.0)
    if rank is None:
        k, errors = rms_rank(spectrum, S, S_inv, skies, selection, settings)
        k = max(k, min_k)
    else:
        k, errors = rank, {}
    f = factors(spectrum, k, S, S_inv, errors)
    # V in int8 (settle_v_dtype below may take float16 or float32): the splits are judged
    # with V as the client will read it.
    dtype = V_DTYPE_LADDER[0]
    (out_dir / "ktx2").mkdir(exist_ok=True)
    (out_dir / "v").mkdir(exist_ok=True)

    def full(values: np.ndarray) -> np.ndarray:
        out = np.zeros((H, W) + values.shape[1:], dtype=np.float32)
        out[valid] = values
        return out

    def encode_array(pngs: list[Path], out: Path) -> None:
        # Arrays (gain, base) hold coarse and refinement layers: one level for both.
        encode(pngs, out, settings, array=True, level=settings.refine_level)

    heads = _etc1s_heads(f.k, settings, etc1s_tries)
    if len(heads) > 1 and (ratio is not None or refine_all or normalized_gain
                           or gain_file is not None or not verify):
        raise ValueError("ETC1S splits are tried for a stack judged by its RMS error alone")
    tail_file = out_dir / "ktx2" / f"{name}.etc1s.ktx2"
    base_file = out_dir / "ktx2" / f"{name}.base.ktx2"
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # Only selectable lights get images, and none when no light is selected; light-major
        # (len(lit), H, W, 3), so that each image is one contiguous block (normalized[j] is
        # light lit[j]).
        lit = selection.selectable if selection.m > 0 else np.zeros(0, dtype=int)
        # (With the default m = 0 none: a stack that selects lights holds their images.)
        normalized = np.ascontiguousarray(full(spectrum.columns(lit)).transpose(2, 0, 1, 3))
        # Stage 1: coarse gain and light images (and the lights' refinements, written: they
        # do not depend on the base's ETC1S split), each base layer quantized. The gain only
        # where this stack writes it (a pair's first stack): no other file or value reads
        # its coarse encoding (docs/benchmarks.md, "The ratio rule's moves at the lit
        # values": the gain encoded and decoded for nothing by the other stacks).
        write_gain = normalized_gain and gain_file is None
        if write_gain:
            gain_image = np.repeat(full(spectrum.gain[:, None]), 3, axis=2)
            gain_q = quantized_png(gain_image, tmp / "gain.png")
            encode_array([gain_q.path], tmp / "gain-coarse.ktx2")
        # Each base layer's full image is made when it is written and again for its loss:
        # k full images at once were k x texels x 3 more (docs/benchmarks.md, "The write
        # stage's memory").
        base_q = [quantized_png(full(f.U[:, :, j]), tmp / f"base{j:04d}.png")
                  for j in range(f.k)]
        coarse_dir = tmp / "coarse"
        coarse_dir.mkdir()
        light_q = [
            quantized_png(normalized[j], tmp / f"{name}.L{i:04d}.png") for j, i in enumerate(lit)
        ]
        encode([q.path for q in light_q], coarse_dir, settings, array=False)
        gains = [tmp / "gain-coarse.ktx2"] if write_gain else []
        decoded = decode(gains + [coarse_dir / f"{name}.L{i:04d}.ktx2" for i in lit])
        coarse_gain = gain_q.value(decoded[0][0]) if write_gain else None
        coarse_lights = [q.value(decoded[len(gains) + i][0]) for i, q in enumerate(light_q)]
        del decoded
        light_refine_q, light_files = _light_refinements(
            name, lit, normalized, coarse_lights, light_q, coarse_dir, out_dir, tmp,
            refine_mask, settings,
        )
        del normalized, coarse_lights
        # [light][level], null for the lights that cannot be selected (they have no images).
        scales: list = [None] * n
        offsets: list = [None] * n
        for i, q, r in zip(lit, light_q, light_refine_q, strict=True):
            scales[i], offsets[i] = [q.scale_list, r.scale_list], [q.offset_list, r.offset_list]
        lights = {
            "ktx2": [f"ktx2/{name}.L{{index:04d}}.ktx2", f"ktx2/{name}.L{{index:04d}}r.ktx2"],
            "scale": scales,
            "offset": offsets,
        }

        def lost(j, coarse):  # what layer j's coarse encoding (H, W, 4) lost, (H, W, 3)
            return full(f.U[:, :, j]) - base_q[j].value(coarse)

        # Stage 2, for each ETC1S split tried (the first whose decoded composite is within
        # the budget on every test sky is written, else the last): its coarse base layers,
        # the UASTC ones encoded once for all splits (bake.uastclayers), its ETC1S array;
        # which of its layers are refined.
        uastc = UastcLayers(base_q, lost, encode_array, tmp, refine_mask)
        # What the refinement rule takes from each sky whatever the split: made once for
        # every split tried (on disk beside the spectrum's composites, if they are).
        base = (BaseResiduals(f, skies, selection, spectrum.absolute_truths(skies),
                              spectrum.work)
                if len(heads) > 1 and settings.rms_refine_target is not None else None)
        predicted, first = None, 0
        for attempt, head in (enumerate(heads) if base is None else base.held(heads)):
            tail = []
            if head < f.k:
                encode([q.path for q in base_q[head:]], tail_file,
                       replace(settings, encoding="etc1s"), array=True)
                tail = list(decode([tail_file])[0])
            arrays = uastc.coarse(head) + tail  # each layer's decoded bytes, (H, W, 4)
            refine = _refined_layers(f, arrays, head, lost, valid, uastc, spectrum, skies,
                                     selection, settings, ratio, refine_all, base)
            if attempt == len(heads) - 1:
                break
            # This split's composite as the client will decode it, from the same bytes,
            # judged from the sky that rejected the split before (a rejected split stops at
            # its first sky over the budget; bake.stackerrors.within_budget).
            raw = arrays[:head] + [uastc.candidates(head)[1][j] for j in refine] + tail
            candidates = uastc.candidates(head)[0]
            predicted = {"layers": _layer_entries(base_q, [candidates[j] for j in refine], head,
                                                  refine),
                         "lights": lights, "error": {}}
            # With V in each type of the ladder in turn, as settle_v_dtype would write this
            # split alone: a split within the budget only with float16 V is kept with it.
            within, rejected = False, first
            for v_type in V_DTYPE_LADDER:
                reader = CompactReader.decoded(out_dir, predicted, (H, W),
                                               stored_v(f.V, v_type), raw)
                reader.lights(selected_by_any(skies, selection))
                within, at = within_budget(
                    predicted, lambda sky: next(spectrum.absolute_truths([sky])),
                    lambda r, reader=reader: reader.composite(r, selection, at=valid), skies,
                    settings.budget, first,
                )
                del reader
                if within:
                    dtype = v_type
                    break
                rejected = at if v_type == V_DTYPE_LADDER[0] else rejected
            if within:
                break
            first = rejected
            predicted = raw = None
        del base
        if head == f.k:  # an earlier try's ETC1S array
            tail_file.unlink(missing_ok=True)
        refine_q = [
            refinement_png(lost(j, arrays[j]), tmp / f"refine{j:04d}.png", refine_mask)
            for j in refine
        ]
        del arrays, uastc
        encode_array([q.path for q in base_q[:head] + refine_q], base_file)
        written_gain = out_dir / "ktx2" / f"{name}.gain.ktx2"
        if write_gain:
            gain_refine_q = refinement_png(gain_image - coarse_gain, tmp / "gain-refine.png",
                                           None)
            encode_array([gain_q.path, gain_refine_q.path], written_gain)
    v_file = out_dir / "v" / f"{name}.V.bin"
    v_type = write_v(v_file, f.V, dtype)  # {"dtype", "scales"}
    encode_s = time.perf_counter() - started

    entry = {
        "k": f.k,
        "selected_lights": selection.m,
        "ktx2": base_file.relative_to(out_dir).as_posix(),
        "layers": _layer_entries(base_q, refine_q, head, refine),
        "v": {
            "path": v_file.relative_to(out_dir).as_posix(),
            "shape": [n, f.k],
            **v_type,
        },
        "lights": lights,
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
    written = None
    if predicted is not None:  # the files decode to the bytes judged: the same errors
        written = np.concatenate(decode([base_file] + ([tail_file] if head < f.k else [])))
    if written is not None and all(np.array_equal(a, b) for a, b in zip(written, raw,
                                                                         strict=True)):
        entry["error"].update(predicted["error"])
    elif verify:
        # The decoded composite against the master on the test skies.
        reader = CompactReader(out_dir, entry, (H, W))
        reader.lights(selected_by_any(skies, selection))
        record_errors(
            entry,
            spectrum.absolute_truths(skies),
            lambda r: reader.composite(r, selection, at=valid),
            skies,
        )
        if settle_v_dtype(
            [(entry, f.V, reader)], out_dir, settings.budget,
            lambda: record_errors(entry, spectrum.absolute_truths(skies),
                                  lambda r: reader.composite(r, selection, at=valid), skies),
        ):
            compact.base_bytes = sum(p.stat().st_size for p in files if p not in light_files)
    return compact


def settle_v_dtype(stacks, out_dir: Path, budget: float, judge) -> bool:
    """Keep V in int8 unless that puts a stack over ``budget`` on a test sky: then each
    later type of :data:`V_DTYPE_LADDER` (float16, float32) is judged in turn (``judge()``
    records the errors again into the entries, with their readers' V set to it) until one
    is within the budget; the type with the lowest worst error is kept, its files rewritten
    (else int8 and its errors are restored). ``stacks``: (entry, V float32 (n, k), its
    CompactReader) of the stacks judged together (a shadowing pair's two). Int8 moved the
    demo's composites by at most 3.4e-4 of the mean, float16 by < 6e-6 (docs/benchmarks.md):
    this is a guard. Returns whether the files were rewritten."""
    first = V_DTYPE_LADDER[0]
    moved = [(e, V, r) for e, V, r in stacks if e["v"]["dtype"] == first]
    worst = max(e["error"]["max"] for e, _, _ in stacks)
    if not moved or worst <= budget:
        return False
    best, best_worst = None, worst
    kept = [(dict(e["error"]), r.V) for e, _, r in moved]
    for dtype in V_DTYPE_LADDER[1:]:
        for _, V, reader in moved:
            reader.V = stored_v(V, dtype)
        judge()
        now = max(e["error"]["max"] for e, _, _ in stacks)
        if now < best_worst:
            best, best_worst = (dtype, [dict(e["error"]) for e, _, _ in moved]), now
        if now <= budget:
            break
    if best is None:
        for (entry, _, reader), (error, V_first) in zip(moved, kept, strict=True):
            entry["error"], reader.V = error, V_first
        return False
    dtype, errors = best
    for (entry, V, reader), error in zip(moved, errors, strict=True):
        path = entry["v"]["path"]
        entry["v"] = {"path": path, "shape": entry["v"]["shape"],
                      **write_v(out_dir / path, V, dtype)}
        entry["error"], reader.V = error, stored_v(V, dtype)
    return True


def _etc1s_heads(k: int, settings: Settings, tries: list[int | None] | None) -> list[int]:
    """How many of k base layers go to the UASTC array, for each ETC1S split tried in order
    (``tries``: first ETC1S layers, as :func:`bake.stackkinds.rms_etc1s_tries` lists them;
    None: the one ``settings`` gives), each once."""
    heads: list[int] = []
    for j0 in [settings.etc1s_from_layer] if tries is None else tries:
        head = _etc1s_split(k, replace(settings, etc1s_from_layer=j0))
        if head not in heads:
            heads.append(head)
    return heads


def _layer_entries(base_q, refine_q, head: int, refine: list[int]) -> list[dict]:
    """An entry's ``layers``: the UASTC array's (coarse layers 0 .. head - 1, then the
    refinements ``refine_q`` of the layers ``refine``), then the ETC1S array's."""
    layers = [q.entry(coefficient=j) for j, q in enumerate(base_q[:head])]
    layers += [q.entry(coefficient=j) for j, q in zip(refine, refine_q, strict=True)]
    layers += [q.entry(coefficient=j) for j, q in enumerate(base_q) if j >= head]
    return layers


def _light_refinements(name, lit, normalized, coarse_lights, light_q, coarse_dir, out_dir,
                       tmp, refine_mask, settings):
    """Every selectable light's refinement encoded, and its coarse and refined images
    moved into ``out_dir``; returns the refinements' :class:`Quantized` and the files."""
    refine_dir = tmp / "refine"
    refine_dir.mkdir()
    light_refine_q = [
        refinement_png(
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
    return light_refine_q, light_files


def _refined_layers(f, arrays, head, lost, valid, uastc, spectrum, skies, selection, settings,
                    ratio, refine_all, base=None) -> list[int]:
    """Which base layers are refined, given each layer's coarse decoded bytes ``arrays``
    (the first ``head`` UASTC, the rest ETC1S): :func:`compress_stack`'s rules (``base``
    the skies' :class:`BaseResiduals` shared by the splits tried, if any)."""
    if refine_all:
        return list(range(f.k))
    losses = np.empty((f.k, len(f.U), 3), dtype=np.float32)  # a block per layer
    for j in range(f.k):
        losses[j] = lost(j, arrays[j])[valid]
    if ratio is None and settings.rms_refine_target is not None:
        # A stack judged by its RMS error alone: the fewest layers that keep the decoded
        # composite within the target on every test sky (ETC1S layers' losses counted, never
        # refined), knowing what each UASTC layer's refinement restores as decoded: every
        # candidate refinement is encoded (at the level the base array is written at: UASTC
        # encodes each block on its own, so a chosen one comes out the same there) and
        # decoded.
        candidates, decoded = uastc.candidates(head)
        restored = np.empty((head, len(f.U), 3), dtype=np.float32)
        for j, texel in enumerate(decoded):
            restored[j] = candidates[j].value(texel)[valid]
        refine = layers_to_refine_within(
            losses, f, skies, selection, spectrum.absolute_truths(skies),
            settings.rms_refine_target * settings.budget, refinable=head, restored=restored,
            base=base,
        )
        del restored
    else:
        refine = layers_to_refine(
            losses, f, skies, selection, settings, None if ratio is None else ratio.means,
        )
    if ratio is not None:
        refine = sorted(set(refine) | set(ratio.layers(losses, f)))
    # The ETC1S layers are never refined: both rules above are per-layer bounds that their
    # ETC1S loss trips, and refining them (in UASTC) cost about what ETC1S saved, where
    # unrefined they keep the stacks within the budget and the ground's ratio within 0.02
    # (docs/benchmarks.md, "Downloads with the sun apart").
    return [j for j in refine if j < head]


def _etc1s_split(k: int, settings: Settings) -> int:
    """How many of k base layers go to the UASTC array; the rest go to the ETC1S one, which
    holds two layers or more: basisu writes a one-layer "array" as a plain 2D texture, which
    the client's ``sampler2DArray`` cannot read (a lone last layer stays UASTC)."""
    if settings.encoding != "uastc" or settings.etc1s_from_layer is None:
        return k
    head = min(k, max(1, settings.etc1s_from_layer))
    return k if k - head < 2 else head

