"""Parameter dataclasses with units, ranges and provenance.

Every physical number in awiwi_drake is a field of a frozen dataclass derived
from :class:`Parameters` and declared with :func:`param`.  The declaration
carries the unit, the allowed range and the *source* of the default value
(a thesis table/equation, or ``"chosen: <reason>"``).  Construction validates
every field and raises a :class:`ValueError` naming the class and the field.

Example
-------
>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Pendulum(Parameters):
...     mass: float = param(1.0, unit="kg", low=0.0, low_inclusive=False,
...                         source="chosen: unit mass")
>>> Pendulum(mass=-1.0)
Traceback (most recent call last):
...
ValueError: Pendulum.mass = -1.0 is out of range: must be > 0.0 [kg]
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields
from typing import Any, Mapping

import numpy as np

__all__ = ["Parameters", "param", "ParameterInfo", "provenance_table"]


@dataclass(frozen=True)
class ParameterInfo:
    """Metadata of one parameter field (unit, range, source, description)."""

    name: str
    unit: str
    source: str
    low: float | None
    high: float | None
    low_inclusive: bool
    high_inclusive: bool
    doc: str

    def range_text(self) -> str:
        lo = "-inf" if self.low is None else repr(self.low)
        hi = "+inf" if self.high is None else repr(self.high)
        lb = "[" if (self.low is not None and self.low_inclusive) else "("
        rb = "]" if (self.high is not None and self.high_inclusive) else ")"
        text = f"{lb}{lo}, {hi}{rb}"
        if self.high is None and self.unit in UNIT_CEILINGS:
            text += f", abs <= {UNIT_CEILINGS[self.unit]:g}"
        return text


def param(
    default: Any,
    *,
    unit: str,
    source: str,
    low: float | None = None,
    high: float | None = None,
    low_inclusive: bool = True,
    high_inclusive: bool = True,
    doc: str = "",
    vector: bool = False,
    finite: bool = True,
    choices: tuple | None = None,
):
    """Declare a validated dataclass field.

    ``default`` (sequences are stored as tuples); ``unit``: SI unit, e.g. ``"kg m^2"``, ``"-"`` for
    dimensionless; ``source``: where the default comes from (``"Table 12.1"``, ``"(3.8), Table 3.3"`` or
    ``"chosen: <reason>"``); ``low``/``high``: the allowed range (each element of a sequence), bounds
    allowed unless ``low_inclusive``/``high_inclusive`` is False; ``doc``: one-line description; ``vector``:
    a sequence of numbers; ``finite``: reject NaN and infinity; ``choices``: the allowed values of a text
    field.  The field's annotation sets its type: ``bool`` takes only True/False, ``int`` only whole
    numbers, ``str`` text, any other a real number (not a bool).
    """
    if not source:
        raise ValueError("param(): every parameter needs a source")
    meta = dict(unit=unit, source=source, low=low, high=high,
                low_inclusive=low_inclusive, high_inclusive=high_inclusive,
                doc=doc, vector=vector, finite=finite, choices=choices, is_param=True)
    if vector or isinstance(default, (list, tuple, np.ndarray)):
        meta["vector"] = True
        value = tuple(float(v) for v in np.ravel(default))
        return field(default=value, metadata=meta)
    return field(default=default, metadata=meta)


# Physical ceilings by unit, applied to every finite value of a field that declares no ``high``.
# chosen: generous limits for a hand-sized robot, so that unit mistakes and absurd inputs (1e30 kg m^2,
# a 10 km pulley) are rejected while every studied value passes (the largest defaults are ~1e-2 kg m^2,
# 0.4 m, 250 N, 1e3 Nm/rad, 10 s, 1e3 Hz, 1e11 Pa).  A field with ``finite=False`` may still be infinite
# (e.g. "no torque limit").
UNIT_CEILINGS: dict[str, float] = {
    "kg": 100.0, "kg m^2": 1.0, "m": 10.0, "N": 1e5, "Nm": 1e4, "Nm s/rad": 1e4, "N m s/rad": 1e4,
    "s": 1e5, "Hz": 1e7, "rad/s": 1e7, "m/s": 1e3, "Pa": 1e13, "N/m": 1e12,
}


def _kind(f) -> str:
    """'bool', 'int', 'str' or 'float' from a dataclass field's annotation."""
    t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
    t = t.replace(" ", "")
    return t if t in ("bool", "int", "str") else "float"


def _check_scalar(cls_name: str, name: str, v: Any, m: Mapping[str, Any], where: str = "",
                  kind: str = "float") -> None:
    label = f"{cls_name}.{name}{where}"
    kind = "float" if m.get("vector") else kind
    if kind == "str":
        if not isinstance(v, str) or (m.get("choices") and v not in m["choices"]):
            raise ValueError(f"{label} = {v!r} must be one of {', '.join(map(repr, m.get('choices') or ()))}")
        return
    if kind == "bool":
        if not isinstance(v, (bool, np.bool_)):
            raise ValueError(f"{label} = {v!r} must be True or False")
        return
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.floating, np.integer)):
        raise ValueError(f"{label} = {v!r} is not a number [{m['unit']}]")
    if kind == "int" and float(v) != int(v):
        raise ValueError(f"{label} = {v!r} must be a whole number")
    v = float(v)
    if m["finite"] and not math.isfinite(v):
        raise ValueError(f"{label} = {v!r} is not finite [{m['unit']}]")
    lo, hi = m["low"], m["high"]
    if lo is not None and (v < lo or (v == lo and not m["low_inclusive"])):
        op = ">=" if m["low_inclusive"] else ">"
        raise ValueError(f"{label} = {v!r} is out of range: must be {op} {lo} [{m['unit']}]")
    if hi is not None and (v > hi or (v == hi and not m["high_inclusive"])):
        op = "<=" if m["high_inclusive"] else "<"
        raise ValueError(f"{label} = {v!r} is out of range: must be {op} {hi} [{m['unit']}]")
    ceiling = UNIT_CEILINGS.get(m["unit"]) if hi is None else None
    if ceiling is not None and math.isfinite(v) and abs(v) > ceiling:
        raise ValueError(f"{label} = {v!r} is implausible: |value| must be <= {ceiling:g} [{m['unit']}] "
                         f"(physical ceiling of the unit; check the unit)")


@dataclass(frozen=True)
class Parameters:
    """Base class: validated, immutable, self-documenting parameter sets.

    Subclasses may override :meth:`_validate` for cross-field checks (call
    ``super()._validate()`` first).  Nested :class:`Parameters` fields are
    validated by their own constructors.
    """

    def __post_init__(self) -> None:
        for f in fields(self):
            m = f.metadata
            if not m.get("is_param"):
                expected = _nested_type(type(self), f.name)
                if expected is not None and not isinstance(getattr(self, f.name), expected):
                    v = getattr(self, f.name)
                    raise ValueError(f"{type(self).__name__}.{f.name} = {v!r} must be a "
                                     f"{' or '.join(t.__name__ for t in expected)} (a nested parameter set), "
                                     f"got {type(v).__name__}")
                continue
            v = getattr(self, f.name)
            if m.get("vector"):
                if isinstance(v, (list, np.ndarray)):
                    v = tuple(float(x) for x in np.ravel(v))
                    object.__setattr__(self, f.name, v)
                if not isinstance(v, tuple):
                    raise ValueError(
                        f"{type(self).__name__}.{f.name} = {v!r} must be a sequence of numbers [{m['unit']}]")
                for i, x in enumerate(v):
                    _check_scalar(type(self).__name__, f.name, x, m, where=f"[{i}]")
            else:
                _check_scalar(type(self).__name__, f.name, v, m, kind=_kind(f))
        self._validate()

    def _validate(self) -> None:  # pragma: no cover - hook
        """Cross-field checks; raise ValueError naming the field(s)."""

    # ------------------------------------------------------------------
    @classmethod
    def info(cls) -> dict[str, ParameterInfo]:
        """Metadata of every declared parameter, by field name."""
        out = {}
        for f in fields(cls):
            m = f.metadata
            if m.get("is_param"):
                out[f.name] = ParameterInfo(f.name, m["unit"], m["source"], m["low"], m["high"],
                                            m["low_inclusive"], m["high_inclusive"], m["doc"])
        return out

    def replace(self, **changes: Any) -> "Parameters":
        """A validated copy with some fields changed (unknown names raise)."""
        names = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise ValueError(
                f"{type(self).__name__} has no parameter {unknown[0]!r}; known: {', '.join(sorted(names))}")
        return dataclasses.replace(self, **changes)

    def with_overrides(self, overrides: Mapping[str, str | float]) -> "Parameters":
        """Apply ``NAME=VALUE`` overrides, searching nested parameter sets.

        A name may be a field of this set or of a nested set (e.g. the
        ``motor`` of a rig); dotted paths (``motor.inertia``) are accepted too.
        String values are parsed as floats, or comma-separated float lists for
        vector fields.  Unknown names and malformed values raise ValueError.
        """
        if not isinstance(overrides, Mapping):
            raise ValueError(f"{type(self).__name__}.with_overrides: expected a mapping NAME -> VALUE "
                             f"(e.g. {{'pretension': 40}}), got {type(overrides).__name__}")
        result = self
        for key, raw in overrides.items():
            if not isinstance(key, str):
                raise ValueError(f"{type(self).__name__}.with_overrides: parameter names are text, got {key!r}")
            result = result._override_one(key, raw)
        return result

    def _override_one(self, key: str, raw: Any) -> "Parameters":
        path = self._find_path(key)
        if path is None:
            raise ValueError(f"unknown parameter {key!r} for {type(self).__name__}; "
                             f"known: {', '.join(sorted(self.all_names()))}")
        return self._set_path(path, raw)

    def _set_path(self, path: list[str], raw: Any) -> "Parameters":
        head = path[0]
        if len(path) > 1:
            child = getattr(self, head)
            return dataclasses.replace(self, **{head: child._set_path(path[1:], raw)})
        f = next(f for f in fields(self) if f.name == head)
        value = _parse_value(type(self).__name__, head, raw, vector=bool(f.metadata.get("vector")),
                             current=getattr(self, head))
        return dataclasses.replace(self, **{head: value})

    def _find_path(self, key: str) -> list[str] | None:
        if "." in key:
            head, rest = key.split(".", 1)
            child = getattr(self, head, None) if head in {f.name for f in fields(self)} else None
            if isinstance(child, Parameters):
                sub = child._find_path(rest)
                return None if sub is None else [head] + sub
            return None
        for f in fields(self):
            if f.name == key and f.metadata.get("is_param"):
                return [key]
        found = []
        for f in fields(self):
            child = getattr(self, f.name)
            if isinstance(child, Parameters):
                sub = child._find_path(key)
                if sub is not None:
                    found.append([f.name] + sub)
        if len(found) > 1:
            raise ValueError(f"parameter name {key!r} is ambiguous in {type(self).__name__}: use one of "
                             + ", ".join(".".join(p) for p in found))
        return found[0] if found else None

    def all_names(self, prefix: str = "") -> list[str]:
        """Every settable parameter name (nested ones dotted)."""
        names = []
        for f in fields(self):
            child = getattr(self, f.name)
            if isinstance(child, Parameters):
                names += child.all_names(prefix + f.name + ".")
            elif f.metadata.get("is_param"):
                names.append(prefix + f.name)
        return names

    def provenance(self, prefix: str = "") -> list[dict[str, Any]]:
        """Rows ``{name, value, unit, range, source, doc}`` for this set and nested sets."""
        rows = []
        for f in fields(self):
            child = getattr(self, f.name)
            if isinstance(child, Parameters):
                rows += child.provenance(prefix + f.name + ".")
            elif f.metadata.get("is_param"):
                info = type(self).info()[f.name]
                rows.append(dict(name=prefix + f.name, value=child, unit=info.unit,
                                 range=info.range_text(), source=info.source, doc=info.doc))
        return rows


_NESTED_TYPES: dict = {}


def _nested_type(cls, name: str):
    """The Parameters class(es) a non-``param`` field holds, from its annotation, or None.

    An annotation that does not resolve falls back to :class:`Parameters` when the
    default is a parameter set.
    """
    key = (cls, name)
    if key not in _NESTED_TYPES:
        import typing

        f = next(f for f in fields(cls) if f.name == name)
        try:
            hint = typing.get_type_hints(cls).get(name)
        except Exception:  # noqa: BLE001 - unresolvable annotation: fall back to the default's kind
            hint = None
        options = typing.get_args(hint) if typing.get_args(hint) else (hint,)
        classes = tuple(t for t in options if isinstance(t, type) and issubclass(t, Parameters))
        if not classes and f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
            fac = f.default_factory  # type: ignore[misc]
            if (isinstance(fac, type) and issubclass(fac, Parameters)):
                classes = (Parameters,)
        _NESTED_TYPES[key] = classes or None
    return _NESTED_TYPES[key]


def _parse_value(cls_name: str, name: str, raw: Any, *, vector: bool, current: Any) -> Any:
    if not isinstance(raw, str):
        return tuple(raw) if vector else raw
    text = raw.strip()
    if isinstance(current, str):
        return text
    try:
        if vector:
            return tuple(float(t) for t in text.split(",") if t.strip() != "")
        if isinstance(current, bool):
            low = text.lower()
            if low in ("1", "true", "yes", "on"):
                return True
            if low in ("0", "false", "no", "off"):
                return False
            raise ValueError
        if isinstance(current, int) and not isinstance(current, bool):
            value = float(text)
            if value != int(value):
                raise ValueError
            return int(value)
        return float(text)
    except ValueError:
        kind = "a comma-separated list of numbers" if vector else type(current).__name__
        raise ValueError(f"{cls_name}.{name}: cannot parse {raw!r} as {kind}") from None


def provenance_table(params: Parameters) -> str:
    """Markdown table of a parameter set: name, value, unit, range, source."""
    lines = ["| parameter | value | unit | range | source |", "|---|---|---|---|---|"]
    for r in params.provenance():
        lines.append(f"| `{r['name']}` | {r['value']} | {r['unit']} | {r['range']} | {r['source']} |")
    return "\n".join(lines)
