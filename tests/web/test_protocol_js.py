"""The JavaScript decoders (web/src/protocol.js) read the same test vectors as Python: the
light-stream messages, and the occlusion masks (docs/occlusion.md)."""

import json
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VECTORS = ROOT / "tests" / "protocol_vectors"


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
@pytest.mark.parametrize("script,vectors,expected_suffix,at_least", [
    ("decode_vectors.mjs", "*.bin", ".json", 9),
    ("decode_masks.mjs", "occlusion_rle_*.bin", ".mask.json", 10),
], ids=["messages", "occlusion-masks"])
def test_javascript_decoder_matches_the_vectors(script, vectors, expected_suffix, at_least):
    result = subprocess.run(
        ["node", str(ROOT / "tests" / "web" / script), str(VECTORS)],
        capture_output=True, text=True, timeout=60, check=True,
    )
    decoded = json.loads(result.stdout)
    names = sorted(p.stem for p in VECTORS.glob(vectors))
    assert sorted(decoded) == names and len(names) >= at_least
    for name in names:
        expected = json.loads((VECTORS / f"{name}{expected_suffix}").read_text())
        got = decoded[name]
        if "error" in expected:
            assert "error" in got, name
            assert expected["error"] in got["error"], (name, got["error"])
        else:
            assert got == expected, name
