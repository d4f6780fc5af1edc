"""The JavaScript decoder (web/src/protocol.js) reads the same test vectors as Python."""

import json
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VECTORS = ROOT / "tests" / "protocol_vectors"


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_javascript_decoder_matches_the_vectors():
    result = subprocess.run(
        ["node", str(ROOT / "tests" / "web" / "decode_vectors.mjs"), str(VECTORS)],
        capture_output=True, text=True, timeout=60, check=True,
    )
    decoded = json.loads(result.stdout)
    names = sorted(p.stem for p in VECTORS.glob("*.bin"))
    assert sorted(decoded) == names and len(names) >= 9
    for name in names:
        expected = json.loads((VECTORS / f"{name}.json").read_text())
        got = decoded[name]
        if "error" in expected:
            assert "error" in got, name
            assert expected["error"] in got["error"], (name, got["error"])
        else:
            assert got == expected, name
