"""web/src/lightmath.js's light selection (run by Node) against the hand-worked cases of
tests/vectors/light_selection.json, the same cases daylit.selection is checked on
(tests/daylit/test_selection.py). No skip without Node: the README's commands install it."""

import json
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
VECTORS = ROOT / "tests" / "vectors" / "light_selection.json"


def test_lightmath_selection_gives_the_hand_worked_answers():
    result = subprocess.run(
        ["node", str(ROOT / "tests" / "web" / "selection_vectors.mjs"), str(VECTORS)],
        capture_output=True, text=True, timeout=60, check=True,
    )
    got = json.loads(result.stdout)
    cases = json.loads(VECTORS.read_text())["cases"]
    assert set(got) == {c["name"] for c in cases}
    for case in cases:
        assert got[case["name"]] == case["expected"], case["name"]
