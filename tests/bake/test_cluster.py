"""Baking on a Dask cluster (``daylit bake --cluster``): the same bytes as the local process
pool, resumable locally, and a clear error when the scheduler cannot be reached or its
workers cannot compress.

The cluster is a ``LocalCluster`` of two worker processes started here; the workers trace,
return each chunk's arrays and the baking process saves them (bake.cluster); they compress
the stacks and return the files' bytes, which the baking process writes
(bake.compressjobs)."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from bake import basisu, chunkio, compress, compressjobs, ktx2decoder, sunbounce, tracework
from bake.errors import BakeError
from bake.pipeline import bake
from daylit.cli import main
from tests.buildfiles import build_files
from tests.sites import make_site

pytestmark = pytest.mark.slow

QUIET = {"progress": False, "log": lambda msg: None}
# Small chunks, so the test scene has several per point set (the layout is the baking
# process's: it does not depend on where the chunks run).
RAYS_PER_CHUNK = 60_000
@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as local:
        yield local.scheduler_address


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    # Two bounces: the workers must get the cache points' own bounces too (B_all, B_real).
    return make_site(tmp_path_factory.mktemp("cluster") / "scene", lights=40, hull_texel_m=0.25,
                     bounces=2)


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    """The scene baked by the local pool of two processes."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tracework, "RAYS_PER_CHUNK", RAYS_PER_CHUNK)
        out = tmp_path_factory.mktemp("reference") / "local"
        bake(scene, out, workers=2, **QUIET)
    return build_files(out)


def test_a_cluster_bake_writes_the_same_bytes_as_the_local_pool(
    scene, reference, cluster, tmp_path, monkeypatch
):
    monkeypatch.setattr(tracework, "RAYS_PER_CHUNK", RAYS_PER_CHUNK)

    def not_here(*args, **kwargs):
        raise AssertionError("compressed in the baking process, not on a worker")

    # The workers (other processes) compress; the baking process only writes their bytes.
    monkeypatch.setattr(compress, "compress_stacks", not_here)
    monkeypatch.setattr(sunbounce, "compress_sun_bounce", not_here)
    from distributed import Client

    messages: list[str] = []
    with Client(cluster) as client:
        launched_before = client.run(ktx2decoder.launches)
        result = bake(scene, tmp_path / "out", cluster=cluster, progress=False,
                      log=messages.append)
        launched = client.run(ktx2decoder.launches)
        running = client.run(ktx2decoder.running)
    # The workers decoded with a Node process each (one thread each), all ended with the bake.
    assert 1 <= sum(launched[w] - launched_before[w] for w in launched) <= len(launched)
    assert set(running.values()) == {0}
    assert any(f"on the cluster {cluster}" in m for m in messages)
    assert result.rays > 0
    baked = build_files(tmp_path / "out")
    assert len(reference) >= 10 and any(p.endswith(".ktx2") for p in reference)
    # The coarse start (bake.coarse) is cut by the baking process from the workers' arrays.
    assert any(p.startswith("coarse/") for p in reference)
    assert baked.keys() == reference.keys()
    for path in reference:
        assert baked[path] == reference[path], path
    assert not (tmp_path / ".out.partial").exists()


def test_an_interrupted_cluster_bake_resumes_locally_to_the_same_bytes(
    scene, reference, cluster, tmp_path, monkeypatch
):
    monkeypatch.setattr(tracework, "RAYS_PER_CHUNK", RAYS_PER_CHUNK)
    out, partial = tmp_path / "out", tmp_path / ".out.partial"
    saved: list[Path] = []
    save_chunk = chunkio.save_chunk

    def ctrl_c_after_three(path, arrays):
        # The baking process saves the chunks the workers return: Ctrl-C after the third.
        save_chunk(path, arrays)
        saved.append(path)
        if len(saved) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(chunkio, "save_chunk", ctrl_c_after_three)
    with pytest.raises(KeyboardInterrupt):
        bake(scene, out, cluster=cluster, **QUIET)
    monkeypatch.setattr(chunkio, "save_chunk", save_chunk)
    assert not out.exists()  # nothing half-written where the build goes
    kept = sorted((partial / "chunks").glob("*" + chunkio.SUFFIX))
    assert kept == sorted(saved)
    assert not list((partial / "chunks").glob("*.tmp"))
    total = sum(len(s.chunks) for s in _chunked_sets(scene))
    assert 3 == len(kept) < total  # the interruption left work to do

    messages: list[str] = []
    result = bake(scene, out, workers=2, progress=False, log=messages.append)
    assert any("resuming: 3 chunks already baked" in m for m in messages)
    assert result.rays > 0
    resumed = build_files(out)
    assert resumed.keys() == reference.keys()
    for path in reference:
        assert resumed[path] == reference[path], path
    assert not partial.exists()


def _chunked_sets(scene: Path) -> list:
    """The point sets of the scene as the bake chunks them (cache set first)."""
    from bake import pipeline
    from bake.dome import Dome
    from bake.irradiance import SceneSet
    from bake.scene import load_site

    site = load_site(scene)
    dome = Dome.for_light_count(site.settings.lights)
    geometry = pipeline._site_geometry(site)
    scenes = SceneSet.build(geometry, site.ground.albedo)
    atlases = pipeline._atlases(site, dome, geometry, scenes, lambda m: None)
    samples = max(2, -(-site.settings.direct_rays // dome.count))
    work = tracework.TraceWork(site, dome, geometry, atlases, {}, samples, lambda m: None)
    return [work.cache_set, *work.point_sets]


def _closed_port() -> int:
    """A local port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_scheduler_is_a_clear_error_before_any_work(tmp_path, capsys):
    scene = make_site(tmp_path / "scene")
    address = f"tcp://127.0.0.1:{_closed_port()}"
    out = tmp_path / "out"
    with pytest.raises(BakeError) as caught:
        bake(scene, out, cluster=address, **QUIET)
    message = str(caught.value)
    assert f"cannot reach the Dask scheduler at {address}" in message
    assert "dask scheduler" in message and "without --cluster" in message
    assert not out.exists() and not (tmp_path / ".out.partial").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]

    status = main(["bake", str(scene), "-o", str(out), "--cluster", address, "--no-progress"])
    assert status == 2
    assert f"error: cannot reach the Dask scheduler at {address}" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]


def test_workers_that_cannot_compress_are_a_clear_error_before_any_work(
    tmp_path, monkeypatch, capsys
):
    from distributed import LocalCluster

    scene = make_site(tmp_path / "scene")
    out = tmp_path / "out"
    # Workers in this process (threads), so that they see a checkout without `npm ci`.
    checkout = tmp_path / "checkout"
    monkeypatch.setattr(basisu, "REPO_ROOT", checkout)
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    ) as local:
        with pytest.raises(BakeError) as caught:
            bake(scene, out, cluster=local.scheduler_address, **QUIET)
        message = str(caught.value)
        assert "cannot compress" in message and "the basisu encoder is missing" in message
        assert f"run `npm ci` in {checkout}" in message and "Nothing was written" in message
        assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]

        status = main(["bake", str(scene), "-o", str(out), "--cluster",
                       local.scheduler_address, "--no-progress"])
    assert status == 2
    assert "the basisu encoder is missing" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]


def test_this_machine_can_compress_and_a_job_writes_inside_the_build_only(tmp_path):
    assert compressjobs.encoder_problem() is None  # what the cluster tests' workers have
    written = compressjobs.write_files(tmp_path, {"ktx2/a.ktx2": b"abc", "v/b.bin": b"d"})
    assert [p.read_bytes() for p in written] == [b"abc", b"d"]
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.ktx2", "b.bin", "ktx2", "v"]
    for bad in ("../escape.ktx2", "/tmp/escape.ktx2"):
        with pytest.raises(ValueError, match="outside the build"):
            compressjobs.write_files(tmp_path / "build", {bad: b"x"})
    assert not (tmp_path / "escape.ktx2").exists()
