"""``daylit bake`` and ``daylit probe``."""

from __future__ import annotations


def add_subcommands(subparsers) -> None:
    pass
