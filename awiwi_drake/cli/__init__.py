"""The ``awiwi-drake`` command line.

Each command group lives in its own module in this package and exposes
``register(subparsers)``, which adds sub-commands whose ``func(args) -> int``
does the work.  To add a group, create the module and list it in
``_COMMAND_MODULES``.  User errors (``ValueError``, ``FileNotFoundError``,
``KeyError``, ``OSError`` on a named path, ``CliError``, argparse errors) print
one line on stderr and exit 2; failures of the computation itself
(``RuntimeError``, e.g. ``analysis.SimulationDivergedError``; ``ArithmeticError``) print one
line and exit 1.  No traceback either way; an unexpected exception also prints
one line (exit 1) naming its type, and ``AWIWI_DEBUG=1`` shows the traceback.
Output paths are checked (:func:`output_dir`, :func:`output_file`) before any
long computation starts.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import pathlib
import sys

__all__ = ["main", "CliError", "parse_sets", "output_dir", "output_file", "finite_float", "positive_float",
           "limited_float", "add_parameter_options", "load_parameters"]

# One module per command group (see each module's register()).
_COMMAND_MODULES = [
    "awiwi_drake.cli.rigs",
    "awiwi_drake.cli.compare",
    "awiwi_drake.cli.hand",
    "awiwi_drake.cli.discrepancy",
    "awiwi_drake.cli.reproduce",
]


class CliError(Exception):
    """A user error: printed as one line, exit status 2."""


def parse_sets(items: list[str] | None, option: str = "--set") -> dict[str, str]:
    """Parse repeated ``--set NAME=VALUE`` arguments (of ``option``) into a dict."""
    out: dict[str, str] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise CliError(f"{option} expects NAME=VALUE, got {item!r}")
        out[name.strip()] = value
    return out


def add_parameter_options(p: argparse.ArgumentParser, what: str = "the rig's parameter set",
                          example: str = "e.g. written by 'params RIG --yaml'") -> None:
    """``--config FILE`` (YAML) and repeated ``--set NAME=VALUE`` (applied after the file)."""
    p.add_argument("--config", metavar="FILE.yaml",
                   help=f"YAML file with {what} (all or some fields; {example}); "
                        "read with Drake's yaml_load_typed")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override one parameter by field name (nested sets searched, dotted paths like "
                        "motor.inertia work); repeatable; applied after --config")


def load_parameters(defaults, args, option: str = "set"):
    """``defaults`` with ``args.config`` (YAML) and then ``args.set`` applied (``option="controller_set"``: only
    ``args.controller_set``, e.g. ``--controller-set``).  An unknown name or bad value names the option."""
    from awiwi_drake.parameters.yaml_io import load_yaml

    params = defaults
    if option == "set" and getattr(args, "config", None):
        params = load_yaml(params, args.config)
    flag = "--" + option.replace("_", "-")
    sets = parse_sets(getattr(args, option, None), flag)
    try:
        return params.with_overrides(sets) if sets else params
    except ValueError as exc:
        raise CliError(f"{flag}: {exc}") from None


def output_dir(path, option: str = "--out") -> pathlib.Path:
    """Create (if needed) and return the output folder ``path``; a one-line ``CliError`` if it cannot be used."""
    p = pathlib.Path(path)
    if p.exists() and not p.is_dir():
        raise CliError(f"{option} {p}: exists and is not a directory")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f"{option} {p}: cannot create the folder ({exc.strerror or exc})") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise CliError(f"{option} {p}: the folder is not writable")
    return p


def output_file(path, option: str = "--out", *, suffixes: tuple[str, ...] = ()) -> pathlib.Path:
    """Check that the file ``path`` can be written (its folder is created); returns the path.

    An existing file is overwritten; a directory, an unwritable file or folder, or
    a wrong suffix (when ``suffixes`` is given) raise a one-line ``CliError``.
    """
    p = pathlib.Path(path)
    if suffixes and p.suffix.lower() not in suffixes:
        raise CliError(f"{option} {p}: expected a file name ending in {' or '.join(suffixes)}")
    if p.is_dir():
        raise CliError(f"{option} {p}: is a directory; give a file name")
    output_dir(p.parent if str(p.parent) else ".", option=f"{option} folder")
    if p.exists() and not os.access(p, os.W_OK):
        raise CliError(f"{option} {p}: the file is not writable")
    return p


def finite_float(text: str) -> float:
    """argparse type: a finite real number (argparse names the option on error)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not finite")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return value


def limited_float(high: str, unit: str, *, low: str | None = None, zero: bool = False, positive: bool = False):
    """argparse type: a finite number in [``CliLimits.<low>`` (default 0), ``CliLimits.<high>``] (``zero``: 0
    also allowed; ``positive``: > 0)."""
    def parse(text: str) -> float:
        from awiwi_drake.parameters.cli import CliLimits

        lim, value = CliLimits(), (positive_float if positive else finite_float)(text)
        lo, hi = (0.0 if low is None else getattr(lim, low)), getattr(lim, high)
        if not (lo <= value <= hi or (zero and value == 0)):
            raise argparse.ArgumentTypeError(f"{text!r} must be {'0 (continuous) or ' if zero else ''}in "
                                             f"[{lo:g}, {hi:g}] {unit} (CliLimits)")
        return value
    return parse


def _version() -> str:
    try:
        from importlib.metadata import version
        return version("awiwi_drake")
    except Exception:  # noqa: BLE001 - not installed (source checkout on PYTHONPATH)
        return "unknown (not installed)"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (the option is named by argparse)."""

    def error(self, message: str):  # noqa: D401 - argparse hook
        print(f"{self.prog}: error: {message} (see '{self.prog} --help')", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="awiwi-drake",
        description="Model, simulate, linearise and control the DLR Awiwi hand (Drake).")
    parser.add_argument("--version", action="version", version=f"awiwi-drake {_version()}",
                        help="print the package version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status (0 ok, 1 failed computation, 2 user error)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: usage error (2) or --help/--version (0); message already printed
        return int(exc.code or 0) if not isinstance(exc.code, str) else 2
    cmd = f"awiwi-drake {args.command}"
    try:
        return int(args.func(args) or 0)
    except (CliError, ValueError, FileNotFoundError, KeyError) as exc:
        msg = exc.args[0] if (isinstance(exc, KeyError) and exc.args) else str(exc)
        print(f"{cmd}: error: {_one_line(msg)}", file=sys.stderr)
        return 2
    except OSError as exc:  # a path the user gave: name it
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{cmd}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except (RuntimeError, ArithmeticError) as exc:  # e.g. SimulationDivergedError: a diverged simulation
        print(f"{cmd}: error: {_one_line(str(exc)) or type(exc).__name__}", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - never a traceback for the user; AWIWI_DEBUG=1 shows it
        if os.environ.get("AWIWI_DEBUG", "0") not in ("", "0"):
            raise
        print(f"{cmd}: internal error ({type(exc).__name__}): {_one_line(str(exc))} "
              f"(set AWIWI_DEBUG=1 for the traceback and please report it)", file=sys.stderr)
        return 1


def _one_line(text: str) -> str:
    text = str(text).strip()
    return text.splitlines()[0] if text else ""


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
