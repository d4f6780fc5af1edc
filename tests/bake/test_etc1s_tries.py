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
from dataclasses import replace

import numpy as np
import pytest

from bake import compress, stackkinds, testskies
from bake.basisu import encode
from bake.compact_reader import CompactReader
from bake.dome import Dome
from bake.ktx2decoder import decode
from bake.quantize import quantized_png

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
