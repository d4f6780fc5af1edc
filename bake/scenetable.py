"""A table of a checked ``scene.toml`` and the error that names what is wrong in one.

bake.scene reads a site description through :class:`SceneTable` (each key's default from the
schema, bake/scene_schema.py) and bake.scenegeometry loads the geometry it names; both raise
:class:`SceneError` with the file and the key's full path, so a content preparer sees where
to look.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


class SceneError(ValueError):
    """A mistake in a site description: which file, which key, what is wrong."""

    def __init__(self, path: Path | str, key: str, message: str):
        self.path = str(path)
        self.key = key
        self.message = message
        super().__init__(f"{self.path}: {key}: {message}" if key else f"{self.path}: {message}")



class SceneTable:
    """A table of a scene.toml already checked against its schema (bake/scene_schema.py), with
    the path of keys that led to it for messages; absent keys read as the schema's default
    (None where there is none: an optional key)."""

    def __init__(self, file: Path, prefix: str, data: dict, schema: dict):
        self.file = file
        self.prefix = prefix
        self.data = data
        self.schema = schema

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str) -> Any:
        prop = self.schema["properties"][name]
        return self.data.get(name, prop.get("default"))

    def number(self, name: str) -> float | int | None:
        value = self.raw(name)
        if value is None:
            return None
        return int(value) if self.schema["properties"][name]["type"] == "integer" else float(value)

    def vector(self, name: str) -> np.ndarray | None:
        value = self.raw(name)
        return None if value is None else np.array([float(x) for x in value])

    def string(self, name: str) -> str | None:
        return self.raw(name)

    def boolean(self, name: str) -> bool:
        return self.raw(name)

    def table(self, name: str) -> SceneTable:
        return SceneTable(self.file, self.key(name), self.data.get(name, {}),
                      self.schema["properties"][name])

    def tables(self, name: str) -> list[SceneTable]:
        items = self.schema["properties"][name]["items"]
        return [SceneTable(self.file, f"{self.key(name)}[{i}]", v, items)
                for i, v in enumerate(self.data.get(name, []))]
