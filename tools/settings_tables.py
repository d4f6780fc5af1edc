"""Write the settings tables in docs/ from their JSON Schemas (daylit.settingschema).

Usage: python tools/settings_tables.py [--check]

Each table sits between ``<!-- settings:NAME -->`` and ``<!-- /settings:NAME -->`` in its doc;
``--check`` only reports the tables that differ (exit status 1), as
tests/test_settings_tables.py does.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from daylit.settingschema import allowed, reference_table, replace_table, table_in

ROOT = Path(__file__).resolve().parents[1]


def tables() -> list[tuple[Path, str, str]]:
    """(doc, table name, table text) for every generated settings table."""
    from server.config import REPO_ROOT, json_schema
    from server.occlusion.settings import SCHEMA as OCCLUSION

    def in_repo(key, default):
        if isinstance(default, str) and default.startswith(str(REPO_ROOT)):
            return json.dumps("<repo>" + default[len(str(REPO_ROOT)):])
        return None

    out = [(ROOT / "docs" / "occlusion.md", "occlusion", reference_table(OCCLUSION))]
    out += scene_tables()
    for section, schema in json_schema()["properties"].items():
        out.append((ROOT / "docs" / "server.md", f"server.{section}",
                    reference_table(schema, in_repo)))
    return out


def _quality_levels(quality: dict) -> str:
    """The quality levels side by side: key, draft, final, allowed, meaning."""
    levels = [k for k, p in quality["properties"].items() if p.get("type") == "object"]
    lines = ["| key | " + " | ".join(levels) + " | allowed | meaning |",
             "|---|" + "---|" * len(levels) + "---|---|"]
    first = quality["properties"][levels[0]]["properties"]
    for key, prop in first.items():
        values = " | ".join(json.dumps(quality["properties"][lv]["properties"][key]["default"])
                            for lv in levels)
        lines.append(f"| `{key}` | {values} | {allowed(prop)} | {prop['description']} |")
    return "\n".join(lines) + "\n"


def scene_tables() -> list[tuple[Path, str, str]]:
    from bake.scene_schema import SCHEMA

    doc = ROOT / "docs" / "scene-format.md"
    props = SCHEMA["properties"]
    out = []
    for name, prop in props.items():
        table = prop["items"] if prop["type"] == "array" else prop
        if name == "quality":
            table = {**table, "properties": {k: v for k, v in table["properties"].items()
                                             if v.get("type") != "object"}}
            out.append((doc, "scene.quality-levels", _quality_levels(prop)))
        out.append((doc, f"scene.{name}", reference_table(table)))
    out.append((doc, "scene.view.intrinsics",
                reference_table(props["view"]["items"]["properties"]["intrinsics"])))
    return out


def main(argv: list[str]) -> int:
    stale = []
    for doc, name, table in tables():
        text = doc.read_text("utf-8")
        if table_in(text, name) != table:
            stale.append(f"{doc.relative_to(ROOT)}: {name}")
            if "--check" not in argv:
                doc.write_text(replace_table(text, name, table), "utf-8")
    for line in stale:
        print(("stale: " if "--check" in argv else "rewrote: ") + line)
    return 1 if stale and "--check" in argv else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
