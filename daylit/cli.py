"""The ``daylit`` command: one entry point, one subcommand per job.

Each package registers its own subcommands (``bake.cli``, ``server.cli``) so that this module
stays a thin switchboard and ``daylit --help`` starts fast.
"""

from __future__ import annotations

import argparse
import importlib
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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "run", None):
        parser.print_help()
        return 2
    try:
        return int(args.run(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
