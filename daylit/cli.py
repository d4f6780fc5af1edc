"""The ``daylit`` command: one entry point, one subcommand per job.

Each package registers its own subcommands (``bake.cli``, ``server.cli``) so that this module
stays a thin switchboard and ``daylit --help`` starts fast.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys

from daylit import __version__

# (module, function that adds its subparsers)
SUBCOMMAND_MODULES = ("bake.cli", "server.cli")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="daylit",
        description=(
            "Show lost buildings on their real site under the real, changing sky. "
            "Bake a site once, then serve it to phones, tablets and the kiosk."
        ),
    )
    parser.add_argument("--version", action="version", version=f"daylit {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module_name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            continue
        module.add_subcommands(subparsers)
    return parser


# An option's value that argparse would take for an option: a minus and a digit or a point.
_NEGATIVE_VALUE = re.compile(r"^-\.?\d")


def attach_negative_values(argv: list[str]) -> list[str]:
    """``--point -8,0,0`` -> ``--point=-8,0,0`` for any long option followed by a value that
    starts with a minus and a digit (argparse refuses it as an unknown option otherwise; no
    option of daylit starts with a digit, so nothing else changes meaning)."""
    out: list[str] = []
    for token in argv:
        previous = out[-1] if out else ""
        if (
            _NEGATIVE_VALUE.match(token)
            and previous.startswith("--")
            and "=" not in previous
            and previous != "--"
        ):
            out[-1] = f"{previous}={token}"
        else:
            out.append(token)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(attach_negative_values(sys.argv[1:] if argv is None else argv))
    if not getattr(args, "run", None):
        parser.print_help()
        return 2
    try:
        return int(args.run(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
