"""daylit.selection against the hand-worked cases of tests/vectors/light_selection.json (the
same cases web/src/lightmath.js is checked on, tests/web/test_selection_js.py)."""

import json
from pathlib import Path

import numpy as np
import pytest

from daylit.selection import Selection, select_lights

VECTORS = json.loads(
    (Path(__file__).resolve().parents[1] / "vectors" / "light_selection.json").read_text()
)


@pytest.mark.parametrize("case", VECTORS["cases"], ids=lambda c: c["name"])
def test_selection_gives_the_hand_worked_answer(case):
    r = np.array(case["r"], dtype=np.float64)
    selection = Selection.of(np.array(case["solid_angles_sr"]), case["m"], case.get("selectable"))
    assert selection(r).tolist() == case["expected"]
    assert select_lights(r, selection.weights_sr, case["m"]).tolist() == case["expected"]


def test_the_vectors_cover_each_part_of_the_rule():
    names = {c["name"] for c in VECTORS["cases"]}
    assert len(names) == len(VECTORS["cases"]) >= 10
    assert any("selectable" in c for c in VECTORS["cases"])
    assert any(c["m"] == 0 for c in VECTORS["cases"])
