"""The bake's memory over time, and which write step holds its peak (issue 20: a large site's
write stage within a memory bound).

Bakes a scene in this process (resuming from its traced chunks when they are there) while a
thread samples the resident memory of the whole process tree (the bake, its tracing workers,
encoders and decoders) every ``--every`` seconds; the write stage's steps (each atlas's or
view's stacks assembled, masters written, sun-bounce and compact stacks) are wrapped to log
when they start and end. Past ``--limit-gb`` the tree is killed (a sign the bound is not
met). Prints the stage seconds and each stage's share of the bake, the peak and the step
that was running at it, and writes the samples to ``--log`` (seconds, GB, running steps).

Usage::

    .venv/bin/python benchmarks/bench_write_memory.py SCENE OUT --lights 40 --quality draft \\
        [--workers N] [--limit-gb 9] [--every 1] [--log rss.tsv]

Run it niced on a shared machine; wrap it in ``/usr/bin/time -v`` for the largest single
process's peak as the kernel counts it. Results go in docs/benchmarks.md by hand.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import sys
import threading
import time
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

RUNNING: dict[int, str] = {}  # thread id -> the write step it is in
EVENTS: list[tuple[float, str]] = []
STARTED = time.perf_counter()


def _wrap(module, name: str, label) -> None:
    original = getattr(module, name)

    @functools.wraps(original)
    def wrapped(*args, **kwargs):
        step = label(*args, **kwargs)
        if UNTIL_WRITE.is_set():
            raise StopAtWriteError(step)
        me = threading.get_ident()
        before = RUNNING.get(me)
        RUNNING[me] = step
        EVENTS.append((time.perf_counter() - STARTED, f"start {step}"))
        try:
            return original(*args, **kwargs)
        finally:
            EVENTS.append((time.perf_counter() - STARTED, f"end {step}"))
            if before is None:
                RUNNING.pop(me, None)
            else:
                RUNNING[me] = before

    setattr(module, name, wrapped)


def _instrument() -> None:
    from bake import pipeline, stackkinds, sunbounce, writers

    _wrap(writers, "_assemble", lambda a, stack, *r: f"assemble {a.id}.{stack}")
    _wrap(writers, "_write_master", lambda path, store: f"master {Path(path).name}")
    _wrap(stackkinds, "compress_ratio_pair", lambda I, d, names, *r, **k: f"pair {names[1]}")
    _wrap(stackkinds, "compress_rms_stack", lambda image, name, *r, **k: f"rms {name}")
    _wrap(sunbounce, "compress_sun_bounce", lambda image, name, *r, **k: f"sun {name}")
    _wrap(pipeline, "write_view", lambda view, *r, **k: f"view {view.name}")


class StopAtWriteError(Exception):
    """``--until-write``: the write stage's first step started."""


UNTIL_WRITE = threading.Event()
PSS = threading.Event()


def _tree_rss(process: psutil.Process) -> int:
    """The tree's resident bytes: RSS summed, or with ``--pss`` each process's proportional
    share (pages mapped by several processes, e.g. the tracing workers' memory-mapped bounce
    cache, counted once in all, not once per process)."""
    total = 0
    for p in [process, *process.children(recursive=True)]:
        with contextlib.suppress(psutil.Error):
            total += p.memory_full_info().pss if PSS.is_set() else p.memory_info().rss
    return total


def _sample(limit: float, every: float, samples: list, stop: threading.Event,
            log: Path | None) -> None:
    me = psutil.Process()
    while not stop.is_set():
        rss = _tree_rss(me)
        samples.append((time.perf_counter() - STARTED, rss, sorted(set(RUNNING.values()))))
        if rss > limit:
            print(f"stopped: the process tree passed {limit / 1e9:.1f} GB "
                  f"({rss / 1e9:.2f} GB) in {sorted(set(RUNNING.values()))}", file=sys.stderr,
                  flush=True)
            _write_log(log, samples)
            for child in me.children(recursive=True):
                child.kill()
            os._exit(3)
        stop.wait(every)


def _write_log(log: Path | None, samples: list) -> None:
    if log is None:
        return
    with open(log, "w") as f:
        for t, rss, steps in samples:
            f.write(f"{t:.1f}\t{rss / 1e9:.3f}\t{'; '.join(steps)}\n")
        for t, event in EVENTS:
            f.write(f"{t:.1f}\t-\t{event}\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--lights", type=int, default=40)
    parser.add_argument("--quality", default="draft")
    parser.add_argument("--workers", type=int, help="tracing processes (default: one per core)")
    parser.add_argument("--limit-gb", type=float, default=9.0)
    parser.add_argument("--every", type=float, default=1.0)
    parser.add_argument("--log", type=Path)
    parser.add_argument("--until-write", action="store_true",
                        help="stop when the write stage starts (receivers, cache, tracing)")
    parser.add_argument("--pss", action="store_true",
                        help="count each process's proportional set size, not its RSS")
    args = parser.parse_args()
    if args.until_write:
        UNTIL_WRITE.set()
    if args.pss:
        PSS.set()
    from bake.pipeline import bake

    _instrument()
    samples: list = []
    stop = threading.Event()
    sampler = threading.Thread(
        target=_sample, args=(args.limit_gb * 1e9, args.every, samples, stop, args.log),
        daemon=True
    )
    sampler.start()
    load = os.getloadavg()[0]
    wall = time.strftime("%H:%M:%S", time.gmtime())
    try:
        result = bake(args.scene, args.out, lights=args.lights, quality=args.quality,
                      workers=args.workers, progress=False,
                      log=lambda msg: print(msg, file=sys.stderr, flush=True))
    except StopAtWriteError as reached:
        result = None
        print(f"stopped as the write stage started ({reached})", file=sys.stderr)
    finally:
        stop.set()
        sampler.join()
        _write_log(args.log, samples)
    end = time.strftime("%H:%M:%S", time.gmtime())
    if result is None:
        t, peak, _ = max(samples, key=lambda s: s[1])
        print(f"{wall}-{end} UTC, load average {load:.1f} at the start, "
              f"{os.getloadavg()[0]:.1f} at the end; {args.scene}, {args.lights} lights, "
              f"{args.quality}; {'PSS' if args.pss else 'RSS'} of the process tree")
        print(f"peak before the write stage: {peak / 1e9:.2f} GB at {t:.0f} s "
              f"(receivers, cache and tracing, {samples[-1][0]:.0f} s)")
        return
    print(f"{wall}-{end} UTC, load average {load:.1f} at the start, "
          f"{os.getloadavg()[0]:.1f} at the end; {args.scene}, {args.lights} lights, "
          f"{args.quality}")
    total = result.duration_s
    for stage, seconds in result.stage_s.items():
        print(f"  {stage:<10} {seconds:8.1f} s  {seconds / total:6.1%}")
    print(f"  bake       {total:8.1f} s")
    t, peak, steps = max(samples, key=lambda s: s[1])
    print(f"peak of the process tree: {peak / 1e9:.2f} GB at {t:.0f} s, in "
          f"{'; '.join(steps) or 'no write step (receivers, cache or tracing)'}")
    for step in sorted({s for _, _, steps in samples for s in steps}):
        held = max(rss for _, rss, steps in samples if step in steps)
        print(f"  highest during {step:<34} {held / 1e9:6.2f} GB")


if __name__ == "__main__":
    main()
