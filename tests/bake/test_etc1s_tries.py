"""The ETC1S splits of a stack judged by its RMS error alone, tried from one UASTC encoding
(issue 20: the write stage's share; bake.uastclayers).

The premise, checked with the encoder and the browser's transcoder: a UASTC layer decodes to
the same bytes whatever array it is encoded in, and at whatever place. Then the stack
compressed with every split tried at once is, byte for byte, the stack compressed with the
first split that is within the budget on its own (each split written and its decoded
composite checked against the master's, as the bake did before), and its composite is
within the budget of the master's summed here."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace

import numpy as np
import pytest

from bake import compress, lowrank, refinement, stackerrors, stackkinds, testskies
from bake.basisu import encode
from bake.compact_reader import CompactReader
from bake.dome import Dome
from bake.ktx2decoder import decode
from bake.quantize import quantized_png
from daylit.selection import Selection

SITE = {"timezone": "Europe/Paris", "latitude_deg": 48.85, "longitude_deg": 2.35,
        "elevation_m": 35.0}
SIZE = 48
RANK = 12


def _fields(rng, count: int) -> np.ndarray:
    """(count, SIZE, SIZE) smooth random fields in [-1, 1] (sums of a few waves)."""
    y, x = np.mgrid[0:SIZE, 0:SIZE] / SIZE
    out = np.zeros((count, SIZE, SIZE))
    for j in range(count):
        for _ in range(3):
            fx, fy, phase = rng.uniform(0.5, 4.0), rng.uniform(0.5, 4.0), rng.uniform(0, 6.3)
            out[j] += np.sin(2 * np.pi * (fx * x + fy * y) + phase) / 3
    return out


def _stack(dome: Dome) -> np.ndarray:
    """(SIZE, SIZE, n, 3) a lightmap-like stack of rank ``RANK + 1`` per channel: an open
    surface's light (each light's cosine-weighted solid angle) times fields, each a smooth
    one plus texel noise, of equal weight, so that its later base layers carry enough for
    ETC1S's coarser blocks to weigh on the budget."""
    rng = np.random.default_rng(7)
    fields = _fields(rng, RANK) + 0.5 * rng.normal(size=(RANK, SIZE, SIZE))
    weights = np.full(RANK, 0.25)
    mix = rng.uniform(0.0, 1.0, (dome.count, RANK))
    light = dome.cosine_weighted_sr
    stack = 1.0 + np.einsum("jhw,j,nj->hwn", fields, weights, mix)
    tint = np.array([1.0, 0.95, 0.9])
    return (stack[..., None] * light[None, None, :, None] * tint).astype(np.float32)


def test_a_uastc_layer_decodes_the_same_in_any_array(tmp_path):
    """Layers encoded in arrays [0:6], [0:3], [3:6] and [2:5], at both levels the base arrays
    use: each layer's decoded bytes the same in every array."""
    rng = np.random.default_rng(3)
    layers = np.stack([_fields(rng, 3).transpose(1, 2, 0) for _ in range(6)])
    layers += 0.05 * rng.normal(size=layers.shape)  # noise-like detail, as refinements hold
    pngs = [quantized_png(layer, tmp_path / f"l{j}.png").path for j, layer in enumerate(layers)]
    for level in (0, 1):
        decoded = {}
        for a, b in ((0, 6), (0, 3), (3, 6), (2, 5)):
            out = tmp_path / f"a{a}{b}-{level}.ktx2"
            encode(pngs[a:b], out, compress.Settings(), array=True, level=level)
            decoded[a, b] = decode([out])[0]
        whole = decoded[0, 6]
        for (a, b), layers_ab in decoded.items():
            for i in range(b - a):
                assert np.array_equal(layers_ab[i], whole[a + i]), (level, a, b, i)


def _digests(folder) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted((folder / "ktx2").iterdir()) + sorted((folder / "v").iterdir())}


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    dome = Dome.for_light_count(40)
    image = _stack(dome)
    selectable = testskies.sun_path_selectable(SITE, dome.vertices, dome.solid_angles_sr)
    skies, S, S_inv, selection = compress.prepare(
        SITE, dome.vertices, dome.solid_angles_sr, 0, selectable=selectable
    )
    settings = compress.Settings(selected_lights=0, budget=0.01, refine_level=0)
    return dict(image=image, skies=skies, S=S, S_inv=S_inv, selection=selection,
                settings=settings, tmp=tmp_path_factory)


def _alone(case, j0, budget):
    """The stack compressed with one split, written and checked from its files (the bake's
    way before 2026-12-05, a try at a time)."""
    out = case["tmp"].mktemp(f"alone{j0}")
    settings = replace(case["settings"], etc1s_from_layer=j0, budget=budget)
    result = compress.compress_stack(
        case["image"], "lightmap.I", out, case["skies"], case["S"], case["S_inv"],
        case["selection"], settings, rank=RANK,
    )
    return result, out


def test_the_tried_splits_write_the_first_split_within_budget(case):
    """Every split alone first (ETC1S from 4 to 8, then none), each one's error from its
    files; a budget between the first split's error and a later one's; then all tried at
    once: the split written is the first within that budget, every file the same bytes and
    the manifest entry the same as that split's alone, and its composite within the budget
    of the master's under skies that chose nothing."""
    settings = case["settings"]
    tries = stackkinds.rms_etc1s_tries(replace(settings, rms_etc1s_from_layer=4))
    assert tries == [4, 5, 6, 7, 8, None]
    probe = 0.002
    errors = {j0: _alone(case, j0, probe)[0].entry["error"]["max"] for j0 in tries}
    # The splits' errors straddle a budget: ETC1S from layer 4 is over it, a later one under.
    budget = 0.5 * (errors[4] + min(errors[j0] for j0 in tries[1:]))
    assert errors[4] > budget
    chosen, alone_dir = None, None
    for j0 in tries:
        result, out = _alone(case, j0, budget)
        if result.entry["error"]["max"] <= budget or j0 is None:
            chosen, alone_dir = result, out
            break
    assert chosen.entry.get("etc1s", {}).get("layers", 0) < RANK - 4  # not the first split
    together_dir = case["tmp"].mktemp("together")
    together = compress.compress_stack(
        case["image"], "lightmap.I", together_dir, case["skies"], case["S"], case["S_inv"],
        case["selection"], replace(settings, budget=budget), rank=RANK,
        etc1s_tries=[j0 for j0 in tries],
    )
    assert together.entry == chosen.entry
    assert _digests(together_dir) == _digests(alone_dir)
    # Independent of the bake's own check: the master's composite summed here.
    image = case["image"].astype(np.float64)
    reader = CompactReader(together_dir, together.entry, (SIZE, SIZE))
    for sky in testskies.held_out_skies(SITE, Dome.for_light_count(40).vertices):
        truth = np.einsum("hwnc,nc->hwc", image, sky.r)
        decoded = reader.composite(sky.r, case["selection"])
        error = np.sqrt(((decoded - truth) ** 2).mean()) / truth.mean()
        assert error <= budget, (sky.name, error)


def test_a_split_judged_stops_at_its_first_sky_over_the_budget():
    """``stackerrors.within_budget`` gives the verdict that the errors of every sky recorded
    by ``record_errors`` give (the entry's rounded maximum against the budget, at the
    rounding's edge too), records the same entry when within, and judges a rejected split
    only up to its first sky over the budget, from the sky it is told to start at."""
    T = 64
    reference = np.ones((T, 3), np.float32)

    def case(errors):
        skies = [testskies.TestSky(f"sky {s}", np.full((4, 3), float(s)))
                 for s in range(len(errors))]
        calls = []

        def composite(r):  # an error of exactly errors[s] of the mean under sky s
            s = int(r[0, 0])
            calls.append(s)
            out = reference.copy()
            out[: T // 2] += errors[s]
            out[T // 2 :] -= errors[s]
            return out

        return skies, composite, calls

    for errors, budget in (([0.004, 0.012, 0.003, 0.02, 0.009], 0.01),
                           ([0.004, 0.012, 0.003, 0.02, 0.009], 0.03),
                           ([0.004, 0.0100004, 0.003], 0.01),  # rounds to the budget: within
                           ([0.004, 0.0100006, 0.003], 0.01)):  # rounds over it
        skies, composite, calls = case(errors)
        full = {"error": {}}
        stackerrors.record_errors(full, [reference] * len(skies), composite, skies)
        expected = full["error"]["max"] <= budget
        for first in range(len(skies)):
            calls.clear()
            entry = {"error": {}}
            within, decided = stackerrors.within_budget(entry, lambda sky: reference,
                                                        composite, skies, budget, first)
            assert within == expected, (errors, budget, first)
            order = list(range(first, len(skies))) + list(range(first))
            if within:
                assert decided == first and sorted(calls) == list(range(len(skies)))
                assert json.dumps(entry) == json.dumps(full)  # the same errors, same order
            else:
                over = [s for s in order if round(errors[s], 6) > budget]
                assert decided == over[0] and calls == order[: order.index(decided) + 1]
                assert entry == {"error": {}}
    # On a rejected split the judgement ends at the first sky over the budget.
    skies, composite, calls = case([0.004, 0.012, 0.003, 0.02, 0.009])
    assert stackerrors.within_budget({"error": {}}, lambda sky: reference, composite, skies,
                                     0.01, 3) == (False, 3)
    assert calls == [3]


def _refinement_case(rng, T=300, k=10, n=12, skies=6):
    """Random factors (T, 3, k) and (n, k), skies, masters near ``U V^T r``, and losses."""
    U = (1.0 + 0.3 * rng.normal(size=(T, 3, k))).astype(np.float32)
    V = rng.uniform(0.0, 1.0, (n, k)).astype(np.float32)
    f = lowrank.Factors(k, U, V, {})
    sky_list = [testskies.TestSky(f"s{s}", rng.uniform(0.2, 1.0, (n, 3))) for s in range(skies)]
    truths = [np.einsum("tck,kc->tc", U, (V.T @ sky.r).astype(np.float32))
              + rng.normal(scale=0.02, size=(T, 3)).astype(np.float32) for sky in sky_list]
    losses = rng.normal(scale=0.05, size=(k, T, 3)).astype(np.float32)
    return f, sky_list, truths, losses


@pytest.mark.parametrize("on_disk", [False, True])
def test_the_splits_share_each_skys_base_residual(tmp_path, on_disk):
    """``refinement.BaseResiduals``, made once for every split tried: each sky's ``truth - U
    c`` the very values the rule makes alone, and the rule given it chooses the same layers
    as alone, for splits whose ETC1S layers lose differently, at targets where the choice
    changes (a residual missing ``U c``, or another sky's, chooses others)."""
    rng = np.random.default_rng(11)
    f, sky_list, truths, losses = _refinement_case(rng)
    nothing = Selection(np.zeros(f.V.shape[0]), 0)
    base = refinement.BaseResiduals(f, sky_list, nothing, iter(truths),
                                    tmp_path if on_disk else None)
    for s, (sky, truth) in enumerate(zip(sky_list, truths, strict=True)):
        c = (f.V.T @ sky.r).astype(np.float32)
        assert np.array_equal(base.cs[s], c)
        assert np.array_equal(base.residual(s),
                              truth.astype(np.float32) - np.einsum("tck,kc->tc", f.U, c))
    rule = refinement.layers_to_refine_within
    wrong = refinement.BaseResiduals(f, sky_list, nothing, iter(truths))
    wrong._held = [truth.astype(np.float32) for truth in truths]  # U c left out
    choices, wrong_differs = set(), False
    for head in (4, 6, f.k):
        split = losses.copy()
        split[head:] = rng.normal(scale=0.08, size=split[head:].shape)  # this split's ETC1S
        restored = split[:head] * rng.uniform(0.3, 1.0, (head, 1, 1)).astype(np.float32)
        everything = rule(split, f, sky_list, nothing, truths, 0.0, refinable=head,
                          restored=restored)
        for target in np.linspace(0.0, 0.03, 13):
            alone = rule(split, f, sky_list, nothing, truths, target, refinable=head,
                         restored=restored)
            shared = rule(split, f, sky_list, nothing, None, target, refinable=head,
                          restored=restored, base=base)
            assert shared == alone, (head, target)
            choices.add(tuple(alone))
            wrong_differs |= rule(split, f, sky_list, nothing, None, target, refinable=head,
                                  restored=restored, base=wrong) != alone
        assert everything  # the case is one where layers are refined
    assert len(choices) >= 4 and wrong_differs  # the targets move the choice
    if on_disk:
        assert list(tmp_path.iterdir())
    for _attempt, head in base.held([4, 6, f.k]):  # as compress_stack tries the splits
        if head == 6:
            break  # a split within the budget: the errors go with the loop
    assert not list(tmp_path.iterdir()) and not base._held
