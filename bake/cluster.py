"""Tracing a bake's chunks on a Dask distributed cluster (``daylit bake --cluster ADDRESS``).

The chunks are the local process pool's (bake.tracework): the same points, the same random
numbers from ``(seed, stage, name, chunk)`` and the same estimator, so a cluster bake writes
the same bytes as a local one. What differs is where the arrays go: a worker may run on
another machine with no view of the baking machine's disk, so it returns each chunk's arrays
and the baking process saves them under the partial folder as they arrive
(:func:`bake.chunkio.save_chunk`, the local pool's format and names). An interrupted cluster
bake therefore resumes, locally or on a cluster, from the chunks it saved.

Each worker needs daylit (the same version as the baking machine: another version could trace
differently), its Python dependencies and nothing else: the geometry, the dome and the bounce
cache are sent to every worker once per stage (``Client.scatter(..., broadcast=True)``), and
each worker process builds its Embree scenes from them once and keeps them while the stage
runs.
"""

from __future__ import annotations

import contextlib
import threading
import uuid
from dataclasses import dataclass

import numpy as np

from bake import chunkio
from bake.errors import BakeError

CONNECT_TIMEOUT_S = 10
WORKERS_TIMEOUT_S = 60
_POLL_S = 1.0  # how often a compression job's wait checks whether the bake was stopped


@dataclass
class WorkerSetup:
    """What every worker needs to trace a stage's chunks: the arguments of the local pool's
    initializer (bake.tracework), with the bounce cache's arrays instead of its file
    (``cache``: ``None`` for the cache stage itself, else ``{name: array}`` as
    ``cache.npz`` holds them). ``token`` tells one stage's setup from the next."""

    geometry: object
    dome_vertices: np.ndarray
    ground_albedo: np.ndarray
    samples: int
    bounce_rays: int
    cache: dict | None
    token: str


# {(setup token, thread id): Estimator}: a worker's threads share the setup, not the
# estimator (it counts its rays). Only the newest stage's estimators are kept.
_ESTIMATORS: dict = {}
_ESTIMATORS_LOCK = threading.Lock()


def _estimator(setup: WorkerSetup):
    from bake.irradiance import BounceCache, Estimator, SceneSet

    key = (setup.token, threading.get_ident())
    with _ESTIMATORS_LOCK:
        found = _ESTIMATORS.get(key)
        if found is not None:
            return found
        for old in [k for k in _ESTIMATORS if k[0] != setup.token]:
            del _ESTIMATORS[old]
    scenes = SceneSet.build(setup.geometry, setup.ground_albedo)
    cache = None
    if setup.cache is not None:
        cache = BounceCache.from_arrays(setup.cache, setup.geometry)
    estimator = Estimator(setup.dome_vertices, scenes, setup.samples, setup.bounce_rays, cache)
    with _ESTIMATORS_LOCK:
        _ESTIMATORS[key] = estimator
    return estimator


def trace_chunk(setup: WorkerSetup, points, normals, configs, bounce, seed_words):
    """Run on a worker: one chunk's arrays (``{config: array}``, as the local pool saves
    them) and the rays cast. ``points``, ``normals``: (P, 3) metres, unit."""
    estimator = _estimator(setup)
    estimator.rays_cast = 0
    rng = np.random.default_rng(seed_words)
    if bounce:
        out = estimator.basis(points, normals, configs, rng)
    else:
        out = estimator.direct(points, normals, configs, rng)
    return out, estimator.rays_cast


class Cluster:
    """A connection to a Dask scheduler that traces chunks on its workers."""

    def __init__(self, address: str, log):
        """Connect and check the workers; raises :class:`BakeError` saying what to do when
        the scheduler cannot be reached, has no workers or its workers cannot run this
        daylit. Nothing is traced or written before this succeeds."""
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - a pinned dependency
            raise BakeError(
                f"--cluster needs dask.distributed ({exc}); install daylit's dependencies"
            ) from None
        self.address = address
        try:
            self.client = Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise BakeError(
                f"cannot reach the Dask scheduler at {address} ({exc}). Check the address "
                "and port, or start a scheduler there (`dask scheduler`) and workers with "
                f"daylit installed (`dask worker {address}`); or bake on this machine "
                "without --cluster. Nothing was written."
            ) from None
        try:
            self._check_workers(log)
        except BaseException:
            self.client.close()
            raise

    def _check_workers(self, log) -> None:
        from daylit import __version__

        try:
            self.client.wait_for_workers(1, timeout=WORKERS_TIMEOUT_S)
        except TimeoutError:
            raise BakeError(
                f"the Dask scheduler at {self.address} has had no workers for "
                f"{WORKERS_TIMEOUT_S} s: start some (`dask worker {self.address}` on machines "
                "with daylit installed) and run the same command again. Nothing was written."
            ) from None

        def version():  # defined here: sent by value, so a worker without daylit can answer
            try:
                import daylit
            except ImportError as exc:
                return f"no daylit ({exc})"
            return daylit.__version__

        found = self.client.run(version)
        wrong = {worker: v for worker, v in found.items() if v != __version__}
        if wrong:
            raise BakeError(
                f"workers of {self.address} cannot bake with daylit {__version__}: "
                + ", ".join(f"{w}: {v}" for w, v in sorted(wrong.items()))
                + ". Install the same daylit on every worker. Nothing was written."
            )
        from bake.compressjobs import encoder_problem

        problems = {w: p for w, p in self.client.run(encoder_problem).items() if p is not None}
        if problems:
            raise BakeError(
                f"workers of {self.address} cannot compress the build's textures (the write "
                "stage runs on the workers too): "
                + "; ".join(f"{w}: {p}" for w, p in sorted(problems.items()))
                + ". Nothing was written."
            )
        log(f"  cluster {self.address}: {len(found)} workers, {self.threads} threads")

    @property
    def threads(self) -> int:
        return sum(self.client.nthreads().values())

    def run(self, todo: list, setup_args: tuple, cache: dict | None, bar) -> int:
        """Trace ``todo`` (``[(points, (points, normals, configs, bounce, seed words,
        path))]`` as bake.tracework lists them) on the workers and save each chunk to its
        path as it arrives; returns the rays cast. ``setup_args``: the local initializer's
        first five arguments."""
        from distributed import as_completed

        if not todo:
            return 0
        setup = WorkerSetup(*setup_args, cache=cache, token=uuid.uuid4().hex)
        shared = self.client.scatter(setup, broadcast=True, hash=False)
        pending = {}
        for count, (points, normals, configs, bounce, words, path) in todo:
            future = self.client.submit(
                trace_chunk,
                shared,
                points,
                normals,
                configs,
                bounce,
                words,
                key=f"daylit-chunk-{path.stem}-{setup.token[:8]}",
                pure=False,
            )
            pending[future] = (count, path)
        rays = 0
        try:
            for future in as_completed(pending, loop=self.client.loop):
                out, cast = future.result()
                count, path = pending.pop(future)
                chunkio.save_chunk(path, out)
                rays += cast
                bar.update(count)
                del out, future
        except BaseException:
            self.client.cancel(list(pending))
            raise
        finally:
            self.client.cancel([shared])
        return rays

    def compress(self, job, *args):
        """Run a compression job (bake.compressjobs) on a worker and return its result; the
        arguments (a unit's stacks) are sent to the scheduler's choice of worker. Waits in
        short steps: when the bake is stopped (:func:`bake.basisu.stop_encoding`: another
        unit failed, or Ctrl-C) the job is cancelled and CompressionError raised."""
        from bake import basisu

        basisu.check_not_stopped()
        data = self.client.scatter(list(args), hash=False)
        future = self.client.submit(
            job, *data, key=f"daylit-{job.__name__}-{uuid.uuid4().hex[:12]}", pure=False
        )
        try:
            while True:
                try:
                    return future.result(timeout=_POLL_S)
                except TimeoutError:
                    basisu.check_not_stopped()
        finally:
            self.client.cancel([future, *data])

    def close(self) -> None:
        """End the workers' KTX2 decoders (bake.ktx2decoder: kept from job to job during the
        bake) and disconnect; the workers themselves go on."""
        from bake.ktx2decoder import close_decoders

        try:
            # After a failure the error that matters is the one being raised, not this one.
            with contextlib.suppress(Exception):
                self.client.run(close_decoders)
        finally:
            self.client.close()
