"""docs/occlusion.md keeps up with the code: every setting and every test vector is described."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from server.occlusion.settings import OcclusionSettings

ROOT = Path(__file__).resolve().parents[3]
DOC = (ROOT / "docs" / "occlusion.md").read_text("utf-8")


def test_every_setting_is_in_the_settings_table():
    rows = {line.split("|")[1].strip().strip("`") for line in DOC.splitlines()
            if line.startswith("| `")}
    fields = {f.name for f in dataclasses.fields(OcclusionSettings)}
    assert fields <= rows, sorted(fields - rows)


def test_every_test_vector_is_named_in_the_wire_format_section():
    names = sorted(p.name[len("occlusion_rle_"): -len(".mask.json")]
                   for p in (ROOT / "tests" / "protocol_vectors").glob("occlusion_rle_*.mask.json"))
    assert names
    for name in names:
        assert f"`{name}`" in DOC or f"`{name.removeprefix('error_')}`" in DOC, name
