"""docs/architecture.md's module map against the tree: every module of bake/, daylit/,
server/ (with its sub-packages) and web/src/ listed exactly once, and nothing listed that is
not there."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _listed() -> list[str]:
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = text[text.index("## Module map"):]
    return re.findall(r"^- `([\w/.-]+\.(?:py|js))` — \S", section, flags=re.M)


def _modules() -> set[str]:
    found = set()
    for folder, pattern in (("bake", "*.py"), ("daylit", "*.py"), ("server", "**/*.py"),
                            ("web/src", "*.js")):
        found |= {p.relative_to(ROOT).as_posix() for p in (ROOT / folder).glob(pattern)}
    return found


def test_the_module_map_lists_every_module_once():
    listed = _listed()
    assert len(listed) == len(set(listed)), "listed twice"
    assert set(listed) == _modules()
