"""The settings tables in docs/ are the ones generated from the settings' JSON Schemas
(tools/settings_tables.py), and daylit.settingschema words problems as the docs say."""

from __future__ import annotations

import pytest

from daylit.settingschema import first_problem, table_in
from tools.settings_tables import tables


@pytest.mark.parametrize("doc, name, table", tables(), ids=lambda x: getattr(x, "name", x))
def test_docs_table_is_the_generated_one(doc, name, table):
    assert table_in(doc.read_text("utf-8"), name) == table, (
        f"{doc.name}: the {name} settings table is stale; run python tools/settings_tables.py")


SCHEMA = {"type": "object", "additionalProperties": False, "properties": {
    "rate_hz": {"type": "number", "exclusiveMinimum": 0, "maximum": 120},
    "port": {"type": "integer", "minimum": 1, "maximum": 65535},
    "mode": {"enum": ["process", "thread"]},
    "rgb": {"type": "array", "items": {"type": "number", "exclusiveMinimum": 0},
            "minItems": 3, "maxItems": 3, "x-allowed": "three positive numbers [r, g, b]"},
}}


@pytest.mark.parametrize(("instance", "path", "words"), [
    ({"rate_hz": -2}, ("rate_hz",), "must be a number > 0, got -2"),
    ({"rate_hz": float("nan")}, ("rate_hz",), "must be a number > 0 and <= 120 (finite), "
                                              "got nan"),
    ({"port": "eighty"}, ("port",), "must be an integer, got 'eighty'"),
    ({"port": True}, ("port",), "must be an integer, got True"),
    ({"port": 70000}, ("port",), "must be a number <= 65535, got 70000"),
    ({"mode": "fork"}, ("mode",), "must be process | thread, got 'fork'"),
    ({"rgb": [1, 2]}, ("rgb",), "must be three positive numbers [r, g, b], got [1, 2]"),
    ({"rgb": [1, 2, -1]}, ("rgb",), "must be three positive numbers [r, g, b], got [1, 2, -1]"),
    ({"rat_hz": 2}, ("rat_hz",), "(known: rate_hz, port, mode, rgb)"),
])
def test_problems_name_the_key_and_what_is_allowed(instance, path, words):
    problem = first_problem(instance, SCHEMA)
    assert (problem.path, problem.words, problem.unknown) == (path, words, "known" in words)
    assert first_problem({"rate_hz": 120, "port": 1, "mode": "thread", "rgb": [1, 1, 1]},
                         SCHEMA) is None
