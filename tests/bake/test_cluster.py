"""Baking on a Dask cluster (``daylit bake --cluster``): the same bytes as the local process
pool, resumable locally, and a clear error when the scheduler cannot be reached or its
workers cannot compress.

The cluster is a ``LocalCluster`` of two worker processes started here; the workers trace,
return each chunk's arrays and the baking process saves them (bake.cluster); they compress
the stacks and return the files' bytes, which the baking process writes
(bake.compressjobs)."""

from __future__ import annotations

import os
import signal
import socket
import threading
from pathlib import Path

import pytest

from bake import (
    basisu,
    chunkio,
    compressjobs,
    ktx2decoder,
    stackkinds,
    sunbounce,
    tracework,
)
from bake import cluster as cluster_mod
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
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
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
    monkeypatch.setattr(stackkinds, "compress_stacks", not_here)
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


def test_workers_killed_mid_trace_are_replaced_and_the_bytes_are_the_same(
    scene, reference, tmp_path, monkeypatch
):
    """Worker processes killed (SIGKILL: a machine's out-of-memory killer, a reboot) while
    they trace: first one (Dask runs its chunks on the other and on the nanny's new one),
    then every one (the stage's setup is lost with them: the bake scatters it again). The
    bake finishes with the local pool's bytes.

    The victims really hold work when they die, however many chunks the cache or the other
    sets make and however fast the workers are: the first task of the second stage to
    start holds its chunk (waits before tracing it) until its worker is killed, and after
    that kill, the next task to start does the same until every worker is killed. The
    first kill happens when another chunk is saved (so a chunk is saved before it), the
    second as soon as a task holds. Nothing here depends on how many chunks got done
    meanwhile."""
    from distributed import Client, LocalCluster

    monkeypatch.setattr(tracework, "RAYS_PER_CHUNK", RAYS_PER_CHUNK)
    out = tmp_path / "out"
    gate = tmp_path / "gate"
    gate.mkdir()
    killed: list = []
    sent: list = []
    save_chunk = chunkio.save_chunk
    run_once = cluster_mod.Cluster._run_once
    monkeypatch.setattr(cluster_mod, "trace_chunk", _holding(cluster_mod.trace_chunk, gate))

    def counted_run_once(self, setup, remaining, bar):
        sent.append(len(remaining))
        return run_once(self, setup, remaining, bar)

    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as local, Client(local) as client:

        def kill_one(path, arrays):
            save_chunk(path, arrays)
            if (gate / "hold1").exists() and not killed:  # the worker holding a chunk
                held = int((gate / "hold1").read_text())
                # A worker just killed may still be listed: ask the living ones.
                victim = [w for w, pid in client.run(os.getpid, on_error="ignore").items()
                          if pid == held]
                processing = client.processing()
                assert victim and processing[victim[0]]  # busy with the held chunk
                os.kill(held, signal.SIGKILL)
                killed.append({victim[0]: processing[victim[0]]})
                (gate / "killed1").touch()  # from now on the next task to start holds

        def kill_all():
            # Not at a save: the held chunk may be the stage's last one.
            while not (gate / "hold2").exists():
                if stop.wait(0.05):
                    return
            pids = client.run(os.getpid, on_error="ignore")
            assert int((gate / "hold2").read_text()) in pids.values()
            for pid in pids.values():
                os.kill(pid, signal.SIGKILL)
            killed.append(pids)

        stop = threading.Event()
        killer = threading.Thread(target=kill_all, daemon=True)
        killer.start()
        monkeypatch.setattr(chunkio, "save_chunk", kill_one)
        monkeypatch.setattr(cluster_mod.Cluster, "_run_once", counted_run_once)
        try:
            result = bake(scene, out, cluster=local.scheduler_address, **QUIET)
        finally:
            stop.set()
            killer.join()
    assert len(killed) == 2
    assert any(killed[0].values())  # it died holding chunks
    # Once for the cache's chunks, once for the rest, and again after every worker died (at
    # least the held chunk: its result died with it). On a loaded machine the killed workers
    # may still be listed when the setup is scattered again, so it is lost once more and
    # sent a further time (bake.cluster.SETUP_RESENDS bounds it): seen once under load.
    assert len(sent) >= 3 and sent[0] >= 1, sent
    assert all(0 < n < sent[1] for n in sent[2:]), sent
    assert result.rays > 0
    baked = build_files(out)
    assert baked.keys() == reference.keys()
    for path in reference:
        assert baked[path] == reference[path], path
    assert not (tmp_path / ".out.partial").exists()


def _holding(trace_chunk, gate: Path, hold_s: float = 600.0):
    """``trace_chunk`` (bake.cluster's) behind a gate in the folder ``gate``: the first of the
    second stage's tasks (``bounce``) to start writes its process id to ``hold1`` and waits;
    once ``killed1`` exists, the next task to start writes ``hold2`` and waits. A waiting
    task traces as usual after ``hold_s`` (only if the test went wrong: it then fails on its
    kills instead of hanging). The function is sent to the workers by value (cloudpickle: it
    is defined in a function), and calls the real one, so the bytes are bake.cluster's."""

    def held(setup, points, normals, configs, bounce, seed_words):
        import os
        import time

        if bounce:
            for k in (1, 2):
                if k == 2 and not (gate / "killed1").exists():
                    break
                mine = gate / f"pid{os.getpid()}-{k}"
                mine.write_text(str(os.getpid()))
                try:  # a link is made whole or not at all: one task takes each hold
                    os.link(mine, gate / f"hold{k}")
                except FileExistsError:
                    continue
                deadline = time.monotonic() + hold_s
                while time.monotonic() < deadline:
                    time.sleep(0.05)
                break
        return trace_chunk(setup, points, normals, configs, bounce, seed_words)

    return held


def test_a_chunk_dask_gives_up_on_is_exit_2_with_what_to_do_and_resumes_locally(
    scene, reference, tmp_path, monkeypatch, capsys
):
    """A chunk that kills every worker it runs on: Dask tries it on allowed-failures + 1
    workers, then gives up (KilledWorker). The bake ends with exit status 2, says which
    chunk, how many chunks are saved and the commands to resume; nothing is published; a
    local resume gives the local pool's bytes."""
    from distributed import LocalCluster

    monkeypatch.setattr(tracework, "RAYS_PER_CHUNK", RAYS_PER_CHUNK)

    def killer(setup, points, normals, configs, bounce, seed_words):
        # Stands in for bake.cluster.trace_chunk on the workers (a local function: cloudpickle
        # sends it by value): the worker running an atlas's chunk 1 dies at once, every time.
        import os

        from bake import cluster, tracework

        if seed_words[1] == tracework.STAGE_CODES["atlas"] and seed_words[3] == 1:
            os._exit(1)
        return cluster.trace_chunk(setup, points, normals, configs, bounce, seed_words)

    monkeypatch.setattr(cluster_mod, "trace_chunk", killer)
    out, partial = tmp_path / "out", tmp_path / ".out.partial"
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as local:
        local.scheduler.allowed_failures = 1  # two deaths, then KilledWorker
        address = local.scheduler_address
        status = main(
            ["bake", str(scene), "-o", str(out), "--cluster", address, "--no-progress"]
        )
    err = capsys.readouterr().err
    assert status == 2, err
    message = err[err.index("error: "):]
    assert "Traceback" not in err
    assert "the cluster bake stopped while tracing: Dask gave up on chunk 1 of" in message
    assert "(stage atlas" in message and "the 2 workers that ran it all died" in message
    saved = sorted((partial / "chunks").glob("*" + chunkio.SUFFIX))
    total = sum(len(s.chunks) for s in _chunked_sets(scene))
    assert 0 < len(saved) < total
    assert f"{len(saved)} of {total} traced chunks are saved in {partial}" in message
    assert f"`daylit bake {scene} -o {out} --cluster {address}`" in message
    assert f"or on this machine: `daylit bake {scene} -o {out}`" in message
    assert not out.exists()  # nothing published, nothing half-written
    assert not list((partial / "chunks").glob("*.tmp"))

    monkeypatch.undo()
    messages: list[str] = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tracework, "RAYS_PER_CHUNK", RAYS_PER_CHUNK)
        bake(scene, out, workers=2, progress=False, log=messages.append)
    assert any(f"resuming: {len(saved)} chunks already baked" in m for m in messages)
    resumed = build_files(out)
    assert resumed.keys() == reference.keys()
    for path in reference:
        assert resumed[path] == reference[path], path
    assert not partial.exists()


def test_a_worker_leaving_during_the_setup_broadcast_is_waited_out(scene, reference, tmp_path,
                                                                   monkeypatch):
    """A worker that leaves while the stage's setup is broadcast makes the scheduler refuse
    the scatter with a ValueError (met on CI: "Can not use replicate to delete data"). Here
    the real client's first broadcast is refused so: the bake sends it again and ends with
    the local pool's bytes."""
    from distributed import Client, LocalCluster

    monkeypatch.setattr(tracework, "RAYS_PER_CHUNK", RAYS_PER_CHUNK)
    refused: list = []
    scatter = Client.scatter

    def refused_once(self, *args, **kwargs):
        if not refused:
            refused.append(True)
            raise ValueError("Can not use replicate to delete data")
        return scatter(self, *args, **kwargs)

    monkeypatch.setattr(Client, "scatter", refused_once)
    out = tmp_path / "out"
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as local:
        bake(scene, out, cluster=local.scheduler_address, **QUIET)
    assert refused
    assert build_files(out) == reference


def test_a_cluster_left_without_workers_is_exit_2_with_what_to_do(
    scene, tmp_path, monkeypatch, capsys
):
    """Every worker gone for longer than the no-workers timeout (the scheduler would wait
    for one forever): the bake ends with the message, the saved chunks kept."""
    from distributed import LocalCluster

    monkeypatch.setattr(tracework, "RAYS_PER_CHUNK", RAYS_PER_CHUNK)
    monkeypatch.setattr(cluster_mod, "WORKERS_TIMEOUT_S", 2)
    out, partial = tmp_path / "out", tmp_path / ".out.partial"
    save_chunk = chunkio.save_chunk
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as local:

        def stop_the_workers_after_one(path, arrays):
            save_chunk(path, arrays)
            local.scale(0)

        monkeypatch.setattr(chunkio, "save_chunk", stop_the_workers_after_one)
        address = local.scheduler_address
        status = main(["bake", str(scene), "-o", str(out), "--cluster", address,
                       "--no-progress"])
    err = capsys.readouterr().err
    assert status == 2, err
    assert "has had no workers for 2 s" in err and "Traceback" not in err
    saved = sorted((partial / "chunks").glob("*" + chunkio.SUFFIX))
    assert len(saved) >= 1 and f"{len(saved)} of " in err
    assert f"--cluster {address}`, or on this machine: `daylit bake {scene} -o {out}`" in err
    assert not out.exists()


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
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0"
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
