"""docs/occlusion.md keeps up with the code: every setting and every test vector is described."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from server.occlusion.settings import SCHEMA, OcclusionSettings

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


@pytest.mark.parametrize(("changes", "message"), [
    ({"bg_rate": 2}, "occlusion settings: bg_rate must be a number < 1, got 2"),
    ({"lut_bits": 7}, "occlusion settings: lut_bits must be a number <= 6, got 7"),
    ({"learn_frames": 0}, "occlusion settings: learn_frames must be a number >= 1, got 0"),
    ({"temporal_prior": (0.1, 0.2, 0.3, 1.5)}, "temporal_prior must be a list of 4 numbers, "
                                                "each > 0 and < 1"),
    ({"full_frame": 1}, "full_frame must be true or false, got 1"),
    ({"bg_rate": 0.3}, "bg_rate * bg_update_bands must be < 1"),
    ({"shadow_ratio": (0.9, 0.2)}, "shadow_ratio must be (lo, hi) with lo < hi"),
    ({"t_f": float("nan")}, "t_f must be a number > 0 (finite), got nan"),
])
def test_bad_settings_name_the_key_and_what_is_allowed(changes, message):
    with pytest.raises(ValueError) as info:
        OcclusionSettings(**changes)
    assert message in str(info.value)
    OcclusionSettings(**{k: SCHEMA["properties"][k]["default"] for k in changes})  # defaults ok
