"""The JavaScript occlusion-mask decoder (web/src/protocol.js) reads the shared vectors."""

import json
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VECTORS = ROOT / "tests" / "protocol_vectors"


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_javascript_mask_decoder_matches_the_vectors():
    result = subprocess.run(
        ["node", str(ROOT / "tests" / "web" / "decode_masks.mjs"), str(VECTORS)],
        capture_output=True, text=True, timeout=60, check=True,
    )
    decoded = json.loads(result.stdout)
    names = sorted(p.stem for p in VECTORS.glob("occlusion_rle_*.bin"))
    assert sorted(decoded) == names and len(names) >= 10
    for name in names:
        expected = json.loads((VECTORS / f"{name}.mask.json").read_text())
        got = decoded[name]
        if "error" in expected:
            assert "error" in got, name
            assert expected["error"] in got["error"], (name, got["error"])
        else:
            assert got == expected, name
