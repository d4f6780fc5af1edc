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
    ("decode_vectors.mjs", "*.bin", ".json", 12),
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


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_javascript_client_asks_for_version_2_and_accepts_either_hello():
    script = """
    import { lightStreamUrl, parseHello, PROTOCOL_VERSION, Flags } from 'PROTOCOL_JS';
    const loc = { protocol: 'https:', host: 'site.example:8443' };
    const out = { version: PROTOCOL_VERSION, sunFlag: Flags.SUN_ESTIMATED,
      url: lightStreamUrl(loc, ['light', 'site-camera']), bare: lightStreamUrl(loc, []) };
    for (const p of [1, 2, 3]) {
      try { out['hello' + p] = parseHello(JSON.stringify({ type: 'hello', protocol: p,
        lights: 4 })).protocol; } catch (err) { out['hello' + p] = err.message; }
    }
    process.stdout.write(JSON.stringify(out));
    """.replace("PROTOCOL_JS", (ROOT / "web" / "src" / "protocol.js").as_uri())
    result = subprocess.run(["node", "--input-type=module", "-e", script], capture_output=True,
                            text=True, timeout=60, check=True)
    out = json.loads(result.stdout)
    assert out["version"] == 2 and out["sunFlag"] == 32
    assert out["url"] == "wss://site.example:8443/ws/light?protocol=2&streams=light,site-camera"
    assert out["bare"] == "wss://site.example:8443/ws/light?protocol=2"
    assert out["hello1"] == 1 and out["hello2"] == 2 and "protocol 3" in out["hello3"]
