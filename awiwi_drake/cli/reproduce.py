"""``awiwi-drake reproduce``: the thesis figures of :data:`awiwi_drake.reproductions.FIGURES`, written to a folder.

``--list`` prints each id with its thesis reference and one line; ``reproduce ID [ID ...] --out DIR [--short]``
runs them (:func:`awiwi_drake.reproductions.reproduce`) and writes ``ID.png``, ``ID.csv`` (series, units in the
column names) and ``ID.json`` (numbers with units).  The ids and the studies live in the reproductions package.
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["register"]


def register(sub) -> None:
    p = sub.add_parser(
        "reproduce", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="recompute thesis figures (PNG + CSV/JSON with units) into a folder; --list shows the ids",
        epilog="Example: awiwi-drake reproduce fig15.26 fig15.24 --out out/figures --short\n"
               "docs/REPRODUCTIONS.md records each figure: the printed value, ours, the verdict.")
    p.add_argument("ids", nargs="*", metavar="ID", help="figure ids (see --list)")
    p.add_argument("--list", action="store_true", help="print the figure ids with their thesis reference and exit")
    p.add_argument("--out", metavar="DIR", help="folder to write ID.png, ID.csv, ID.json into (created)")
    p.add_argument("--short", action="store_true",
                   help="the studies' short mode (shorter runs, fewer cases: seconds instead of minutes)")
    p.set_defaults(func=_reproduce)


def _reproduce(args) -> int:
    from awiwi_drake.cli import CliError, output_dir
    from awiwi_drake.reproductions import FIGURES, reproduce

    if args.list:
        width = max(len(i) for i in FIGURES)
        for e in FIGURES.values():
            print(f"{e.id:<{width}}  {e.reference:<28s} {e.summary}")
        return 0
    if not args.ids:
        raise CliError(f"give at least one figure id (known: {', '.join(FIGURES)}) or --list")
    unknown = [i for i in args.ids if i not in FIGURES]
    if unknown:
        raise CliError(f"unknown figure id {unknown[0]!r}; known: {', '.join(FIGURES)} (see --list)")
    if not args.out:
        raise CliError("--out DIR is required to write the figures")
    out = output_dir(args.out, "--out")
    written = reproduce(args.ids, out, short=args.short,
                        progress=lambda i: print(f"{i}: running {FIGURES[i].reference} ...", file=sys.stderr))
    for i, paths in written.items():
        print(f"{i}: wrote {', '.join(str(p) for p in paths)}")
    return 0
