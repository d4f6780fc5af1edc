"""Test helper: a copy of a build with a coarse start added (bake/coarse.py), its files hard
links to the original's where the file system allows (the original is never written)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def coarse_copy(build_dir: Path, out: Path, budget_bytes: int | None = None) -> Path:
    """``out``: ``build_dir`` with ``coarse/`` and a rewritten manifest (a real copy of it)."""
    from bake.coarse import DEFAULT_BUDGET_BYTES, add_coarse

    shutil.copytree(build_dir, out, copy_function=_link_or_copy,
                    ignore=shutil.ignore_patterns("manifest.json", "coarse"))
    shutil.copy2(Path(build_dir) / "manifest.json", out / "manifest.json")
    add_coarse(out, budget_bytes or DEFAULT_BUDGET_BYTES)
    return out
