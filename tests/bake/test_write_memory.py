"""The write stage's memory (issue 20, "A large site"): an atlas stack is assembled by blocks
of lights (bake.writers.LIGHT_BLOCK), its bounce fitted within each surface by blocks of
channels (bake.denoise.FIT_BYTES), into the same bytes as made whole, and a shadowing pair
lets go of its whole (H, W, n, 3) stacks once their valid texels are gathered, before any
encoding (bake.compress.compress_stacks)."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from bake import compress, denoise, writers
from bake.evaluate import Build
from bake.pipeline import bake
from tests.buildfiles import build_files
from tests.sites import make_site

pytestmark = pytest.mark.slow

QUIET = {"progress": False, "log": lambda msg: None}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    # The default box on the ground: buried texels under it, texels moved onto its contact
    # lines, a hull and a ground atlas with a bounce and sun-bounce stacks.
    return make_site(tmp_path_factory.mktemp("memory") / "scene", lights=40)


@pytest.fixture(scope="module")
def whole(scene, tmp_path_factory):
    """The scene baked with every light of a stack in one block (40 lights < LIGHT_BLOCK)."""
    assert writers.LIGHT_BLOCK >= 40
    out = tmp_path_factory.mktemp("whole") / "out"
    bake(scene, out, workers=2, **QUIET)
    return out


def test_stacks_assembled_by_blocks_of_lights_are_the_bytes_of_whole_ones(
    scene, whole, tmp_path, monkeypatch
):
    monkeypatch.setattr(writers, "LIGHT_BLOCK", 7)  # 40 lights: six blocks (7 each, then 5)
    # And the fits within a surface a few channels at a time: one at a time wherever a fit's
    # region has 8 k texels or more.
    monkeypatch.setattr(denoise, "FIT_BYTES", 1 << 16)
    assert denoise.channel_blocks(21, 8192) == [(c, c + 1) for c in range(21)]
    calls = []
    smooth = writers.smooth_bounce

    def counted(image, *args):
        calls.append(image.shape[2])
        return smooth(image, *args)

    monkeypatch.setattr(writers, "smooth_bounce", counted)
    bake(scene, tmp_path / "out", workers=2, **QUIET)
    # Each atlas stack with a bounce was smoothed block by block (the views' are not).
    assert calls and set(calls) == {7, 5} and calls.count(5) * 6 == len(calls)
    blocked, reference = build_files(tmp_path / "out"), build_files(whole)
    assert blocked.keys() == reference.keys()
    assert any(".sun_bounce." in p for p in reference)
    for path in reference:
        assert blocked[path] == reference[path], path


def test_a_shadowing_pair_lets_go_of_its_whole_stacks_before_encoding(whole, tmp_path,
                                                                        monkeypatch):
    build = Build(whole)
    m = build.manifest
    skies, S, S_inv, selection = compress.prepare(
        m["scene"], build.dome_vertices, build.solid_angles, 0,
        selectable=build.selection.selectable,
    )
    images = {name: build.stack("hull", name).copy() for name in ("I", "d")}
    alive = {name: weakref.ref(image) for name, image in images.items()}
    seen = []

    class StopError(Exception):
        pass

    def first_encoding(image, *args, **kwargs):
        gc.collect()
        seen.append((image, {name: ref() is not None for name, ref in alive.items()}))
        raise StopError

    monkeypatch.setattr(compress, "compress_stack", first_encoding)
    with pytest.raises(StopError):
        compress.compress_stacks(images, "hull", tmp_path, skies, S, S_inv, selection,
                                 compress.Settings())
    # By the first encoding the caller's dict is empty and neither whole stack is alive:
    # the pair's spectra (its valid texels, normalized) are all that is held of them.
    assert images == {}
    [(image, held)] = seen
    assert image is None and held == {"I": False, "d": False}


def test_light_blocks_cover_every_light_once():
    for n in (1, 40, writers.LIGHT_BLOCK, writers.LIGHT_BLOCK + 1, 400):
        covered = np.concatenate([np.arange(n)[b] for b in writers.light_blocks(n)])
        assert np.array_equal(covered, np.arange(n))
        assert max(b.stop - b.start for b in writers.light_blocks(n)) <= writers.LIGHT_BLOCK


def test_fits_by_blocks_of_channels_are_the_fits_of_all_channels_at_once(monkeypatch):
    """The bounce fit and its continuation into buried texels, on a surface of 60 k texels
    with a buried patch, 120 channels: one channel at a time gives the same bits as all at
    once (each channel is fitted on its own)."""
    from bake import contact, denoise

    rng = np.random.default_rng(7)
    labels = np.full((260, 250), 0, dtype=np.int64)
    labels[:, 240:] = 1
    labels[100:140, 100:160] = -2  # buried texels of surface 0
    image = rng.random((260, 250, 40, 3), dtype=np.float32)

    def both():
        fit = denoise.smooth_within_labels(image, labels, 1.5, order=1)
        return fit, contact.continue_into_buried(fit, labels)

    at_once = both()
    assert denoise.channel_blocks(120, 260 * 240) == [(0, 120)]
    monkeypatch.setattr(denoise, "FIT_BYTES", 8 * 260 * 240)  # one channel per block
    assert len(denoise.channel_blocks(120, 260 * 240)) == 120
    blocked = both()
    for a, b in zip(at_once, blocked, strict=True):
        assert a.tobytes() == b.tobytes()
    assert not np.array_equal(at_once[0], image)  # the fit did change the values
