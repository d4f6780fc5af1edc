"""Where the bake's write stage spends its time (issue 20): bakes a site with each sub-step of
the write stage (smoothing, low-rank choices, encoders, decoders, checks, EXR masters, PNGs,
manifest) wrapped, and prints each one's own time summed over the writing threads (its timed
callees excluded): wall thread-seconds (which include waiting for a core and for the GIL on a
loaded machine), the thread's CPU seconds, and the CPU of the encoder and decoder processes.

Usage::

    .venv/bin/python benchmarks/prof_write.py OUT [--lights 160] [--quality draft]

Results go in docs/benchmarks.md ("The write stage, profiled") by hand.
"""

from __future__ import annotations

import argparse
import collections
import functools
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import bake.basisu as basisu  # noqa: E402
import bake.compact_reader as compact_reader  # noqa: E402
import bake.compress as compress  # noqa: E402
import bake.contact as contact  # noqa: E402
import bake.ktx2decoder as ktx2decoder  # noqa: E402
import bake.lowrank as lowrank  # noqa: E402
import bake.pipeline as pipeline  # noqa: E402
import bake.quantize as quantize  # noqa: E402
import bake.refinement as refinement  # noqa: E402
import bake.stackerrors as stackerrors  # noqa: E402
import bake.stackkinds as stackkinds  # noqa: E402
import bake.sunbounce as sunbounce  # noqa: E402
import bake.tracework as tracework  # noqa: E402
import bake.writers as writers  # noqa: E402
import daylit.stackio as stackio  # noqa: E402

WALL: dict = collections.defaultdict(float)
CPU: dict = collections.defaultdict(float)
CALLS: collections.Counter = collections.Counter()
CHILD_CPU: dict = collections.defaultdict(float)  # encoder / decoder processes, by program
_LOCAL = threading.local()


def _timed(function, label):
    @functools.wraps(function)
    def timed(*args, **kwargs):
        stack = _LOCAL.__dict__.setdefault("stack", [])
        wall0, cpu0 = time.perf_counter(), time.thread_time()
        stack.append([0.0, 0.0])
        try:
            return function(*args, **kwargs)
        finally:
            wall, cpu = time.perf_counter() - wall0, time.thread_time() - cpu0
            inner_wall, inner_cpu = stack.pop()
            WALL[label] += wall - inner_wall
            CPU[label] += cpu - inner_cpu
            CALLS[label] += 1
            if stack:
                stack[-1][0] += wall
                stack[-1][1] += cpu

    return timed


def _wrap(owner, name, *also):
    """Wrap ``owner.name`` and put the wrapper where ``also`` (modules) imported it."""
    label = f"{getattr(owner, '__name__', owner)}.{name}".replace("bake.", "")
    wrapped = _timed(getattr(owner, name), label)
    for target in (owner, *also):
        setattr(target, name, wrapped)


def _try_wait(self, wait_flags):
    """subprocess.Popen._try_wait with the child's CPU time recorded (os.wait4)."""
    try:
        pid, status, usage = os.wait4(self.pid, wait_flags)
    except ChildProcessError:
        return (self.pid, 0)
    if pid == self.pid:
        CHILD_CPU[Path(str(self.args[0])).name] += usage.ru_utime + usage.ru_stime
    return (pid, status)


def instrument() -> None:
    subprocess.Popen._try_wait = _try_wait
    _wrap(basisu, "_run_encoders")
    _wrap(ktx2decoder, "decode", compress, sunbounce, compact_reader)
    for name in ("quantized_png", "refinement_png"):
        _wrap(quantize, name, compress, sunbounce)
    for name in ("factors", "rms_rank", "ratio_rank"):
        _wrap(lowrank, name, compress)
    _wrap(refinement, "layers_to_refine", compress)
    for name in ("of", "absolute_truths"):
        _wrap(lowrank.Spectrum, name)
    _wrap(refinement.RatioRefinement, "pair")
    for name in ("composite", "lights"):
        _wrap(compact_reader.CompactReader, name)
    _wrap(stackio, "write_stack_exr_by_rows", writers)
    for name in ("_atlas_image", "smooth_bounce", "_dilate", "view_smoothed", "_write_depth"):
        _wrap(writers, name)
    # The continuation into buried texels, within _atlas_image and smooth_bounce (issue 20:
    # 72 s of a loaded demo bake's write stage by cProfile, docs/benchmarks.md).
    _wrap(contact, "continue_into_buried", writers)
    _wrap(writers.SunBounce, "image")
    _wrap(tracework.TracedResults, "load")
    _wrap(compress, "compress_stack", stackkinds)
    for name in ("record_errors", "within_budget"):
        _wrap(stackerrors, name, compress, stackkinds)
    _wrap(refinement, "layers_to_refine_within", compress)
    for name in ("compress_rms_stack", "compress_ratio_pair"):
        _wrap(stackkinds, name)
    _wrap(sunbounce, "compress_sun_bounce")
    _wrap(writers, "write_atlas", pipeline)
    _wrap(writers, "write_view", pipeline)
    _wrap(pipeline, "write_site_glb")
    _wrap(pipeline, "write_manifest")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--scene", type=Path, default=REPO / "scenes" / "demo")
    parser.add_argument("--lights", type=int, default=160)
    parser.add_argument("--quality", default="draft")
    args = parser.parse_args()
    instrument()
    started = time.process_time()
    result = pipeline.bake(args.scene, args.out, lights=args.lights, quality=args.quality,
                           progress=False)
    stages = {k: round(v, 1) for k, v in result.stage_s.items()}
    print(f"bake {result.duration_s:.1f} s, stages {stages}, this process's CPU "
          f"{time.process_time() - started:.1f} s")
    total = sum(WALL.values())
    print(f"{'wall thread-s':>14}{'share':>7}{'CPU s':>9}{'calls':>7}  step")
    for label, wall in sorted(WALL.items(), key=lambda kv: -kv[1]):
        print(f"{wall:14.2f}{wall / total:7.1%}{CPU[label]:9.2f}{CALLS[label]:7d}  {label}")
    for program, seconds in sorted(CHILD_CPU.items()):
        print(f"processes {program}: {seconds:.1f} s CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
