"""The write stage's memory (issue 20, "A large site"): an atlas stack is assembled by blocks
of lights (bake.writers.LIGHT_BLOCK), its bounce fitted within each surface by blocks of
channels (bake.denoise.FIT_BYTES), into the same bytes as made whole; a shadowing pair
lets go of its whole (H, W, n, 3) stacks once their valid texels are gathered, before any
encoding (bake.stackkinds.compress_stacks); and a stack on disk is written (its compact pair,
its EXR master, its sun-bounce images) holding far less than its lights x texels
(bake.rowstore)."""

from __future__ import annotations

import gc
import tracemalloc
import weakref

import numpy as np
import pytest

from bake import compress, denoise, stackkinds, writers
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

    def counted(image, *args, **kwargs):
        calls.append(image.shape[2])
        return smooth(image, *args, **kwargs)

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

    monkeypatch.setattr(stackkinds, "compress_stack", first_encoding)
    with pytest.raises(StopError):
        stackkinds.compress_stacks(images, "hull", tmp_path, skies, S, S_inv, selection,
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


# --------------------------------------------------------------------------------------------
# No step of a stack's writing holds its lights x texels (issue 20): the stacks are given
# memory-mapped (as the bake's write stage reads them back from disk) and every numpy
# allocation is counted (tracemalloc: numpy reports its buffers to it; a mapped file's pages
# are not allocations).

SITE = {"timezone": "Asia/Tokyo", "latitude_deg": 34.47, "longitude_deg": 135.82,
        "elevation_m": 60.0}


def _pair_on_disk(folder, height=1024, width=32, lights=400):
    """A shadowing pair ``I``, ``d`` (H, W, n, 3) saved as .npy files and opened memory-mapped:
    ``d`` smooth over the texels and the lights, ``I`` darkened by a virtual object's shadow
    (a disc of texels, the lights of one side of the dome); a quarter of the texels empty."""
    from bake.dome import Dome

    dome = Dome.for_light_count(lights)
    y, x = np.mgrid[0:height, 0:width] / max(height, width)
    up = np.clip(dome.centroids[:, 1], 0.0, None)  # (n,)
    east = np.clip(dome.centroids[:, 0], 0.0, None)
    d = ((0.5 + x)[..., None, None] * up[None, None, :, None]
         + (0.3 * y)[..., None, None] * east[None, None, :, None]
         ) * np.array([1.0, 0.9, 0.8])
    shadow = (((x - 0.5) ** 2 + (y - 0.5) ** 2) < 0.05)[..., None, None] * (east > 0.2)[
        None, None, :, None]
    I = d * (1.0 - 0.7 * shadow)
    d[: height // 2, : width // 2] = I[: height // 2, : width // 2] = 0.0
    maps = {}
    for name, stack in (("I", I), ("d", d)):
        np.save(folder / f"{name}.npy", stack.astype(np.float32))
        maps[name] = np.load(folder / f"{name}.npy", mmap_mode="r")
    return dome, maps


def _peak_bytes(run) -> int:
    tracemalloc.start()
    try:
        run()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_writing_a_stack_holds_far_less_than_its_lights_x_texels(tmp_path, monkeypatch):
    from bake import lowrank, rowstore, sunbounce, sundisplay
    from daylit.stackio import read_stack_exr, write_stack_exr, write_stack_exr_by_rows

    dome, maps = _pair_on_disk(tmp_path)
    stack_bytes = maps["d"].nbytes  # 157 MB: 32 k texels x 400 lights x RGB float32
    # Working blocks in proportion to this small stack (the bake's are 64 MB and 65,536
    # rows, against a palace stack of 0.7-6.8 GB).
    monkeypatch.setattr(rowstore, "ROW_BLOCK_BYTES", 1 << 18)
    monkeypatch.setattr(lowrank, "GRAM_ROWS", 256)
    skies, S, S_inv, selection = compress.prepare(SITE, dome.vertices, dome.solid_angles_sr, 0)
    skies = skies[:8]  # uniform, overcast and clear skies: a few, so skies x texels is small
    out = tmp_path / "out"
    out.mkdir()
    results = {}

    def pair():
        results["pair"] = stackkinds.compress_stacks(
            dict(maps), "hull", out, skies, S, S_inv, selection, compress.Settings()
        )

    peak = _peak_bytes(pair)
    # The compact pair is right (its errors on the test skies within the budget) ...
    for name, result in results["pair"]:
        assert result.entry["error"]["max"] <= compress.Settings().budget, name
    # ... and was made holding far less than one stack, let alone the two.
    assert peak < stack_bytes / 4, (peak, stack_bytes)

    # The master by bands of lines: OpenEXR's own whole-stack file, byte for byte.
    h, w, n, _ = maps["d"].shape
    whole, banded = tmp_path / "whole.exr", tmp_path / "banded.exr"
    write_stack_exr(whole, maps["d"])
    peak = _peak_bytes(lambda: write_stack_exr_by_rows(
        banded, h, w, n, lambda y0, y1: maps["d"][y0:y1], band_bytes=1 << 20))
    assert banded.read_bytes() == whole.read_bytes()
    assert np.array_equal(read_stack_exr(banded), maps["d"])
    assert peak < stack_bytes / 4, (peak, stack_bytes)

    # A sun-bounce stack (here the shadow's light, d - I, in the sun's columns), judged as
    # displayed with its sky stack: one image per light the sun can be in.
    lights = selection.selectable[:12]
    bounce = np.zeros(maps["d"].shape, np.float32)
    bounce[:, :, lights] = (maps["d"][:, :, lights] - maps["I"][:, :, lights]) + 0.01 * maps[
        "d"][:, :, lights]
    np.save(tmp_path / "bounce.npy", bounce)
    del bounce
    bounce = np.load(tmp_path / "bounce.npy", mmap_mode="r")
    display = sundisplay.DisplaySkies.of_dome(dome.vertices, dome.solid_angles_sr, lights)
    settings = compress.Settings()
    peak = _peak_bytes(lambda: results.setdefault("sun", sunbounce.compress_sun_bounce(
        bounce, "hull.sun_bounce.I", out, lights, settings, maps["I"], display)))
    assert results["sun"].entry["error"]["test_lights"] == len(lights)
    assert results["sun"].entry["error"]["displayed"]["max"] <= settings.sun_bounce_budget
    assert peak < stack_bytes / 4, (peak, stack_bytes)
