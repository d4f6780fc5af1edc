"""The write stage's share of a bake, before and after a change, in the same run (issue 20):
bakes one scene with two checkouts of daylit at once (each bake a process of its own, with
that checkout first on its path), then prints each bake's stage seconds, the write stage's
share of the bake, the CPU seconds of each bake's whole process tree, and whether every file
of the two builds is equal byte for byte (SHA-256; ``manifest.json`` less what it records
about the run: times, rays, workers).

Usage::

    .venv/bin/python benchmarks/ab_write.py OUT --before /path/to/old/checkout \\
        [--after .] [--scene DIR | --small] [--lights 40] [--quality draft]

``--small`` bakes the scene of ``tests/bake/test_cluster.py`` (40 lights, two bounces)
generated into ``OUT/scene``. The old checkout needs its own ``node_modules`` (a symlink to
this one's is enough). Results go in docs/benchmarks.md by hand.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tests.buildfiles import build_files  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def _bake_here(code: Path, scene: Path, out: Path, lights: int, quality: str) -> None:
    """Run in a child: bake with the checkout ``code`` and print a JSON line of results."""
    sys.path.insert(0, str(code))
    from bake.pipeline import bake

    result = bake(scene, out, lights=lights, quality=quality, progress=False,
                  log=lambda msg: None)
    try:
        from bake import ktx2decoder

        launches = ktx2decoder.launches()
    except ImportError:
        launches = None  # the code before: one Node launch per decode call
    print(json.dumps({"duration_s": result.duration_s, "stage_s": result.stage_s,
                      "decoder_launches": launches}))


def _start(code: Path, scene: Path, out: Path, args) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(code))
    command = [sys.executable, __file__, "--child", str(code), str(scene), str(out),
               str(args.lights), args.quality]
    return subprocess.Popen(command, stdout=subprocess.PIPE, text=True, env=env, cwd=code)


def _wait(process: subprocess.Popen) -> tuple[dict, float]:
    """The child's JSON line and the CPU seconds of its whole process tree (its children
    were all reaped by it: wait4 counts them)."""
    out = process.stdout.read()
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise SystemExit(f"a bake failed ({process.returncode})")
    return json.loads(out.strip().splitlines()[-1]), usage.ru_utime + usage.ru_stime


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        code, scene, out, lights, quality = sys.argv[2:]
        _bake_here(Path(code), Path(scene), Path(out), int(lights), quality)
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--before", type=Path, required=True)
    parser.add_argument("--after", type=Path, default=REPO)
    parser.add_argument("--scene", type=Path)
    parser.add_argument("--small", action="store_true")
    parser.add_argument("--lights", type=int, default=40)
    parser.add_argument("--quality", default="draft")
    args = parser.parse_args()
    out = args.out.absolute()
    scene = args.scene
    if args.small:
        sys.path.insert(0, str(REPO))
        from tests.sites import make_site

        scene = make_site(out / "scene", lights=args.lights, hull_texel_m=0.25, bounces=2)
    scene = Path(scene).absolute()
    load = os.getloadavg()[0]
    started = time.strftime("%H:%M:%S")
    runs = {
        name: _start(code.absolute(), scene, out / name, args)
        for name, code in (("before", args.before), ("after", args.after))
    }
    results = {name: _wait(p) for name, p in runs.items()}
    print(f"{started}-{time.strftime('%H:%M:%S')} UTC, load average {load:.1f} at the start, "
          f"{os.getloadavg()[0]:.1f} at the end; {scene}, {args.lights} lights, {args.quality}")
    for name, (result, cpu_s) in results.items():
        stages = {k: round(v, 1) for k, v in result["stage_s"].items()}
        share = result["stage_s"]["write"] / result["duration_s"]
        print(f"{name:>7}: bake {result['duration_s']:.1f} s, write share {share:.1%}, "
              f"process tree CPU {cpu_s:.1f} s, decoder launches "
              f"{result['decoder_launches']}, stages {stages}")
    before, after = build_files(out / "before"), build_files(out / "after")
    same = [k for k in before if before[k] == after.get(k)]
    print(f"files equal: {len(same)} of {len(before)} (after has {len(after)})")
    for k in sorted(set(before) | set(after)):
        if before.get(k) != after.get(k):
            print("  differs:", k)
    return 0 if len(same) == len(before) == len(after) else 1


if __name__ == "__main__":
    sys.exit(main())
