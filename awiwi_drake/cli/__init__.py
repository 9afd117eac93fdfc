"""The ``awiwi-drake`` command line.

Each command group lives in its own module in this package and exposes
``register(subparsers)``, which adds sub-commands whose ``func(args) -> int``
does the work.  To add a group, create the module and list it in
``_COMMAND_MODULES``.  User errors (``ValueError``, ``FileNotFoundError``,
``KeyError``, ``CliError``) print one line on stderr and exit 2; failures of
the computation itself (``RuntimeError``, e.g. a diverged simulation) print
one line and exit 1. No traceback either way.
"""

from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["main", "CliError", "parse_sets"]

# One module per command group (see each module's register()).
_COMMAND_MODULES = [
    "awiwi_drake.cli.rigs",
    "awiwi_drake.cli.compare",
    "awiwi_drake.cli.hand",
]


class CliError(Exception):
    """A user error: printed as one line, exit status 2."""


def parse_sets(items: list[str] | None) -> dict[str, str]:
    """Parse repeated ``--set NAME=VALUE`` arguments into a dict."""
    out: dict[str, str] = {}
    for item in items or []:
        if "=" not in item:
            raise CliError(f"--set expects NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        name = name.strip()
        if not name:
            raise CliError(f"--set expects NAME=VALUE, got {item!r}")
        out[name] = value
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="awiwi-drake",
        description="Model, simulate, linearise and control the DLR Awiwi hand (Drake).")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (CliError, ValueError, FileNotFoundError, KeyError) as exc:
        msg = exc.args[0] if (isinstance(exc, KeyError) and exc.args) else str(exc)
        print(f"awiwi-drake {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # e.g. Drake refusing a non-equilibrium, a diverged simulation
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        print(f"awiwi-drake {args.command}: error: {first}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
