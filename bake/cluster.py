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

Workers die (a machine reboots, a worker runs out of memory). Dask runs a dead worker's tasks
again on the others by itself, up to the scheduler's ``allowed-failures``; when every worker
holding a stage's setup died, its chunks are sent again with the setup scattered anew (at most
:data:`SETUP_RESENDS` times a stage). A failure that is final (a chunk Dask gave up on:
``KilledWorker``; no worker for :data:`WORKERS_TIMEOUT_S`; the scheduler gone) raises
:class:`ClusterLostError`, saying what happened; the bake (bake.pipeline) adds what was saved and
how to resume. The chunks saved until then are kept: they are the local pool's.
"""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from dataclasses import dataclass

import numpy as np

from bake import chunkio
from bake.errors import BakeError

CONNECT_TIMEOUT_S = 10
WORKERS_TIMEOUT_S = 60
_POLL_S = 1.0  # how often a wait checks whether the bake was stopped or the workers gone
SETUP_RESENDS = 3  # times a stage's setup is scattered again after all its holders died


class ClusterLostError(BakeError):
    """A cluster failure the bake cannot get past by itself (its message says what happened;
    the bake adds what was saved and the commands to resume)."""


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
    return _estimator(setup).chunk(points, normals, configs, bounce, seed_words)


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
        first five arguments. Raises :class:`ClusterLostError` on a final failure (module
        docstring), with the chunks saved until then kept."""
        if not todo:
            return 0
        setup = WorkerSetup(*setup_args, cache=cache, token=uuid.uuid4().hex)
        remaining = {task[-1]: (count, task) for count, task in todo}  # by chunk path
        rays = 0
        for _ in range(SETUP_RESENDS + 1):
            rays += self._run_once(setup, remaining, bar)
            if not remaining:
                return rays
        raise ClusterLostError(
            f"the workers of {self.address} holding the stage's geometry all died "
            f"{SETUP_RESENDS + 1} times while tracing it"
        )

    def _run_once(self, setup: WorkerSetup, remaining: dict, bar) -> int:
        """Scatter ``setup``, trace the chunks of ``remaining`` ({path: (points, task)}),
        removing each one saved; returns the rays cast. Chunks are left in ``remaining`` when
        Dask cancelled them because every worker holding the setup died (scattered data
        cannot be recomputed: the caller scatters it again)."""
        from distributed import as_completed
        from distributed.client import FutureCancelledError
        from distributed.scheduler import KilledWorker, NoValidWorkerError

        shared = self._scatter_to_all(setup)
        pending = {}
        for path, (_, (points, normals, configs, bounce, words, _)) in remaining.items():
            future = self.client.submit(
                trace_chunk,
                shared,
                points,
                normals,
                configs,
                bounce,
                words,
                key=f"daylit-chunk-{path.stem}-{uuid.uuid4().hex[:8]}",
                pure=False,
            )
            pending[future] = path
        rays = 0
        finished = as_completed(pending, loop=self.client.loop)
        try:
            while not finished.is_empty():
                future = self._next_finished(finished)
                path = pending.pop(future)
                try:
                    out, cast = future.result()
                except KilledWorker as exc:
                    raise ClusterLostError(
                        f"Dask gave up on {chunk_label(path)}: the {exc.allowed_failures + 1} "
                        f"workers that ran it all died (KilledWorker; the last was "
                        f"{_address(exc.last_worker)}). A worker dies when its machine "
                        "restarts or it runs out of memory (the scheduler's dashboard and the "
                        "workers' logs say which)"
                    ) from None
                except NoValidWorkerError:
                    raise ClusterLostError(
                        f"the scheduler at {self.address} had no worker for {chunk_label(path)} "
                        "for longer than its no-workers-timeout"
                    ) from None
                except FutureCancelledError:
                    if self.client.status not in ("running", "connecting"):
                        raise self._lost_scheduler("the client was closed") from None
                    # Every holder of the setup died: the others are cancelled at once too
                    # (or finished, or given up on: drained here); the caller sends it again.
                    continue
                chunkio.save_chunk(path, out)
                count, _ = remaining.pop(path)
                rays += cast
                bar.update(count)
                del out, future
        finally:
            # Whatever is still pending (an error, Ctrl-C, or a lost setup) is not wanted.
            with contextlib.suppress(Exception):
                self.client.cancel([*pending, shared])
        return rays

    def _scatter_to_all(self, setup: WorkerSetup):
        """``setup`` scattered to every worker, once there is one. A worker that leaves during
        the broadcast makes Dask's scheduler refuse it ("Can not use replicate to delete
        data", a ValueError: CI met it while the test's only worker was being retired): the
        workers are looked at again and the setup sent again, at most SETUP_RESENDS times."""
        for _ in range(SETUP_RESENDS + 1):
            self._wait_for_a_worker()
            try:
                return self.client.scatter(setup, broadcast=True, hash=False)
            except (OSError, TimeoutError) as exc:
                raise self._lost_scheduler(exc) from None
            except ValueError as exc:
                refused = exc
                time.sleep(_POLL_S)
        raise ClusterLostError(
            f"the workers of {self.address} kept leaving while the stage's geometry was sent "
            f"to them ({refused})"
        )

    def _next_finished(self, finished):
        """The next finished future of ``finished`` (a ``distributed.as_completed``), checking
        every :data:`_POLL_S` that the cluster still has workers."""
        while not finished.has_ready():
            self._check_workers_present()
            time.sleep(0.1)
        return next(finished)

    _no_workers_since: float | None = None
    _last_check: float = 0.0

    def _check_workers_present(self) -> None:
        """Raise :class:`ClusterLostError` once the scheduler has had no worker for
        :data:`WORKERS_TIMEOUT_S` (it would wait for one forever) or cannot be reached; at
        most one look every :data:`_POLL_S`."""
        now = time.monotonic()
        if now - self._last_check < _POLL_S:
            return
        self._last_check = now
        if self.client.status not in ("running", "connecting"):
            raise self._lost_scheduler(f"the client is {self.client.status}")
        try:
            workers = len(self.client.nthreads())
        except (OSError, TimeoutError) as exc:
            raise self._lost_scheduler(exc) from None
        if workers:
            self._no_workers_since = None
            return
        if self._no_workers_since is None:
            self._no_workers_since = now
        elif now - self._no_workers_since > WORKERS_TIMEOUT_S:
            raise ClusterLostError(
                f"the Dask scheduler at {self.address} has had no workers for "
                f"{WORKERS_TIMEOUT_S} s (they died or were stopped)"
            )

    def _wait_for_a_worker(self) -> None:
        while True:
            self._last_check = 0.0
            self._check_workers_present()
            if self._no_workers_since is None:
                return
            time.sleep(_POLL_S)

    def _lost_scheduler(self, exc) -> ClusterLostError:
        return ClusterLostError(f"lost the Dask scheduler at {self.address} ({exc})")

    def compress(self, job, *args, label: str = "a compression job"):
        """Run a compression job (bake.compressjobs) on a worker and return its result; the
        arguments (a unit's stacks) are sent to the scheduler's choice of worker. Waits in
        short steps: when the bake is stopped (:func:`bake.basisu.stop_encoding`: another
        unit failed, or Ctrl-C) the job is cancelled and CompressionError raised; a final
        cluster failure raises :class:`ClusterLostError` naming ``label`` (what is compressed).
        A job whose worker died is run again by Dask (its arguments are scattered to the
        scheduler's choice of worker: when every copy is lost, they are sent again)."""
        from distributed.client import FutureCancelledError
        from distributed.scheduler import KilledWorker, NoValidWorkerError

        from bake import basisu

        for _ in range(SETUP_RESENDS + 1):
            basisu.check_not_stopped()
            self._wait_for_a_worker()
            try:
                data = self.client.scatter(list(args), hash=False)
            except (OSError, TimeoutError) as exc:
                raise self._lost_scheduler(exc) from None
            future = self.client.submit(
                job, *data, key=f"daylit-{job.__name__}-{uuid.uuid4().hex[:12]}", pure=False
            )
            try:
                while True:
                    try:
                        return future.result(timeout=_POLL_S)
                    except TimeoutError:
                        basisu.check_not_stopped()
                        self._check_workers_present()
            except KilledWorker as exc:
                raise ClusterLostError(
                    f"Dask gave up on the compression of {label}: the "
                    f"{exc.allowed_failures + 1} workers that ran it all died (KilledWorker; "
                    f"the last was {_address(exc.last_worker)})"
                ) from None
            except NoValidWorkerError:
                raise ClusterLostError(
                    f"the scheduler at {self.address} had no worker for the compression of "
                    f"{label} for longer than its no-workers-timeout"
                ) from None
            except FutureCancelledError:
                if self.client.status not in ("running", "connecting"):
                    raise self._lost_scheduler("the client was closed") from None
                continue  # the worker holding the stacks died: send them again
            finally:
                with contextlib.suppress(Exception):
                    self.client.cancel([future, *data])
        raise ClusterLostError(
            f"the workers of {self.address} holding the stacks of {label} all died "
            f"{SETUP_RESENDS + 1} times"
        )

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


def _address(worker) -> str:
    """A ``KilledWorker``'s last worker (a scheduler ``WorkerState``, or what was sent)."""
    return getattr(worker, "address", str(worker))


def chunk_label(path) -> str:
    """``.../atlas-ground.shared-00003.chunk`` -> "chunk 3 of ground.shared (stage atlas)"."""
    stem = path.name[: -len(chunkio.SUFFIX)] if path.name.endswith(chunkio.SUFFIX) else path.stem
    head, _, index = stem.rpartition("-")
    stage, _, name = head.partition("-")
    return f"chunk {int(index)} of {name} (stage {stage}, file {path.name})"
