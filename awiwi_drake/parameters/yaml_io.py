"""Parameter sets as YAML, through Drake's ``yaml_load_typed`` / ``yaml_dump_typed``.

Each :class:`~awiwi_drake.parameters.base.Parameters` class gets a mirror *schema* dataclass for Drake's
typed YAML (vectors as ``list[float]``, nested sets as their schemas, ``A | B`` unions as tagged unions,
e.g. ``finger: !ThumbParams {...}``, named overrides such as ``tendon_motors`` as a mapping ``{name: P}``
of whole sets).  Loading goes YAML -> schema (Drake rejects unknown keys and wrong types) -> the frozen
parameter set (units, ranges, ceilings); fields the YAML leaves out keep the values of ``defaults``.

>>> from awiwi_drake.parameters import JointRigParams
>>> text = to_yaml(JointRigParams().replace(pretension=40.0))
>>> from_yaml(JointRigParams, text).pretension
40.0
"""

from __future__ import annotations

import dataclasses
import pathlib
import types
import typing
from typing import Union

from .base import Parameters

__all__ = ["yaml_schema", "to_yaml", "from_yaml", "save_yaml", "load_yaml", "named_overrides_class"]

_SCHEMAS: dict[type, type] = {}
_BACK: dict[type, type] = {}


def _with_subclasses(cls: type) -> list[type]:
    out = [cls]
    for sub in cls.__subclasses__():
        out += [c for c in _with_subclasses(sub) if c not in out]
    return out


def _schema_type(hint, where: str):
    """The schema type of a field: a nested class with subclasses becomes a tagged union of all of them."""
    if isinstance(hint, type) and issubclass(hint, Parameters):
        options = [yaml_schema(c) for c in _with_subclasses(hint)]
        return options[0] if len(options) == 1 else Union[tuple(options)]  # type: ignore[valid-type]
    if hint in (float, int, bool, str):
        return hint
    pair = named_overrides_class(hint)
    if pair is not None:        # tuple[tuple[str, P], ...]: per-name overrides, a mapping {name: P}
        return dict[str, _schema_type(pair, where)]
    if hint is tuple or typing.get_origin(hint) is tuple:
        return list[float]
    args = typing.get_args(hint)
    if args and typing.get_origin(hint) in (Union, types.UnionType):
        options = []
        for a in args:
            m = _schema_type(a, where) if a is not type(None) else type(None)
            for o in (typing.get_args(m) or (m,)):
                if o not in options:
                    options.append(o)
        return Union[tuple(options)]  # type: ignore[valid-type]
    raise TypeError(f"{where}: the field type {hint!r} has no YAML form")


def named_overrides_class(hint):
    """``P`` when ``hint`` is ``tuple[tuple[str, P], ...]`` (named overrides, e.g. ``tendon_springs``), else None."""
    args = typing.get_args(hint) if typing.get_origin(hint) is tuple else ()
    if len(args) == 2 and args[1] is Ellipsis and typing.get_origin(args[0]) is tuple:
        inner = typing.get_args(args[0])
        if len(inner) == 2 and inner[0] is str and isinstance(inner[1], type) and issubclass(inner[1], Parameters):
            return inner[1]
    return None


def yaml_schema(cls: type) -> type:
    """The plain dataclass that Drake's typed YAML uses for parameter class ``cls``."""
    if cls not in _SCHEMAS:
        if not (isinstance(cls, type) and issubclass(cls, Parameters)):
            raise ValueError(f"yaml_schema: {cls!r} is not a Parameters class")
        hints = typing.get_type_hints(cls)
        specs = []
        for f in dataclasses.fields(cls):
            t = _schema_type(hints[f.name], f"{cls.__name__}.{f.name}")
            # a nested set starts as its (empty) schema, so a new named-override entry can merge into it
            nested = dataclasses.field(default_factory=t) if dataclasses.is_dataclass(t) else dataclasses.field(
                default=None)
            specs.append((f.name, t, nested))
        schema = dataclasses.make_dataclass(cls.__name__, specs)
        schema.__module__ = __name__
        _SCHEMAS[cls] = schema
        _BACK[schema] = cls
    return _SCHEMAS[cls]


def _to_schema(params: Parameters):
    schema = yaml_schema(type(params))
    hints = typing.get_type_hints(type(params))
    values = {}
    for f in dataclasses.fields(params):
        v = getattr(params, f.name)
        if isinstance(v, Parameters):
            v = _to_schema(v)
        elif named_overrides_class(hints[f.name]) is not None:
            v = {str(k): _to_schema(x) for k, x in v}      # named overrides
        elif isinstance(v, tuple):
            v = [float(x) for x in v]
        values[f.name] = v
    return schema(**values)


def _from_schema(obj, fill: bool = False) -> Parameters:
    """The parameter set of a schema object; ``fill``: fields the YAML left out take the class defaults (a
    named override entry, e.g. ``tendon_motors: {index_h5: {coulomb_torque: 0.1}}``, is a whole set)."""
    cls = _BACK[type(obj)]
    values = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if v is None and fill:
            continue
        if type(v) in _BACK:
            v = _from_schema(v, fill)
        elif isinstance(v, dict):
            v = tuple((k, _named_entry(f.name, k, x)) for k, x in v.items())
        elif isinstance(v, list):
            v = tuple(v)
        values[f.name] = v
    return cls(**values)


def _named_entry(field: str, key: str, obj) -> Parameters:
    """One named override entry; an invalid value names its entry (``tendon_motors['index_h3']: ...``)."""
    try:
        return _from_schema(obj, True)
    except ValueError as exc:
        raise ValueError(f"{field}[{key!r}]: {exc}") from None


def to_yaml(params: Parameters) -> str:
    """The parameter set as YAML text (Drake's ``yaml_dump_typed``): every field, nested sets included."""
    from pydrake.common.yaml import yaml_dump_typed

    if not isinstance(params, Parameters):
        raise ValueError(f"to_yaml: expected a parameter set, got {type(params).__name__}")
    return yaml_dump_typed(_to_schema(params))


def from_yaml(cls_or_defaults, text: str, *, where: str = "YAML") -> Parameters:
    """Parse YAML ``text`` into a parameter set (Drake's ``yaml_load_typed``).

    ``cls_or_defaults`` is a Parameters class (defaults: its defaults) or an
    instance whose values fill the fields the YAML leaves out.  Unknown keys,
    wrong types and out-of-range values raise a ``ValueError`` that starts
    with ``where`` (e.g. the file name).
    """
    from pydrake.common.yaml import yaml_load_typed

    defaults = cls_or_defaults() if isinstance(cls_or_defaults, type) else cls_or_defaults
    if not isinstance(defaults, Parameters):
        raise ValueError(f"from_yaml: expected a Parameters class or instance, got {cls_or_defaults!r}")
    if not isinstance(text, str):
        raise ValueError(f"{where}: expected YAML text, got {type(text).__name__}")
    if not text.strip():
        return defaults
    try:
        obj = yaml_load_typed(schema=type(_to_schema(defaults)), data=text, defaults=_to_schema(defaults))
    except Exception as exc:  # noqa: BLE001 - yaml.YAMLError, Drake's errors: name the source
        msg = " ".join(str(exc).split())
        found = _unknown_key_message(text, type(defaults)) if "unknown to the schema" in msg else None
        if found:      # Drake names the key, not where it is: its path
            raise ValueError(f"{where}: {found}") from None
        if "field" not in msg and not msg.startswith(("while ", "mapping ", "expected ")):
            msg = f"a value does not fit {type(defaults).__name__} ({type(exc).__name__}: {msg})"
        raise ValueError(f"{where}: {msg}") from None
    try:
        return _from_schema(obj)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def _unknown_key_message(text: str, cls: type):
    """``unknown key 'a.b.c' (known there: ...)`` for the first key of ``text`` that ``cls`` has no field for (its
    dotted path through nested sets, named-override entries and tagged unions), or None."""
    import yaml

    class _Loader(yaml.SafeLoader):
        pass
    _Loader.add_multi_constructor("!", lambda loader, tag, node: (
        {"__tag__": tag, **loader.construct_mapping(node, deep=True)} if isinstance(node, yaml.MappingNode) else None))
    try:
        data = yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader that reads tags as plain mappings
    except yaml.YAMLError:
        return None

    def walk(obj, c, path):
        if not isinstance(obj, dict):
            return None
        options = [a for a in (typing.get_args(c) or (c,)) if isinstance(a, type) and issubclass(a, Parameters)]
        if not options:
            return None
        tag = obj.pop("__tag__", None)
        c = next((k for o in options for k in _with_subclasses(o) if k.__name__ == tag), options[0])
        hints = typing.get_type_hints(c)
        names = [f.name for f in dataclasses.fields(c)]
        for key, val in obj.items():
            if key not in names:
                return f"unknown key '{path}{key}' (known there: {', '.join(names)})"
            pair = named_overrides_class(hints[key])
            if pair is not None and isinstance(val, dict):
                for name, entry in val.items():
                    found = walk(entry, pair, f"{path}{key}.{name}.")
                    if found:
                        return found
            else:
                found = walk(val, hints[key], f"{path}{key}.")
                if found:
                    return found
        return None
    return walk(data, cls, "")


def save_yaml(params: Parameters, path) -> pathlib.Path:
    """Write ``params`` as YAML to ``path`` (folders created); returns the path."""
    p = pathlib.Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(to_yaml(params), encoding="utf-8")
    return p


def load_yaml(cls_or_defaults, path) -> Parameters:
    """Read a parameter set from the YAML file ``path`` (see :func:`from_yaml`); errors name the file."""
    p = pathlib.Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    if p.is_dir():
        raise ValueError(f"{p}: is a directory, not a YAML file")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{p}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    return from_yaml(cls_or_defaults, text, where=str(p))
