"""What a build is, file by file, for comparing two builds byte for byte.

Used by the cluster tests (tests/bake/test_cluster.py) and the write stage's A/B benchmark
(benchmarks/ab_write.py).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

# What a manifest records about the run rather than the build: times, rays cast by this run.
RUN_KEYS = {"created_utc", "duration_s", "encode_s", "stage_s", "rays_per_s", "rays", "workers"}


def without_run(value):
    """A manifest's JSON value less what it records about the run (:data:`RUN_KEYS`)."""
    if isinstance(value, dict):
        return {k: without_run(v) for k, v in value.items() if k not in RUN_KEYS}
    if isinstance(value, list):
        return [without_run(v) for v in value]
    return value


def build_files(build: Path) -> dict:
    """``{relative path: SHA-256 hex}`` of every file of a build; ``manifest.json`` as its
    contents less what it records about the run."""
    out = {
        p.relative_to(build).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(build.rglob("*"))
        if p.is_file() and p.name != "manifest.json"
    }
    out["manifest.json"] = without_run(json.loads((build / "manifest.json").read_text()))
    return out
