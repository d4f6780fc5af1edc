"""RDO images encoded one per process: how often an image's bytes change from run to run,
and what the encoder processes cost (issue 20: bit-identical builds; docs/benchmarks.md,
"RDO images encoded one per process").

    PYTHONPATH=. python benchmarks/rdo_processes.py BUILD [--stack NAME ...] [--rounds N]
        [--every K] [--rdo LAMBDA]

For each sun-bounce stack of the build (its EXR master; default every one), every K-th
light's column is quantized as the bake quantizes it and encoded at UASTC level 0 with RDO,
``--rounds`` times over, three ways:

- ``shared``: the images shared out between one ``basisu`` process per core, as the bake
  encoded them before (the baseline, the command made here);
- ``shared, ASLR off``: the same under ``setarch -R`` (when it is there): the encoder's
  addresses the same in every run;
- ``shipped``: :func:`bake.basisu.encode` as the bake calls it (one process per image).

Printed per way: the files whose bytes differed between rounds, and the encoders' CPU and
the wall time per round.
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bake.basisu import encode, separate_images_args  # noqa: E402
from bake.compresssettings import Settings  # noqa: E402
from bake.quantize import quantized_png  # noqa: E402
from daylit.stackio import read_stack_exr  # noqa: E402


def _shared_out(pngs: list[Path], out: Path, settings: Settings, rdo: float,
                prefix: list[str]) -> None:
    """The baseline: ``pngs`` shared out between one single-threaded encoder per core."""
    args = separate_images_args(out, settings, level=0, rdo_lambda=rdo)
    processes = max(1, min(os.cpu_count() or 1, len(pngs)))
    running = [subprocess.Popen(prefix + args + [str(p) for p in pngs[i::processes]],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
               for i in range(processes)]
    for process in running:
        if process.wait() != 0:
            raise SystemExit(f"basisu failed ({process.returncode})")


def _rounds(encode_once, rounds: int, work: Path) -> tuple[int, float, float]:
    """(files with more than one output over ``rounds``, encoder CPU s, wall s per round)."""
    seen: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    for r in range(rounds):
        out = work / f"round{r}"
        out.mkdir()
        encode_once(out)
        for f in out.glob("*.ktx2"):
            seen[f.name][hashlib.sha256(f.read_bytes()).hexdigest()] += 1
        shutil.rmtree(out)
    wall = (time.perf_counter() - t0) / rounds
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime + c1.ru_stime - c0.ru_utime - c0.ru_stime) / rounds
    return sum(len(v) > 1 for v in seen.values()), cpu, wall


def _ways(pngs: list[Path], settings: Settings, rdo: float, setarch: str | None) -> list:
    """[(label, encode all ``pngs`` into a folder)] for the three ways of the module's doc."""
    ways = [("shared", lambda out: _shared_out(pngs, out, settings, rdo, []))]
    if setarch:
        ways.append(("shared, ASLR off",
                     lambda out: _shared_out(pngs, out, settings, rdo, [setarch, "-R"])))
    ways.append(("shipped", lambda out: encode(pngs, out, settings, array=False, level=0,
                                               rdo_lambda=rdo)))
    return ways


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("build", type=Path, help="a baked build with sun-bounce EXR masters")
    parser.add_argument("--stack", action="append", metavar="NAME",
                        help="a sun-bounce master's name, e.g. hull.sun_bounce.I (default: all)")
    parser.add_argument("--rounds", type=int, default=20, help="encodes of each image per way")
    parser.add_argument("--every", type=int, default=1, metavar="K", help="every K-th light")
    parser.add_argument("--rdo", type=float, default=1.0, help="RDO lambda (default 1)")
    a = parser.parse_args()
    exr = a.build / "exr"
    if not exr.is_dir():
        parser.error(f"{a.build} has no exr/ folder: give a build made by `daylit bake`")
    names = a.stack or sorted(p.stem for p in exr.glob("*.sun_bounce.*.exr"))
    settings = Settings()
    setarch = shutil.which("setarch")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in names:
            stack = read_stack_exr(exr / f"{name}.exr")
            lights = [i for i in range(stack.shape[2]) if stack[:, :, i].max() > 0][:: a.every]
            pngs = [quantized_png(stack[:, :, i], tmp / f"{name}.L{i:04d}.png").path
                    for i in lights]
            h, w = stack.shape[:2]
            del stack
            print(f"{name}: {len(pngs)} images of {w}x{h}, RDO {a.rdo:g}, {a.rounds} rounds",
                  flush=True)
            for label, once in _ways(pngs, settings, a.rdo, setarch):
                varied, cpu, wall = _rounds(once, a.rounds, tmp)
                print(f"  {label:17s} files whose bytes varied {varied:4d} of {len(pngs)}; "
                      f"encoder CPU {cpu:6.2f} s, wall {wall:6.2f} s per round", flush=True)
            for p in pngs:
                p.unlink()


if __name__ == "__main__":
    main()
