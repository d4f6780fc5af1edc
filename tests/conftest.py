"""Shared fixtures: small bakes reused across test modules (baked once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def demo_draft_build(tmp_path_factory) -> Path:
    """The demo site baked at draft quality with Kakuta's 40-light dome."""
    from bake.pipeline import bake

    out = tmp_path_factory.mktemp("demo") / "build"
    bake(
        REPO / "scenes" / "demo",
        out,
        lights=40,
        quality="draft",
        progress=False,
        log=lambda msg: None,
    )
    return out
