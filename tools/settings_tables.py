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

from daylit.settingschema import reference_table, replace_table, table_in

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
    for section, schema in json_schema()["properties"].items():
        out.append((ROOT / "docs" / "server.md", f"server.{section}",
                    reference_table(schema, in_repo)))
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
