"""The start rule (web/src/startmode.js, docs/web.md "Slow links") on hand-made manifests:
the bytes each start needs, summed here independently from the file list, and the choice at
rates whose answer is worked out by hand (coarse when the full first download would take
more than 3 s). Node is required (tests/web/harness.py node_path)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from tests.web.harness import node_path

STARTMODE_JS = (Path(__file__).resolve().parents[2] / "web" / "src" / "startmode.js").as_uri()

FILES = {"site.glb": 400_000, "g.ktx2": 1_000_000, "g.V.bin": 50_000, "gain.ktx2": 80_000,
         "g.e.ktx2": 300_000, "l.ktx2": 1_200_000, "l.V.bin": 70_000,
         "coarse/g.ktx2": 90_000, "coarse/g.V.bin": 5_000,
         "coarse/l.ktx2": 95_000, "coarse/l.V.bin": 6_000}
GROUND = {"ktx2": "g.ktx2", "v": {"path": "g.V.bin"}, "gain": {"ktx2": "gain.ktx2"},
          "etc1s": {"ktx2": "g.e.ktx2"},
          "coarse": {"ktx2": "coarse/g.ktx2", "v": {"path": "coarse/g.V.bin"}}}
LIGHTMAP = {"ktx2": "l.ktx2", "v": {"path": "l.V.bin"}, "gain": {"ktx2": "gain.ktx2"},
            "coarse": {"ktx2": "coarse/l.ktx2", "v": {"path": "coarse/l.V.bin"}}}


def run(script: str) -> dict:
    result = subprocess.run([node_path(), "--input-type=module", "-e",
                             script.replace("STARTMODE_JS", STARTMODE_JS)],
                            capture_output=True, text=True, timeout=60, check=True)
    return json.loads(result.stdout)


def test_bytes_and_choices():
    manifest = {"model": {"path": "site.glb"},
                "files": [{"path": p, "bytes": b} for p, b in FILES.items()]}
    # By hand: the model, the shared gain once, each stack's base, V and ETC1S array.
    full = 400_000 + 80_000 + 1_000_000 + 50_000 + 300_000 + 1_200_000 + 70_000  # 3.1 MB
    coarse = 400_000 + 80_000 + 90_000 + 5_000 + 95_000 + 6_000
    no_coarse = {k: v for k, v in LIGHTMAP.items() if k != "coarse"}
    out = run(f"""
      import {{ chooseStart, firstBytes }} from 'STARTMODE_JS';
      const m = {json.dumps(manifest)};
      const bytes = firstBytes(m, [{json.dumps(GROUND)}, {json.dumps(LIGHTMAP)}]);
      const missing = firstBytes(m, [{json.dumps(GROUND)}, {json.dumps(no_coarse)}]);
      console.warn = () => {{}};
      const at = (asked, bytesPerS, b = bytes) =>
        chooseStart(asked, b, bytesPerS === null ? null : {{ bytesPerS }});
      console.log(JSON.stringify({{ bytes, missing, cases: {{
        slow: at(null, 200e3), fast: at('auto', 50e6), edgeBelow: at('auto', 1.04e6),
        edgeAbove: at('auto', 1.03e6), cached: at('auto', null), forcedFull: at('full', 200e3),
        forcedCoarse: at('coarse', 50e6), typo: at('coarze', 200e3),
        noCoarse: at('coarse', 200e3, missing) }} }}));
    """)
    assert out["bytes"] == {"full": full, "coarse": coarse}
    assert out["missing"] == {"full": full, "coarse": None}
    modes = {k: (v["asked"], v["mode"]) for k, v in out["cases"].items()}
    assert modes == {
        "slow": ("auto", "coarse"),  # 3.1 MB at 200 kB/s: 15.5 s
        "fast": ("auto", "full"),  # 0.06 s
        "edgeBelow": ("auto", "full"),  # 3.1 MB / 1.04 MB/s = 2.98 s
        "edgeAbove": ("auto", "coarse"),  # 3.01 s
        "cached": ("auto", "full"),  # no rate
        "forcedFull": ("full", "full"), "forcedCoarse": ("coarse", "coarse"),
        "typo": ("auto", "coarse"),  # an unknown word is taken as auto
        "noCoarse": ("coarse", "full"),  # nothing to start from
    }
    assert abs(out["cases"]["slow"]["fullFirstS"] - full / 200e3) < 1e-9
    assert out["cases"]["slow"]["bytesPerS"] == 200_000
    assert out["cases"]["cached"]["bytesPerS"] is None
