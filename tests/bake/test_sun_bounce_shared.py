"""Neighbouring sun-path patches sharing one sun-bounce image (docs/sun.md, "Shared images";
bake/sunshare.py ``SharedImages``): the layout, the columns a client decodes against the
group's mean computed here from the EXR masters, and what a visit downloads
(bake/downloads.py).

The tests' sun site baked at 400 lights (octahedral, frequency 10): its sun-path patches are
grouped by the patches of the 196-light dome (octahedral, frequency 7; one to three fine
patches each)."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from bake import downloads
from bake.evaluate import Build

LIGHTS = 400


@pytest.fixture(scope="module")
def shared_build(tmp_path_factory) -> Path:
    """The sun site (tests/conftest.py) baked at draft quality with 400 lights (~1 min)."""
    from bake.pipeline import bake
    from tests.conftest import SUN_SHED, SUN_WALL_SIZE_M
    from tests.sites import box, make_site, real_box

    root = tmp_path_factory.mktemp("shared")
    wall = box(list(SUN_WALL_SIZE_M), [0.0, 0.0, 0.0])
    scene = make_site(root / "scene", virtual=[("wall", wall, (0.5, 0.5, 0.5))],
                      real=real_box(**SUN_SHED), ground_m=60.0)
    bake(scene, root / "build", lights=LIGHTS, progress=False, log=lambda msg: None)
    return root / "build"


def _groups(table: dict) -> dict[int, list[int]]:
    """{light whose files hold the image: the lights that read it}."""
    groups: dict[int, list[int]] = {}
    for p, holder in enumerate(table["image"]):
        if holder is not None:
            groups.setdefault(holder, []).append(p)
    return groups


def _best_scaled_error(got: np.ndarray, truth: np.ndarray) -> float:
    """RMS of ``g * got - truth`` over texels (T, 3) at the best gain ``g`` per channel,
    over the mean of ``truth``: the error of an image whatever its scale per channel."""
    g = (got * truth).sum(axis=0) / (got * got).sum(axis=0)
    return float(np.sqrt(((g * got - truth) ** 2).mean()) / truth.mean())


def test_neighbouring_patches_read_one_image_their_groups_mean(shared_build):
    """Every sun-path light has an image, held by one light of its group; only the holders
    have files; a group's lights are neighbours (within 25 degrees of each other); a light's
    decoded column is its group's image at its own gain per channel: scaled at its best, it
    is the group's solid-angle mean of the masters (``sum_q B_q / sum_q omega_q``, computed
    here from the EXR masters and the manifest's dome) as closely for every member (the same
    image) and within what the bake recorded for the image; and that gain is the
    least-squares one against the light's *own* master (no other gain of its image would be
    closer to it: fails on a build whose members take the representative's scale times
    ``omega_p / omega_rep``)."""
    build = Build(shared_build)
    manifest = build.manifest
    assert manifest["version"] >= 3  # 4 since V may be float16, 5 since int8
    lights = build.selection.selectable.tolist()
    omega = np.array([light["solid_angle_sr"] for light in manifest["dome"]["lights"]])
    centroid = np.array([light["centroid"] for light in manifest["dome"]["lights"]])
    images, gain_ranges = {}, []
    for atlas_id, atlas in build.atlases.items():
        for stack, entry in atlas["sun_bounce"].items():
            compact = entry["compact"]
            table = compact["lights"]
            groups = _groups(table)
            assert sorted(p for members in groups.values() for p in members) == lights
            images[atlas_id, stack] = len(groups)
            assert compact["shared"]["images"] == len(groups)
            assert compact["error"]["test_lights"] == len(groups)
            for p in lights:  # files for the holders alone
                path = shared_build / table["ktx2"][0].format(index=p)
                assert path.is_file() == (p in groups), (atlas_id, stack, p)
            for members in groups.values():
                cos = centroid[members] @ centroid[members].T
                assert np.degrees(np.arccos(np.clip(cos.min(), -1, 1))) < 25.0, members
            master = build.sun_bounce_stack(atlas_id, stack)
            reader = build.sun_bounce_compact(atlas_id, stack)
            valid = np.any(master != 0, axis=(2, 3))
            worst, gains = 0.0, []
            for holder, members in groups.items():
                mean = master[:, :, members].sum(axis=2)[valid] / omega[members].sum()
                errors = []
                for p in members:
                    got = reader.lights([p])[p][valid].astype(np.float64)
                    errors.append(_best_scaled_error(got, omega[p] * mean))
                    own = master[:, :, p][valid].astype(np.float64)
                    gains.append((got * own).sum(axis=0) / (got * got).sum(axis=0))
                # one image, each light's own gain: the same error once scaled at its best
                assert np.ptp(errors) <= 1e-4 + 1e-3 * max(errors), (holder, errors)
                worst = max(worst, max(errors))
                reader.forget_lights()
            assert worst <= compact["error"]["max"] + 1e-4, (atlas_id, stack)
            np.testing.assert_allclose(gains, 1.0, atol=2e-3, err_msg=f"{atlas_id} {stack}")
            gain_ranges.append(compact["shared"]["gains"])
    # Sharing still saves images where it is free: the hull planes' closed-form `d` keeps
    # its 102 groups whole here (the models' faces, whose bounce pattern differs from a
    # neighbouring patch's, keep few or none).
    assert min(images.values()) < 0.6 * len(lights), images
    lows, highs = zip(*gain_ranges, strict=True)
    assert min(lows) < 0.9 and max(highs) > 1.1, gain_ranges  # the gains do something


def test_a_visit_fetches_one_image_per_group(shared_build):
    """bake/downloads.py over the two-hour visit: the sun crosses more patches than groups,
    and the sun's bounce over the visit is the sizes of the distinct holders' files (counted
    here from the patches and the tables); the GLB counts as the server sends it, gzipped."""
    import json

    manifest = json.loads((shared_build / "manifest.json").read_text())
    got = downloads.download_bytes(manifest, shared_build)
    patches = downloads.sun_patches_over(manifest, *downloads.VISIT)
    assert got["visit_sun_patches"] == len(patches)
    sizes = {f["path"]: f["bytes"] for f in manifest["files"]}
    files, per_stack = set(), []
    for atlas in manifest["atlases"]:
        if atlas["id"] == "hull":
            continue
        for entry in atlas["sun_bounce"].values():
            table = entry["compact"]["lights"]
            holders = {table["image"][p] for p in patches}
            per_stack.append(len(holders))
            for h in holders:
                files |= {pattern.format(index=h)
                          for pattern in table["ktx2"][: len(table["scale"][h])]}
    assert got["visit_sun_images"] == max(per_stack), (per_stack, patches)
    assert min(per_stack) < len(patches), (per_stack, patches)
    assert got["sun_bounce_visit"] == sum(sizes[f] for f in files)
    assert got["phone_visit_with_sun_bounce"] == got["phone_visit"] + got["sun_bounce_visit"]
    glb = (shared_build / manifest["model"]["path"]).read_bytes()
    sent = len(gzip.compress((shared_build / "manifest.json").read_bytes(), 6))
    base = set()  # the default atlases' base files, V and gain
    for atlas in manifest["atlases"]:
        if atlas["id"] != "hull":
            for entry in atlas["stacks"].values():
                c = entry["compact"]
                base |= {c["ktx2"], c["v"]["path"]} | {c[k]["ktx2"] for k in ("etc1s", "gain")
                                                      if c.get(k)}
    gzipped = len(gzip.compress(glb, 6, mtime=0))
    assert gzipped < len(glb)
    assert got["phone"] == sent + gzipped + sum(sizes[f] for f in base)


def _texel_p99(decoded: np.ndarray, bounce: np.ndarray, shown: np.ndarray) -> float:
    """99th percentile over texels and channels of ``|decoded - bounce|`` over the displayed
    value ``shown`` (T, 3 each), floored at a tenth of its mean."""
    floor = 0.1 * shown.mean()
    return float(np.percentile(np.abs(decoded - bounce) / np.maximum(shown, floor), 99))


def _errors_against_own_columns(build: Build, atlas_id: str, stack: str, lights, skies):
    """Each sun-path patch of ``lights`` decoded from its image against its *own* master
    column, as displayed (the display sky relit on the sky stack, the sun's direct term
    estimated from the masters, the bounce), computed here from the EXR masters: (RMS over
    the displayed mean, 99th percentile at single texels), two arrays (len(lights),)."""
    sky = build.stack(atlas_id, stack)
    valid = np.any(sky != 0.0, axis=(2, 3))
    sky = sky[valid].astype(np.float64)
    master = build.sun_bounce_stack(atlas_id, stack)[valid]
    reader = build.sun_bounce_compact(atlas_id, stack)
    rms, texel = [], []
    for p in lights:
        row = skies.row(p)
        w = skies.weight[row]
        bounce = master[:, p].astype(np.float64) * w
        direct = np.clip(sky[:, p] - master[:, p], 0.0, None) * w
        shown = np.einsum("tnc,nc->tc", sky, skies.r[row]) + direct + bounce
        decoded = reader.lights([p])[p][valid].astype(np.float64) * w
        reader.forget_lights()
        rms.append(np.sqrt(((decoded - bounce) ** 2).mean()) / shown.mean())
        texel.append(_texel_p99(decoded, bounce, shown))
    return np.array(rms), np.array(texel)


def test_the_bake_records_what_sharing_costs_each_patch_as_displayed(shared_build):
    """Each sun-path patch decoded from its group's image against its *own* master column,
    as displayed (:func:`_errors_against_own_columns`): it is what the bake recorded under
    ``error.displayed.shared`` (bake.sunwritten.read_back), larger than the images' own
    recorded error, which is judged against the group's column, where patches share (so the
    bake's report cannot hide the sharing); and a patch shares its group's image only where
    that keeps it within the budget, its RMS and at single texels
    (bake.sunshare.groups_within): fails on a
    build whose groups were kept whole or judged by their RMS alone (``"always"``: the test
    below)."""
    from bake.sundisplay import TEXEL_BOUND_PER_BUDGET, DisplaySkies

    build = Build(shared_build)
    lights = build.selection.selectable.tolist()
    skies = DisplaySkies.of_dome(build.dome_vertices, build.solid_angles, lights,
                                 build.manifest["scene"].get("elevation_m", 0.0))
    costs = []
    for atlas_id, atlas in build.atlases.items():
        for stack, entry in atlas["sun_bounce"].items():
            recorded = entry["compact"]["error"]["displayed"]
            errors, texel = _errors_against_own_columns(build, atlas_id, stack, lights, skies)
            shared = recorded["shared"]
            assert shared["lights"] == len(lights)
            assert shared["max"] == pytest.approx(errors.max(), rel=1e-3, abs=2e-6), stack
            assert shared["median"] == pytest.approx(np.median(errors), rel=1e-3, abs=2e-6)
            assert shared["worst_light"] == lights[int(np.argmax(errors))]
            assert shared["over_budget"] == int((errors > recorded["budget"]).sum())
            costs.append(shared["max"] > recorded["max"])
            for key, value in (("max", texel.max()), ("median", np.median(texel))):
                assert shared["texel_p99"][key] == pytest.approx(value, rel=1e-3, abs=1e-6)
            assert errors.max() <= recorded["budget"], (atlas_id, stack, errors.max())
            sharing = [i for i, p in enumerate(lights)
                       if len(_groups(entry["compact"]["lights"])[
                           entry["compact"]["lights"]["image"][p]]) > 1]
            worst_sharing = texel[sharing].max(initial=0.0)
            assert worst_sharing <= TEXEL_BOUND_PER_BUDGET * recorded["budget"], (
                atlas_id, stack, worst_sharing)
    assert any(costs)  # sharing shows in the report (not where a stack's images are its own)


def test_always_shares_every_group_and_records_what_it_costs(shared_build, tmp_path):
    """``compression.sun_bounce_sharing = "always"``: every sun-path patch reads its group's
    image, as many images as the 196-light dome makes groups and none taken out, each patch
    still at its own gain; the patches that sharing puts over the budget are recorded (on
    this site some are, where the default takes them out of their groups: the test above)."""
    from bake.sundisplay import TEXEL_BOUND_PER_BUDGET
    from bake.sunshare import SharedImages
    from tests.sunbounce_levels import recompress_sun_bounce

    build = Build(shared_build)
    dome = build.manifest["dome"]
    groups = SharedImages.of_dome(dome["kind"], dome["frequency"],
                                  build.selection.selectable, 196)
    always = Build(recompress_sun_bounce(shared_build, tmp_path / "always", 0.01,
                                         shared=groups, sharing="always"))
    over, texel_worst = 0, 0.0
    for atlas in always.atlases.values():
        for entry in atlas["sun_bounce"].values():
            shared = entry["compact"]["shared"]
            assert shared["images"] == len(groups.groups) and shared["split_out"] == 0
            assert len(_groups(entry["compact"]["lights"])) == len(groups.groups)
            over += entry["compact"]["error"]["displayed"]["shared"]["over_budget"]
            texel_worst = max(texel_worst,
                              entry["compact"]["error"]["displayed"]["shared"]["texel_p99"]["max"])
    assert over > 0
    # and at single texels (as recorded: the test above checks the record from the masters)
    assert texel_worst > TEXEL_BOUND_PER_BUDGET * 0.01, texel_worst


def test_the_written_images_are_read_back_once(shared_build, monkeypatch):
    """bake.sunwritten.read_back, as the bake runs it on a stack whose images are shared:
    every image file is decoded once and every master column read once (a stack on disk
    reads its block files whole for each read), and what it measures is what a reader of
    its own, decoding every light's files again, gives: each image against its group's
    column, and each patch's gain, which on the written build's table (its gains already
    fitted) is 1 within float32 rounding."""
    import copy

    import bake.sunwritten as sunwritten
    from bake.compact_reader import CompactReader
    from bake.rowstore import ArrayStack
    from bake.sunshare import SharedColumns, SharedImages
    from daylit.stackio import read_stack_exr

    build = Build(shared_build)
    entry = build.atlases["ground"]["sun_bounce"]["I"]
    compact = copy.deepcopy(entry["compact"])
    groups = _groups(compact["lights"])
    assert any(len(members) > 1 for members in groups.values())  # some patches share
    shared = SharedImages({rep: sorted(m) for rep, m in sorted(groups.items())},
                          build.solid_angles, "octahedral", 7)
    master = read_stack_exr(shared_build / entry["master"])

    class Counted(ArrayStack):
        def __init__(self, image):
            super().__init__(image)
            self.read: list[int] = []

        def columns(self, lights):
            self.read.extend(int(i) for i in lights)
            return super().columns(lights)

    decoded: list[str] = []
    real_decode = sunwritten.decode

    def counted_decode(files):
        decoded.extend(Path(f).name for f in files)
        return real_decode(files)

    monkeypatch.setattr(sunwritten, "decode", counted_decode)
    own = Counted(master)
    reps = shared.representatives
    measured = sunwritten.read_back(shared_build, compact, own, reps, None, shared)
    assert sorted(own.read) == sorted(p for m in groups.values() for p in m)
    assert sorted(decoded) == sorted(f"ground.sun_bounce.I.L{rep:04d}.ktx2" for rep in reps)
    lowest, highest = measured.gains
    assert 1 - 1e-4 < lowest <= highest < 1 + 1e-4

    fresh = CompactReader(shared_build, entry["compact"], master.shape[:2])
    valid = own.valid
    columns = SharedColumns(ArrayStack(master), shared).columns(reps)
    for j, rep in enumerate(reps):
        expected = sunwritten.column_error(fresh.lights([rep])[rep], columns[j], valid)
        assert measured.rms[j] == pytest.approx(expected, rel=1e-6), rep


def test_an_rdo_image_is_encoded_as_it_is_alone(shared_build, tmp_path, monkeypatch):
    """The sun-bounce images' cheaper tries include UASTC with RDO (bake.sunbounce
    ``cheaper_encodings``). basisu 1.16's RDO writes an image after other images in the
    same process differently now and then from run to run (this site's hull image 140: 7 of
    100 runs; docs/benchmarks.md, "RDO images encoded one per process"), which made 2 of 9
    bakes of this site differ in a file. So each RDO image has an encoder process of its
    own: the hull's sun-bounce images, all in one bake.basisu.encode call, are each the
    bytes that image gets encoded alone, and no encoder was given two of them."""
    import bake.basisu as basisu
    from bake.compresssettings import Settings
    from bake.quantize import quantized_png
    from daylit.stackio import read_stack_exr

    build = Build(shared_build)
    master = read_stack_exr(shared_build / build.atlases["hull"]["sun_bounce"]["I"]["master"])
    drawn = [i for i in range(master.shape[2]) if master[:, :, i].max() > 0]
    assert len(drawn) > 100  # the sun-path patches
    pngs = [quantized_png(master[:, :, i], tmp_path / f"L{i:04d}.png").path for i in drawn]
    settings = Settings()
    rdo = settings.sun_bounce_rdo_lambdas[-1]

    commands: list[list[str]] = []
    real_start = basisu._start_encoder

    def recorded(command):
        commands.append(command)
        return real_start(command)

    monkeypatch.setattr(basisu, "_start_encoder", recorded)
    together = tmp_path / "together"
    together.mkdir()
    basisu.encode(pngs, together, settings, array=False, level=0, rdo_lambda=rdo)
    given = sorted(tuple(a for a in c if a.endswith(".png")) for c in commands)
    assert given == sorted((str(p),) for p in pngs)  # one image per encoder, each once
    monkeypatch.undo()

    for png in pngs:
        alone = tmp_path / "alone" / png.stem
        alone.mkdir(parents=True)
        basisu.encode([png], alone, settings, array=False, level=0, rdo_lambda=rdo)
        name = png.stem + ".ktx2"
        assert (together / name).read_bytes() == (alone / name).read_bytes(), name


def test_the_rdo_dictionary_setting_is_what_the_encoder_uses(tmp_path):
    """``sun_bounce_rdo_dictionary_bytes`` reaches basisu (``-uastc_rdo_d``): on an image
    whose blocks repeat two block rows down (64 x 384 texels: 96 blocks, 1536 bytes, a row;
    so 3072 bytes back, within basisu's own default dictionary of 4096 and out of 2048)
    the default (2048 bytes) writes the bytes of 2048 given explicitly and 4096 other bytes;
    each decodes to the image's size (docs/benchmarks.md, "The RDO dictionary")."""
    from dataclasses import replace

    from bake.basisu import encode
    from bake.compresssettings import Settings
    from bake.ktx2decoder import decode
    from bake.quantize import quantized_png

    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:64, 0:384].astype(float)
    rows = np.sin(2 * np.pi * y / 8) * np.cos(2 * np.pi * x / 37)  # period: two block rows
    image = 0.5 + 0.3 * rows[..., None] * np.array([1.0, 0.9, 0.8])
    image += 0.01 * rng.random(image.shape)
    png = quantized_png(image.astype(np.float32), tmp_path / "x.png").path
    settings = Settings()
    assert settings.sun_bounce_rdo_dictionary_bytes == 2048
    rdo = settings.sun_bounce_rdo_lambdas[-1]
    written = {}
    for label, dictionary in (("default", None), ("2048", 2048), ("4096", 4096)):
        out = tmp_path / label
        out.mkdir()
        tried = settings if dictionary is None else replace(
            settings, sun_bounce_rdo_dictionary_bytes=dictionary)
        encode([png], out, tried, array=False, level=0, rdo_lambda=rdo)
        written[label] = (out / "x.ktx2").read_bytes()
        [decoded] = decode([out / "x.ktx2"])
        assert decoded[0].shape[:2] == (64, 384)
    assert written["default"] == written["2048"]
    assert written["default"] != written["4096"]
