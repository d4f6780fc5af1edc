"""Settings checked against JSON Schema, the one mechanism for settings (as for the manifest).

A settings schema is a JSON Schema (draft 2020-12) object whose ``properties`` are the keys,
each with a ``default`` and a ``description`` (its meaning, with units), and optionally
``x-allowed``: the words for what is allowed where the keywords alone would say it badly
(``"three positive numbers [r, g, b]"``). :func:`first_problem` validates with ``jsonschema``
and words the first problem as ``KEY must be WHAT, got VALUE``, WHAT from the keyword that
failed (``a number > 0``, ``an integer``, ``srgb | linear``) or ``x-allowed``;
:func:`reference_table` writes the Markdown table of keys the docs hold (a test keeps each
docs table equal to it).

Numbers must also be finite: JSON Schema's bounds let NaN through (TOML can spell ``nan``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import jsonschema

_TYPE_WORDS = {"integer": "an integer", "number": "a number", "string": "a string",
               "boolean": "true or false", "array": "a list", "object": "a table of keys",
               "null": "nothing"}


def _number(x: float) -> str:
    return f"{x:g}"


def allowed(prop: dict) -> str:
    """What a property allows, in words (``x-allowed``, else from its keywords)."""
    if "x-allowed" in prop:
        return prop["x-allowed"]
    if "enum" in prop:
        return " | ".join(str(v) for v in prop["enum"])
    kind = prop.get("type")
    if isinstance(kind, list):
        return " or ".join(_TYPE_WORDS[k] for k in kind)
    if kind == "array" and "items" in prop:
        count = prop.get("minItems") if prop.get("minItems") == prop.get("maxItems") else None
        item = allowed(prop["items"])
        noun = item.split(" ")[1] if item.startswith(("a ", "an ")) else item
        each = item.split(" ", 2)[2] if item.count(" ") >= 2 else ""
        words = f"a list of {count} {noun}s" if count else f"a list of {noun}s"
        return f"{words}, each {each}" if each else words
    words = _TYPE_WORDS.get(kind, "any value")
    bounds = []
    if "exclusiveMinimum" in prop:
        bounds.append(f"> {_number(prop['exclusiveMinimum'])}")
    if "minimum" in prop:
        bounds.append(f">= {_number(prop['minimum'])}")
    if "exclusiveMaximum" in prop:
        bounds.append(f"< {_number(prop['exclusiveMaximum'])}")
    if "maximum" in prop:
        bounds.append(f"<= {_number(prop['maximum'])}")
    return f"{words} {' and '.join(bounds)}".strip()


def _failed_words(error: jsonschema.ValidationError, prop: dict, inside: bool) -> str:
    """WHAT of the message for one failed keyword of the property ``prop`` (``inside``: in
    one of its items, then the words say what the whole value must be)."""
    if "x-allowed" in prop or inside:
        return allowed(prop)
    keyword, value = error.validator, error.validator_value
    if keyword == "type":
        return _TYPE_WORDS.get(value, allowed(prop)) if isinstance(value, str) else allowed(prop)
    if keyword in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum"):
        sign = {"minimum": ">=", "exclusiveMinimum": ">", "maximum": "<=",
                "exclusiveMaximum": "<"}[keyword]
        return f"a number {sign} {_number(value)}"
    return allowed(prop)


def _show(value: Any) -> str:
    if isinstance(value, float) and value.is_integer():
        return repr(int(value)) if abs(value) < 1e15 else repr(value)
    return repr(value)


@dataclass(frozen=True)
class Problem:
    """One problem: ``path`` the key's path (``("sky", "rate_hz")``), ``words`` e.g.
    ``"must be a number > 0, got -2"``; for a key the schema does not have, ``unknown`` is
    true and ``words`` lists the known ones, ``"(known: a, b)"``."""

    path: tuple
    words: str
    unknown: bool = False


def first_problem(instance: dict, schema: dict, depth: int = 1) -> Problem | None:
    """The first problem of ``instance`` against ``schema``, or None.

    ``depth`` is how many levels of tables hold the keys (1: flat keys, 2: sections of
    keys).
    """
    validator = jsonschema.Draft202012Validator(schema)
    errors = sorted(validator.iter_errors(instance),
                    key=lambda e: (tuple(str(p) for p in e.path), e.validator != "type"))
    for error in errors:
        path = tuple(error.path)
        if error.validator == "additionalProperties":
            here = _at(schema, path)
            known = list(here.get("properties", {}))
            extra = sorted(set(_get(instance, path)) - set(known))
            return Problem(path + (extra[0],), f"(known: {', '.join(known)})", unknown=True)
        if len(path) < depth:  # a section that is not a table
            return Problem(path, f"must be a table of keys, got {_show(_get(instance, path))}")
        key_path = path[:depth]
        prop = _at(schema, key_path)
        words = _failed_words(error, prop, inside=len(path) > depth)
        return Problem(key_path, f"must be {words}, got {_show(_get(instance, key_path))}")
    for key_path, value in _leaves(instance, depth):
        if any(isinstance(v, float) and not math.isfinite(v) for v in _flat(value)):
            return Problem(key_path,
                           f"must be {allowed(_at(schema, key_path))} (finite), got {value!r}")
    return None


def _at(schema: dict, path: tuple) -> dict:
    for key in path:
        schema = schema["properties"][key]
    return schema


def _get(instance: Any, path: tuple) -> Any:
    for key in path:
        instance = instance[key]
    return instance


def _leaves(instance: dict, depth: int):
    for key, value in instance.items():
        if depth == 1:
            yield (key,), value
        elif isinstance(value, dict):
            for sub, leaf in _leaves(value, depth - 1):
                yield (key, *sub), leaf


def _flat(value: Any):
    if isinstance(value, list | tuple):
        for v in value:
            yield from _flat(v)
    else:
        yield value


def defaults(schema: dict) -> dict:
    """``{key: default}`` of a flat settings schema."""
    return {key: prop.get("default") for key, prop in schema["properties"].items()}


def _cell(text: str) -> str:
    return text.replace("|", "&#124;")


def default_words(key: str, prop: dict, required=()) -> str:
    """A key's default for a table: ``x-default``, the default as JSON in backquotes,
    ``required``, or ``-`` (optional, no default)."""
    if "x-default" in prop:
        return prop["x-default"]
    if "default" in prop:
        return f"`{json.dumps(prop['default'])}`"
    return "required" if key in required else "-"


def reference_table(schema: dict, default_text=None) -> str:
    """The Markdown table of a flat settings schema: key, default, allowed, meaning.

    ``default_text(key, default)`` may word a default (e.g. a path inside the repository);
    otherwise :func:`default_words`.
    """
    lines = ["| key | default | allowed | meaning |", "|---|---|---|---|"]
    required = schema.get("required", ())
    for key, prop in schema["properties"].items():
        shown = default_text(key, prop.get("default")) if default_text else None
        shown = f"`{shown}`" if shown is not None else default_words(key, prop, required)
        lines.append(f"| `{key}` | {_cell(shown)} | {_cell(allowed(prop))} | "
                     f"{_cell(prop.get('description', ''))} |")
    return "\n".join(lines) + "\n"


def table_in(doc: str, name: str) -> str:
    """The text between ``<!-- settings:NAME -->`` and ``<!-- /settings:NAME -->`` in a doc."""
    start, end = f"<!-- settings:{name} -->\n", f"<!-- /settings:{name} -->"
    if start not in doc or end not in doc:
        raise KeyError(f"no settings table {name!r} in the doc")
    return doc.split(start, 1)[1].split(end, 1)[0]


def replace_table(doc: str, name: str, table: str) -> str:
    """``doc`` with the table between the markers of :func:`table_in` replaced."""
    old = table_in(doc, name)
    start = f"<!-- settings:{name} -->\n"
    return doc.replace(start + old, start + table, 1)
