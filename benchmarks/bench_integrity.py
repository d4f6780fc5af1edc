"""The server's integrity check at start (server/integrity.py) on a build: the files offered to
clients (server/access.py: without the EXR masters) and their bytes, the time to read them
(the baseline: what any check must at least cost) and to check them against the manifest's
SHA-256, twice (the second run with the files in the page cache).

Usage: python benchmarks/bench_integrity.py BUILD
"""

from __future__ import annotations

import asyncio
import json
import sys
import time
from pathlib import Path

from server.access import AccessPolicy
from server.integrity import BuildIntegrity


def main(build: Path) -> None:
    manifest = json.loads((build / "manifest.json").read_text("utf-8"))
    offered = AccessPolicy().client_files(manifest)
    expected = {f["path"]: f["sha256"] for f in manifest["files"] if f["path"] in offered}
    offered_mb = sum(f["bytes"] for f in manifest["files"] if f["path"] in offered) / 1e6
    all_mb = sum(f["bytes"] for f in manifest["files"]) / 1e6
    print(f"offered: {len(expected)} of {len(manifest['files'])} files, {offered_mb:.1f} MB of "
          f"{all_mb:.1f} MB")
    for run in (1, 2):
        t0 = time.perf_counter()
        for path in expected:
            (build / path).read_bytes()
        read_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        bad = asyncio.run(BuildIntegrity(build, expected).check_all())
        check_s = time.perf_counter() - t0
        print(f"run {run}: read {read_s:.3f} s, check {check_s:.3f} s, mismatches {bad}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
