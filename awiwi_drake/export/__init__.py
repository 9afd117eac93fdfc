"""Diagram export: Graphviz ``.dot`` always, ``.svg``/``.png`` when ``dot`` is installed.

Meshcat HTML recordings of a finger or the hand are :mod:`awiwi_drake.export.animation`.
"""

from __future__ import annotations

import pathlib
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field

from pydrake.systems.framework import Diagram

__all__ = ["ExportResult", "export_diagram", "graphviz_available", "canonical_ids"]


@dataclass
class ExportResult:
    """Files written by :func:`export_diagram` and what was skipped (and why)."""

    dot: pathlib.Path
    images: list = field(default_factory=list)
    skipped: list = field(default_factory=list)


_ID = re.compile(r"\b(_|s|clusters|cluster)(\d+)(?=in\b|out\b|diagram\b|subsystems\b|\b|:)")


def canonical_ids(dot_text: str) -> str:
    """Renumber Drake's system ids (which depend on creation order) as 1, 2, 3, ...

    Makes exported graphs reproducible, so committed ``diagrams/*.dot`` can be
    compared with freshly generated ones.
    """
    mapping: dict[str, str] = {}

    def sub(m):
        new = mapping.setdefault(m.group(2), str(len(mapping) + 1))
        return m.group(1) + new

    lines = _ID.sub(sub, dot_text).split("\n")
    # Edges come out in id order, which also depends on creation order: sort each run of edges.
    out, run = [], []
    for line in lines + [""]:
        if "->" in line:
            run.append(line)
            continue
        out.extend(sorted(run))
        run = []
        out.append(line)
    return "\n".join(out[:-1])


def graphviz_available() -> bool:
    """True when the Graphviz ``dot`` executable is on PATH."""
    return shutil.which("dot") is not None


def export_diagram(diagram: Diagram, out_dir, name: str, *, max_depth: int | None = None,
                   formats=("svg", "png"), quiet: bool = False) -> ExportResult:
    """Write ``name.dot`` (and ``name.svg``/``name.png`` if ``dot`` is available).

    Parameters
    ----------
    diagram : Diagram
    out_dir : path
        Created if missing.
    name : str
        File stem.
    max_depth : int, optional
        Graphviz nesting depth (0: top level only; None: everything).
    formats : tuple of str
        Image formats rendered by ``dot``.
    quiet : bool
        Do not print the note about a missing ``dot``.
    """
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    options = {"split": "I/O"}
    text = (diagram.GetGraphvizString(max_depth=max_depth, options=options) if max_depth is not None
            else diagram.GetGraphvizString(options=options))
    dot_path = out / f"{name}.dot"
    dot_path.write_text(canonical_ids(text))
    result = ExportResult(dot_path)
    if not graphviz_available():
        result.skipped = [f"{name}.{fmt}" for fmt in formats]
        if not quiet:
            print(f"export_diagram: Graphviz 'dot' not found; wrote {dot_path} only "
                  f"(install the Debian package 'graphviz' for {'/'.join(formats)})", file=sys.stderr)
        return result
    for fmt in formats:
        target = out / f"{name}.{fmt}"
        proc = subprocess.run(["dot", f"-T{fmt}", str(dot_path), "-o", str(target)], capture_output=True, text=True)
        if proc.returncode != 0:
            result.skipped.append(f"{target.name}: dot failed: {proc.stderr.strip()[:200]}")
        else:
            result.images.append(target)
    return result
