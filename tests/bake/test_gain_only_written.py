"""A stack encodes its gain only where it writes it (issue 20, the write stage: the coarse
gain of a stack judged by its RMS error alone, or of a pair's second stack, which shares the
first's gain file, was encoded and decoded though no file or value read it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bake import compress, lowrank, testskies
from bake.dome import Dome

SITE = {"timezone": "Europe/Paris", "latitude_deg": 48.85, "longitude_deg": 2.35,
        "elevation_m": 35.0}


def _encoded(monkeypatch) -> list[str]:
    """The names of every file the stack's encoder calls write (their ``out``)."""
    names: list[str] = []
    real = compress.encode

    def recorded(pngs, out, settings, array, level=None):
        names.append(Path(out).name)
        return real(pngs, out, settings, array, level=level)

    monkeypatch.setattr(compress, "encode", recorded)
    return names


def _case():
    dome = Dome.for_light_count(40)
    rng = np.random.default_rng(4)
    field = 1.0 + 0.3 * rng.uniform(size=(24, 24, 1, 1))
    image = (field * dome.cosine_weighted_sr[None, None, :, None]
             * np.array([1.0, 0.9, 0.8])).astype(np.float32)
    selectable = testskies.sun_path_selectable(SITE, dome.vertices, dome.solid_angles_sr)
    skies, S, S_inv, selection = compress.prepare(
        SITE, dome.vertices, dome.solid_angles_sr, 0, selectable=selectable)
    return image, skies, S, S_inv, selection


def test_a_stack_with_unit_gain_encodes_no_gain(tmp_path, monkeypatch):
    """An RMS-judged stack (unit gain): no gain encoded, none in its entry or files."""
    image, skies, S, S_inv, selection = _case()
    names = _encoded(monkeypatch)
    result = compress.compress_stack(image, "lightmap.I", tmp_path, skies, S, S_inv, selection,
                                     compress.Settings(selected_lights=0), rank=2)
    assert names and not any("gain" in name for name in names), names
    assert "gain" not in result.entry
    assert not list(tmp_path.rglob("*gain*"))


def test_a_stack_with_a_gain_encodes_it_coarse_then_writes_it(tmp_path, monkeypatch):
    """A stack with its own gain (a pair's first): the gain's coarse encoding, then its file
    (coarse and refinement layers); the stack sharing that file encodes no gain."""
    image, skies, S, S_inv, selection = _case()
    valid = np.ones(image.shape[:2], bool)
    gain = np.linspace(0.5, 2.0, int(valid.sum())).astype(np.float32)
    spectrum = lowrank.Spectrum.of(image[valid] / gain[:, None, None], gain, S)
    names = _encoded(monkeypatch)
    first = compress.compress_stack(None, "hull.d", tmp_path, skies, S, S_inv, selection,
                                    compress.Settings(selected_lights=0), valid=valid,
                                    spectrum=spectrum, rank=2, verify=False)
    assert [n for n in names if "gain" in n] == ["gain-coarse.ktx2", "hull.d.gain.ktx2"]
    assert len(first.entry["gain"]["layers"]) == 2
    names.clear()
    second = compress.compress_stack(None, "hull.I", tmp_path, skies, S, S_inv, selection,
                                     compress.Settings(selected_lights=0), valid=valid,
                                     spectrum=spectrum, rank=2, verify=False,
                                     gain_file=first.entry["gain"])
    assert names and not any("gain" in name for name in names), names
    assert second.entry["gain"] == first.entry["gain"]
