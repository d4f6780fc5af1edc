"""How each kind of stack is compressed, on :func:`bake.compress.compress_stack`.

- A stack judged by its RMS error alone (the lightmap, the fixed views' ``O`` and ``S``):
  :func:`compress_rms_stack`, its ETC1S array tried from ``settings.rms_etc1s_from_layer``
  on until the decoded composite is within the budget (:func:`rms_etc1s_tries`).
- A shadowing atlas's ``I`` and ``d`` (ground, hull): :func:`compress_ratio_pair`, ``d`` and
  ``d - I`` with one gain and one rank chosen for the per-texel shadow ratio.

:func:`compress_stacks` takes one atlas's or view's stacks and picks between the two.
Shapes: stacks (H, W, n, 3) float32, or :class:`bake.rowstore.StackStore` s read by rows.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from bake.compact_reader import CompactReader
from bake.compress import compress_stack, settle_v_dtype
from bake.compresssettings import Settings
from bake.lowrank import (
    RATIO_FLOOR,
    Spectrum,
    floored_gain,
    ratio_rank,
    rms_rank,
    texel_means,
)
from bake.refinement import RatioRefinement
from bake.rowstore import as_stack, let_go, release_freed_memory, row_block, valid_rows
from bake.stackerrors import record_sky_errors, selected_by_any, sky_error

RATIO_CHECKED = 0.02  # the shadow ratio's per-texel bound the tests check (test_compact.py)


def compress_stacks(images, prefix, out_dir, skies, S, S_inv, selection, settings):
    """Compress the stacks of one atlas or view, ``images`` {name: (H, W, n, 3) array or
    :class:`bake.rowstore.StackStore`}: ``I`` and ``d`` of a shadowing atlas together for
    their ratio (:func:`compress_ratio_pair`), any other stack alone
    (:func:`compress_rms_stack`, its refinements at the UASTC level
    ``settings.rms_refine_level``), each named ``<prefix>.<name>``.

    ``images`` is emptied as its stacks are taken: each is let go of once its valid texels
    are gathered (a whole stack is lights x texels: holding them all through the encoding
    was most of the write stage's peak memory, docs/benchmarks.md "A large site"). A stack
    on disk is read by blocks of rows, and its valid texels (the spectrum) are written
    beside it and read by rows too: no step holds a stack's lights x texels.

    Returns ``[(name, CompactStack)]`` in sorted name order."""
    names = sorted(images)
    if names == ["I", "d"]:
        results = compress_ratio_pair(
            images.pop("I"), images.pop("d"), (f"{prefix}.I", f"{prefix}.d"), out_dir,
            skies, S, S_inv, selection, settings,
        )
    else:
        rms_settings = replace(settings, refine_level=settings.rms_refine_level)
        results = [
            compress_rms_stack(images.pop(name), f"{prefix}.{name}", out_dir, skies, S, S_inv,
                               selection, rms_settings)
            for name in names
        ]
    return list(zip(names, results, strict=True))


def compress_rms_stack(image, name, out_dir, skies, S, S_inv, selection, settings):
    """:func:`compress_stack` for a stack judged by its RMS error alone (lightmap, views):
    ETC1S from ``settings.rms_etc1s_from_layer`` on; while the decoded composite is over the
    budget on a test sky, with the ETC1S array starting one layer later, up to
    ``settings.etc1s_from_layer``, then with every layer UASTC (same rank and factors; the
    last try is kept whatever its error, as before). Each layer moved out of the ETC1S array
    is a UASTC layer (and its refinement) more: the first split within the budget is the
    smallest (docs/benchmarks.md, "Downloads with the sun apart"). The tries share one
    factorization and one UASTC encoding of each layer (``etc1s_tries``; until 2026-12-05
    each try was a whole compression: docs/benchmarks.md, "The ETC1S splits from one UASTC
    encoding").
    ``image``: (H, W, n, 3) or a :class:`bake.rowstore.StackStore`."""
    stack = as_stack(image)
    del image
    valid = stack.valid
    [M] = valid_rows([stack], valid, lambda rows, t: rows, [f"{name}.spectrum"])
    let_go(stack)
    spectrum = Spectrum.of(M, np.ones(len(M), np.float32), S)
    del stack  # the spectrum holds the valid texels (a caller's reference keeps it, if any)
    result = compress_stack(
        None, name, out_dir, skies, S, S_inv, selection, settings, valid=valid,
        spectrum=spectrum, etc1s_tries=rms_etc1s_tries(settings),
    )
    spectrum.remove()
    return result


def rms_etc1s_tries(settings: Settings) -> list[int | None]:
    """The first layers of the ETC1S array that :func:`compress_rms_stack` tries, in order:
    every one from ``settings.rms_etc1s_from_layer`` to ``settings.etc1s_from_layer``, then
    None (every layer UASTC); only None without ``etc1s_from_layer``."""
    last, first = settings.etc1s_from_layer, settings.rms_etc1s_from_layer
    if last is None:
        return [None]
    first = last if first is None else min(first, last)
    return [*range(first, last + 1), None]


def compress_ratio_pair(I, d, names, out_dir, skies, S, S_inv, selection, settings):
    """Compress a shadowing atlas's ``I`` and ``d`` (H, W, n, 3, or
    :class:`bake.rowstore.StackStore` s) for their ratio.

    What is encoded is ``d`` and ``delta = d - I``, the virtual objects' effect (the client
    gets ``I = d - delta`` and the shadow's alpha ``1 - I/d = sum r delta / sum r d``). Errors
    of ``d`` then largely cancel in the ratio, and where no virtual object has any effect
    ``delta`` is zero in whole blocks, which every codec keeps exact: the real scene is never
    darkened by compression noise. Both share one gain (it cancels in the ratio) and one
    rank, chosen so that the ratio stays within ``RATIO_TRUNCATION`` at every texel before
    encoding; base layers are refined where the ratio needs it (:class:`RatioRefinement`).
    Returns the :class:`CompactStack` of ``I`` (whose entry says ``"encodes": "d - I"``) and
    of ``d``, both checked against their masters.

    Two passes over the stacks' rows: the per-texel gain and where the virtual objects have
    an effect, then the normalized valid texels of ``d`` and ``delta`` (the spectra).
    """
    I, d = as_stack(I), as_stack(d)
    valid = I.valid | d.valid
    flat = valid.ravel()
    step = row_block(d.n)
    means_I, means_d, effect = [], [], np.zeros(flat.shape, dtype=bool)
    for a in range(0, d.texels, step):
        rows_I, rows_d = I.rows(a, a + step), d.rows(a, a + step)
        b = a + len(rows_d)
        # The ratio's error is -delta' / d + delta d' / d^2: where the virtual objects
        # change nothing (delta = 0) the errors of d do not matter. Refine only near
        # delta != 0.
        effect[a:b] = (
            np.abs(rows_d - rows_I).max(axis=(1, 2)) > 1e-4 * np.abs(rows_d).max(axis=(1, 2))
        )
        means_I.append(texel_means(rows_I[flat[a:b]]))
        means_d.append(texel_means(rows_d[flat[a:b]]))
        del rows_I, rows_d
    gain = np.maximum(floored_gain(np.concatenate(means_d)),
                      floored_gain(np.concatenate(means_I)))
    del means_I, means_d
    refine_mask = cv2.dilate(effect.reshape(valid.shape).astype(np.uint8),
                             np.ones((9, 9), np.uint8)) > 0
    del effect

    def normalized(rows_d, rows_I, t):
        # delta = d - I and d at the valid texels, divided by the gain in place.
        g = gain[t : t + len(rows_d), None, None]
        delta = rows_d - rows_I
        delta /= g
        rows_d /= g
        return delta, rows_d

    M_delta, M_d = valid_rows([d, I], valid, normalized,
                               [f"{names[0]}.spectrum", f"{names[1]}.spectrum"])
    let_go(I, d)
    del I, d  # the spectra hold the valid texels: a whole stack is no longer held
    release_freed_memory()
    spec_delta = Spectrum.of(M_delta, gain, S)
    spec_d = Spectrum.of(M_d, gain, S)
    k_start = rms_rank(spec_d, S, S_inv, skies, selection, settings)[0]
    k = ratio_rank(spec_delta, spec_d, k_start, S, S_inv, skies, selection, settings)
    ratio_d, ratio_delta = RatioRefinement.pair(spec_d, spec_delta, skies, selection)
    common = dict(valid=valid, rank=k, verify=False, refine_mask=refine_mask)
    d_stack = compress_stack(
        None, names[1], out_dir, skies, S, S_inv, selection, settings, spectrum=spec_d,
        ratio=ratio_d, **common,
    )
    delta_stack = compress_stack(
        None,
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
        reader.lights(selected_by_any(skies, selection))

    # Each test sky's decoded composites of d and delta, computed once and judged three ways
    # (d's error, I's as d's minus delta's, the shadow ratio's): until 2026-12-06 d's was
    # computed three times a sky and delta's twice (docs/benchmarks.md, "One composite per
    # sky, one product per rank"). The ratio is recorded with the errors, so that
    # settle_v_dtype's restoring them restores it too: it is the one of the V kept.
    def judge():
        judge_pair(d_stack.entry, delta_stack.entry, spec_d, spec_delta, skies,
                   lambda r: readers["d"].composite(r, selection, at=valid),
                   lambda r: readers["delta"].composite(r, selection, at=valid))

    judge()
    # V in float16 unless it puts I or d over the budget where float32 does better (both
    # stacks' V together: I is read as d's composite minus delta's).
    settle_v_dtype([(d_stack.entry, d_stack.factors.V, readers["d"]),
                    (delta_stack.entry, delta_stack.factors.V, readers["delta"])],
                   out_dir, settings.budget, judge)
    spec_d.remove()
    spec_delta.remove()
    return delta_stack, d_stack


def judge_pair(d_entry: dict, delta_entry: dict, spec_d, spec_delta, skies, d_composite,
               delta_composite) -> None:
    """A shadowing pair's decoded composites against the masters' on every test sky, each
    sky's composites computed once: into ``d_entry["error"]`` d's RMS errors, into
    ``delta_entry["error"]`` I's (``I = d - delta``, as the client reads it; both as
    :func:`bake.stackerrors.record_errors` records them) and then the shadow ratio's
    (:class:`RatioError`, under ``"ratio"``). ``d_composite(r)`` and ``delta_composite(r)``
    the decoded composites (T, 3) at the valid texels; the masters' from the spectra
    (``absolute_truths``)."""
    d_errors, i_errors, ratio = {}, {}, RatioError()
    for sky, d_true, delta_true in zip(skies, spec_d.absolute_truths(skies),
                                       spec_delta.absolute_truths(skies), strict=True):
        D, delta = d_composite(sky.r), delta_composite(sky.r)
        d_errors[sky.name] = sky_error(D, d_true)
        i_errors[sky.name] = sky_error(D - delta, d_true - delta_true)
        ratio.add(sky.name, D, delta, d_true, delta_true)
    record_sky_errors(d_entry, d_errors)
    record_sky_errors(delta_entry, i_errors)
    delta_entry["error"]["ratio"] = ratio.summary()


class RatioError:
    """The shadow ratio ``I / d`` as decoded against the masters' on every test sky, added
    a sky at a time (:meth:`add`): the worst texel's absolute error where ``sum r d`` is
    above ``RATIO_FLOOR`` of its mean (lowrank.ratio_checks, the texels the rank and
    refinement rules bound), summarized (:meth:`summary`) as
    ``{"max", "sky", "skies_over", "texels_over", "checked"}`` (``*_over``: above
    ``RATIO_CHECKED``, the tests' bound; ``checked``: the texel checks made, texels times
    channels times skies, so that ``texels_over`` can be read as a share). Recorded, not
    enforced: the rank and refinement rules bound the ratio's
    truncation and unrefined losses (0.008 + 2 x 0.002) but not the ETC1S layers', which are
    never refined (docs/benchmarks.md, "The ground's shadow ratio on held-out skies")."""

    def __init__(self):
        self.worst, self.where, self.skies_over, self.texels_over = 0.0, None, 0, 0
        self.checked = 0

    def add(self, name: str, D, delta, d_true, delta_true) -> None:
        """One sky's decoded composites ``D`` (of d) and ``delta`` and the masters' (T, 3)."""
        lit = d_true > RATIO_FLOOR * d_true.mean()
        ratio = (D - delta) / np.maximum(D, 1e-12)
        truth = (d_true - delta_true) / np.maximum(d_true, 1e-12)
        error = np.abs(ratio - truth)[lit]
        top = float(error.max(initial=0.0))
        over = int((error > RATIO_CHECKED).sum())
        self.skies_over += over > 0
        self.texels_over += over
        self.checked += error.size
        if top > self.worst:
            self.worst, self.where = top, name

    def summary(self) -> dict:
        return {"max": round(self.worst, 6), "sky": self.where,
                "skies_over": self.skies_over, "texels_over": self.texels_over,
                "checked": self.checked}
