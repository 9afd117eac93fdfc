"""Compiled float kernels generated from the law functions.

The laws of :mod:`awiwi_drake.components` are written once, generic in the scalar type.  For the float
hot path they are evaluated *once* on ``pydrake.symbolic`` variables; the expression DAG
(``get_kind()`` / ``Unapply()``) is emitted as straight-line Python with one temporary per distinct
sub-expression (hash-consing on the emitted code) and compiled with numba (``njit(cache=True)``).  The
kernel is not a second copy of the physics: change a law and the kernel follows (the source hash changes,
so does the disk cache, ``$AWIWI_KERNEL_CACHE``, default ``~/.cache/awiwi_drake/kernels``; compile and
load times: README, "How the plants are built, and speed").  :func:`compile_kernels` returns one function
per requested output group, so a system evaluates only what a port needs.
"""

from __future__ import annotations

import hashlib
import importlib.util
import math
import os
import pathlib
import re
import sys
from typing import Mapping, Sequence

import numpy as np
import pydrake.symbolic as sym

__all__ = ["compile_kernels", "compile_source", "kernel_cache_dir", "emit_source"]

_EK = sym.ExpressionKind
_FK = sym.FormulaKind

_UNARY = {
    _EK.Abs: "abs", _EK.Sqrt: "math.sqrt", _EK.Exp: "math.exp", _EK.Log: "math.log",
    _EK.Sin: "math.sin", _EK.Cos: "math.cos", _EK.Tan: "math.tan", _EK.Asin: "math.asin",
    _EK.Acos: "math.acos", _EK.Atan: "math.atan", _EK.Sinh: "math.sinh", _EK.Cosh: "math.cosh",
    _EK.Tanh: "math.tanh", _EK.Ceil: "math.ceil", _EK.Floor: "math.floor",
}
# the same functions on numpy arrays (emit_source(vectorized=True): every input entry a row of samples)
_UNARY_NP = {k: ("abs" if v == "abs" else "np." + v[5:].replace("asin", "arcsin").replace("acos", "arccos")
                 .replace("atan", "arctan")) for k, v in _UNARY.items()}
_TEMP = re.compile(r"\bt\d+\b")
_COMPARE = {_FK.Gt: ">", _FK.Geq: ">=", _FK.Lt: "<", _FK.Leq: "<=", _FK.Eq: "==", _FK.Neq: "!="}


def kernel_cache_dir() -> pathlib.Path:
    """Where generated kernels and numba's compiled code are cached."""
    root = os.environ.get("AWIWI_KERNEL_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "awiwi_drake", "kernels")
    return pathlib.Path(root)


def code_text(source: str) -> str:
    """What a module executes, as text: its syntax tree without docstrings (every statement that is only a string,
    which Python evaluates and drops), comments, formatting or line numbers. An edit of a docstring or a comment
    keeps the text; any change of code, constant or default changes it. Cache keys hash this, not the bytes."""
    import ast

    class Strip(ast.NodeTransformer):
        def visit_Expr(self, node):
            return None if isinstance(node.value, ast.Constant) and isinstance(node.value.value, str) else node

    tree = Strip().visit(ast.parse(source))
    for node in ast.walk(tree):   # a body that was only a docstring keeps a statement
        if not isinstance(node, ast.Module) and getattr(node, "body", None) == []:
            node.body = [ast.Pass()]
    return ast.dump(tree, annotate_fields=False, include_attributes=False)


def _const(v: float) -> str:
    if math.isnan(v):
        return "math.nan"
    if math.isinf(v):
        return "math.inf" if v > 0 else "-math.inf"
    return repr(float(v))


class _Emitter:
    """Straight-line code for a set of expressions, one temporary per distinct node."""

    def __init__(self, var_names: Mapping, vectorized: bool = False):
        self.var_names = var_names          # Variable.get_id() -> source name
        self.vectorized = vectorized        # numpy elementwise forms (np.where, np.arctan, ...)
        self.lines: list[tuple[str, str]] = []
        self.used: set[str] = set()
        self._memo: dict[str, str] = {}     # emitted code of a node -> its temporary
        self._count = 0

    def _new(self, code: str) -> str:
        name = f"t{self._count}"
        self._count += 1
        self.lines.append((name, code))
        return name

    def body(self, results: Sequence[str]) -> tuple[list[str], list[str]]:
        """(statement lines, result expressions) with single-use temporaries inlined (fewer statements: numba
        infers types per statement); nesting is capped for the parser."""
        uses: dict[str, int] = {}
        for _, code in self.lines:
            for ref in _TEMP.findall(code):
                uses[ref] = uses.get(ref, 0) + 1
        for r in results:
            for ref in _TEMP.findall(r):
                uses[ref] = uses.get(ref, 0) + 1
        inline: dict[str, tuple[str, int]] = {}   # name -> (code, nesting depth)

        def expand(code: str) -> tuple[str, int]:
            depth = [0]

            def rep(m):
                got = inline.get(m.group(0))
                if got is None:
                    return m.group(0)
                depth[0] = max(depth[0], got[1] + 1)
                return f"({got[0]})"
            return _TEMP.sub(rep, code), depth[0]

        out = []
        for name, code in self.lines:
            code, depth = expand(code)
            if uses.get(name, 0) == 1 and depth < 40:
                inline[name] = (code, depth)
            else:
                out.append(f"    {name} = {code}")
        return out, [expand(r)[0] for r in results]

    def expr(self, e) -> str:
        if not isinstance(e, sym.Expression):
            if isinstance(e, sym.Variable):
                e = sym.Expression(e)
            else:
                return _const(float(e))
        kind = e.get_kind()
        if kind == _EK.Constant:
            return _const(e.Evaluate())
        if kind == _EK.Var:
            v = e.GetVariables()
            (var,) = list(v)
            try:
                name = self.var_names[var.get_id()]
                self.used.add(name)
                return name
            except KeyError:
                raise ValueError(f"codegen: expression uses variable {var.get_name()!r} that is not a kernel input") from None
        code = self._node(e, kind)          # children first: hash-consing on the emitted code
        name = self._memo.get(code)
        if name is None:
            name = self._memo[code] = self._new(code)
        return name

    def _node(self, e, kind) -> str:
        _, args = e.Unapply()
        if kind == _EK.Add:
            c, terms = float(args[0]), [self.expr(a) for a in args[1:]]
            parts = ([] if c == 0.0 else [_const(c)]) + terms
            return " + ".join(parts) if parts else "0.0"
        if kind == _EK.Mul:
            c, facs = float(args[0]), [self.expr(a) for a in args[1:]]
            parts = ([] if c == 1.0 else [_const(c)]) + facs
            return " * ".join(parts) if parts else "1.0"
        if kind == _EK.Div:
            return f"{self.expr(args[0])} / {self.expr(args[1])}"
        if kind == _EK.Pow:
            base = self.expr(args[0])
            ex = args[1]
            if ex.get_kind() == _EK.Constant:
                p = ex.Evaluate()
                if p == int(p) and 1 <= p <= 4:
                    return " * ".join([base] * int(p))
                if p == int(p) and abs(p) <= 64:
                    return f"{base} ** {int(p)}"
                return f"{base} ** {_const(p)}"
            return f"{base} ** {self.expr(ex)}"
        if kind in _UNARY:
            return f"{(_UNARY_NP if self.vectorized else _UNARY)[kind]}({self.expr(args[0])})"
        if kind == _EK.Atan2:
            return f"{'np.arctan2' if self.vectorized else 'math.atan2'}({self.expr(args[0])}, {self.expr(args[1])})"
        if kind in (_EK.Min, _EK.Max):
            # branch-free: numba's compile time grows steeply with builtin min/max call sites and
            # with branches (the hand's drive: 40 s and 100 s). max(a, 0) = (a + |a|)/2 is exact;
            # otherwise the result is within one rounding of the larger magnitude.
            a, b = self.expr(args[0]), self.expr(args[1])
            sign = "-" if kind == _EK.Min else "+"
            if b == "0.0":
                return f"0.5 * ({a} {sign} abs({a}))"
            if a == "0.0":
                return f"0.5 * ({b} {sign} abs({b}))"
            return f"0.5 * ({a} + {b} {sign} abs({a} - {b}))"
        if kind == _EK.IfThenElse:
            cond = self.formula(args[0])
            a, b = self.expr(args[1]), self.expr(args[2])
            return f"np.where({cond}, {a}, {b})" if self.vectorized else f"{a} if {cond} else {b}"
        raise ValueError(f"codegen: expression kind {kind} is not supported ({e.to_string()[:80]})")

    def formula(self, f) -> str:
        kind = f.get_kind()
        if kind == _FK.True_:
            return "True"
        if kind == _FK.False_:
            return "False"
        _, args = f.Unapply()
        if kind in _COMPARE:
            return f"({self.expr(args[0])} {_COMPARE[kind]} {self.expr(args[1])})"
        if kind == _FK.Not:
            return f"np.logical_not({self.formula(args[0])})" if self.vectorized else f"(not {self.formula(args[0])})"
        if kind in (_FK.And, _FK.Or):
            if self.vectorized:
                fn = "np.logical_and" if kind == _FK.And else "np.logical_or"
                code = self.formula(args[0])
                for a in args[1:]:
                    code = f"{fn}({code}, {self.formula(a)})"
                return code
            op = " and " if kind == _FK.And else " or "
            return "(" + op.join(self.formula(a) for a in args) + ")"
        raise ValueError(f"codegen: formula kind {kind} is not supported ({f.to_string()[:80]})")


def emit_source(functions: Mapping[str, tuple[Sequence[Sequence], Sequence]], extra: str = "", *,
                vectorized: bool = False) -> str:
    """Python source of one module with one function per entry.

    ``functions[name] = (inputs, outputs)``: ``inputs`` is a list of variable vectors (one array argument
    each), ``outputs`` a vector of expressions written into the last argument ``out``; each function also
    gets a ``<name>_batch`` twin taking 2-D arrays (one row per copy).  ``extra`` is appended verbatim (numba
    functions that combine the generated ones; they may use ``math``, ``numba`` and ``np``).
    ``vectorized``: numpy's elementwise forms for plain Python, without twins: ``fn(states.T, out.T)``
    evaluates many states at once.
    """
    lines = ["# Generated by awiwi_drake.components.codegen from the law functions. Do not edit.",
             "import math", "import numba", ""]
    if extra or vectorized:
        lines.insert(-1, "import numpy as np")
    for fname, (inputs, outputs) in functions.items():
        var_names = {}
        args = []
        body_in = []
        for a, vec in enumerate(inputs):
            args.append(f"a{a}")
            for i, v in enumerate(vec):
                nm = f"a{a}_{i}"
                var_names[v.get_id()] = nm
                body_in.append(f"    {nm} = a{a}[{i}]")
        em = _Emitter(var_names, vectorized)
        statements, results = em.body([em.expr(o) for o in outputs])
        if not vectorized:
            lines.append("@numba.njit(cache=True, fastmath=False, error_model='numpy')")
        lines.append(f"def {fname}({', '.join(args + ['out'])}):")
        lines.extend(ln for ln in body_in if ln.split(" = ")[0].strip() in em.used)
        lines.extend(statements)
        lines.extend(f"    out[{i}] = {r}" for i, r in enumerate(results))
        lines.append("    return out")
        lines.append("")
        if vectorized:
            continue
        # the same function over N copies: 2-D arguments, one row per copy (batched rigs)
        lines.append("@numba.njit(cache=True, fastmath=False, error_model='numpy')")
        lines.append(f"def {fname}_batch({', '.join(args + ['out'])}):")
        lines.append("    for i in range(out.shape[0]):")
        lines.append(f"        {fname}({', '.join(a + '[i]' for a in args + ['out'])})")
        lines.append("    return out")
        lines.append("")
    if extra:
        lines.append(extra)
    return "\n".join(lines)


_LOADED: dict[str, object] = {}


class _NoJit:
    """Stand-in for ``numba`` that leaves the generated functions as plain Python."""

    @staticmethod
    def njit(*args, **kwargs):
        return lambda fn: fn


def compile_kernels(functions: Mapping[str, tuple[Sequence[Sequence], Sequence]], *, tag: str = "kernel",
                    jit: bool = True, extra: str = "", extra_names: Sequence[str] = (), vectorized: bool = False):
    """Generate, cache and import numba kernels; returns ``{name: function}``.

    Each function takes its input vectors (float64 1-D arrays) and an output array, fills and returns it;
    numba compiles it at its first call and caches it on disk.  ``jit=False`` runs the same source as plain
    Python; ``extra`` / ``extra_names``: hand-written functions appended to the module and returned too;
    ``vectorized``: the numpy forms of :func:`emit_source`, as plain Python (many samples at once).
    """
    with np.errstate(invalid="ignore"):
        source = emit_source(functions, extra, vectorized=vectorized)
    names = [n for name in functions for n in ((name,) if vectorized else (name, f"{name}_batch"))]
    return compile_source(source, names + list(extra_names), tag=tag, jit=jit and not vectorized)


def compile_source(source: str, names: Sequence[str], *, tag: str = "kernel", jit: bool = True):
    """Import a module generated by :func:`emit_source` (compiled by numba, cached on disk by its
    source digest); returns ``{name: function}`` for ``names``."""
    if not jit:
        namespace = {"math": math, "numba": _NoJit, "np": np}
        exec(compile(source.replace("import numba\n", ""), f"<{tag}>", "exec"), namespace)
        return {name: namespace[name] for name in names}
    digest = hashlib.sha1(source.encode()).hexdigest()[:16]
    modname = f"awiwi_kernel_{tag}_{digest}"
    if modname in _LOADED:
        mod = _LOADED[modname]
    else:
        folder = kernel_cache_dir()
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = _write_module(folder, modname, source)
        except OSError as exc:   # unwritable cache: compile from a temporary folder (no reuse across runs)
            import tempfile
            import warnings
            warnings.warn(f"kernel cache {folder} is not writable ({exc}); set AWIWI_KERNEL_CACHE to a writable "
                          "folder to keep compiled kernels between runs", RuntimeWarning, stacklevel=2)
            folder = pathlib.Path(tempfile.mkdtemp(prefix="awiwi_kernels_"))
            path = _write_module(folder, modname, source)
        spec = importlib.util.spec_from_file_location(modname, path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[modname] = mod
        spec.loader.exec_module(mod)
        _LOADED[modname] = mod
    return {name: getattr(mod, name) for name in names}


def _write_module(folder: pathlib.Path, modname: str, source: str) -> pathlib.Path:
    path = folder / f"{modname}.py"
    if not path.exists() or path.read_text() != source:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(source)
        os.replace(tmp, path)       # atomic: concurrent processes never see a half-written module
    return path

