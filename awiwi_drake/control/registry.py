"""Controller registry: ``name -> factory(rig) -> controller system``.

Built-in controllers are registered by the modules listed in
``PROVIDER_MODULES`` (imported lazily on first use, so that registering never
imports Drake-heavy modules at package import).  Other parts of the package
(and users) add controllers with :func:`register_controller`.

Rigs have one name each, the same in the API (``Rig.name``), the CLI and errors:
``tendon-rig``, ``flexible-joint``, ``joint-rig``, ``finger-index`` ... ``finger-thumb`` and
``hand``. Controllers are registered for rig kinds, which are these names except that the
five fingers share the kind ``"finger"``; :func:`rig_kind` maps a rig (or its name) to its kind.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from awiwi_drake.parameters.hand import FINGERS

__all__ = ["ControllerEntry", "register_controller", "make_controller", "controller_names",
           "get_entry", "rig_kind", "split_name", "VARIANTS", "RIG_KINDS", "RIG_NAMES", "PROVIDER_MODULES"]

#: ``<name>:<variant>`` builds the registered ``name`` with these factory options (e.g. on the CLI,
#: ``compare --controllers cascaded,cascaded:no-observer``: the chain without its default ch. 9 observer)
VARIANTS = {"no-observer": {"friction_observer": None}}

RIG_KINDS = ("tendon-rig", "flexible-joint", "joint-rig", "finger", "hand")
RIG_NAMES = ("tendon-rig", "flexible-joint", "joint-rig", *(f"finger-{f}" for f in FINGERS), "hand")
# Modules whose import registers controllers (append yours).
PROVIDER_MODULES = ["awiwi_drake.control.catalog"]


@dataclass(frozen=True)
class ControllerEntry:
    """One registered controller.

    ``factory(rig)`` returns the controller system; ``loop_options`` are the
    keyword defaults for :func:`awiwi_drake.control.base.closed_loop`
    (e.g. ``{"rate_hz": 3000.0}``).
    """

    name: str
    factory: Callable[[Any], Any]
    rigs: tuple[str, ...]
    description: str
    loop_options: Mapping[str, Any] = field(default_factory=dict)


# name -> entries; one name may have one entry per rig kind (e.g. ``cascaded`` on the joint rig
# is (11.16), on a finger/hand the ch. 7-10 chain): the same concept, built for that plant.
_REGISTRY: dict[str, list[ControllerEntry]] = {}
_loaded = False


def _ensure_loaded() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for mod in PROVIDER_MODULES:
        importlib.import_module(mod)


def rig_kind(rig: Any) -> str:
    """The kind of a rig object or rig name (``tendon-rig``, ``flexible-joint``, ``joint-rig``, ``finger``, ``hand``)."""
    name = rig if isinstance(rig, str) else getattr(rig, "name", None)
    if not isinstance(name, str):
        raise ValueError(f"cannot tell the rig kind of {rig!r}: it has no name")
    if name in RIG_KINDS:
        return name
    if name in RIG_NAMES:
        return "finger"
    raise ValueError(f"unknown rig {name!r}; known rigs: {', '.join(RIG_NAMES)} (kinds: {', '.join(RIG_KINDS)})")


def register_controller(name: str, factory: Callable[[Any], Any], *, rigs: tuple[str, ...] | list[str],
                        description: str, loop_options: Mapping[str, Any] | None = None,
                        replace: bool = False) -> ControllerEntry:
    """Register a controller factory under ``name`` for the given rig kinds.

    A name already registered for *other* rig kinds gets this factory for these kinds
    (the same controller built for another plant); registering a kind twice needs ``replace``.
    """
    if not name or name != name.strip():
        raise ValueError(f"register_controller: bad controller name {name!r}")
    kinds = tuple(rig_kind(r) for r in rigs)
    if not kinds:
        raise ValueError(f"register_controller: controller {name!r} needs at least one rig kind")
    entries = _REGISTRY.get(name, [])
    clash = [e for e in entries if set(e.rigs) & set(kinds)]
    if clash and not replace:
        raise ValueError(f"register_controller: controller {name!r} is already registered for "
                         f"{', '.join(sorted(set(clash[0].rigs) & set(kinds)))}")
    entries = [e for e in entries if not set(e.rigs) & set(kinds)]
    entry = ControllerEntry(name, factory, kinds, description, dict(loop_options or {}))
    _REGISTRY[name] = entries + [entry]
    return entry


def _kinds(name: str) -> tuple[str, ...]:
    return tuple(k for e in _REGISTRY[name] for k in e.rigs)


def controller_names(rig: Any | None = None) -> list[str]:
    """Registered names (only those fitting ``rig`` when given)."""
    _ensure_loaded()
    if rig is None:
        return sorted(_REGISTRY)
    kind = rig_kind(rig)
    return sorted(n for n in _REGISTRY if kind in _kinds(n))


def split_name(name: str) -> tuple[str, dict]:
    """``(registered name, factory options)`` of ``name`` or ``name:variant`` (:data:`VARIANTS`)."""
    base, sep, variant = name.partition(":")
    if not sep:
        return name, {}
    if variant not in VARIANTS:
        raise ValueError(f"controller {name!r}: unknown variant {variant!r}; variants: {', '.join(VARIANTS)}")
    return base, dict(VARIANTS[variant])


def get_entry(name: str, rig: Any | None = None) -> ControllerEntry:
    """The entry of ``name`` (for ``rig``'s kind when given; a ``name:variant`` gives its name's entry); ValueError
    when unknown or not fitting ``rig``.

    Without ``rig`` the first registration is returned.
    """
    _ensure_loaded()
    name = split_name(name)[0]
    if name not in _REGISTRY:
        raise ValueError(f"unknown controller {name!r}; known: {', '.join(sorted(_REGISTRY))}")
    entries = _REGISTRY[name]
    if rig is None:
        return entries[0]
    kind = rig_kind(rig)
    for e in entries:
        if kind in e.rigs:
            return e
    fits = controller_names(rig)
    raise ValueError(f"controller {name!r} does not fit rig {kind!r} (it is for "
                     f"{', '.join(_kinds(name))}); controllers for {kind!r}: {', '.join(fits)}")


def make_controller(name: str, rig: Any, **options: Any):
    """Build controller ``name`` (or ``name:variant``, :data:`VARIANTS`) for ``rig`` (ValueError when unknown or
    unfit); ``options`` go to its factory (e.g. ``friction_observer=None`` turns the chain controllers' ch. 9
    observer off on a finger/the hand, as ``name:no-observer`` does)."""
    base, implied = split_name(name)
    entry = get_entry(base, rig)
    options = {**implied, **options}
    if not options:
        return entry.factory(rig)
    try:
        return entry.factory(rig, **options)
    except TypeError as exc:
        # only a keyword the user gave is "no option"; any other TypeError (one inside the factory) is re-raised
        bad = str(exc).split()[-1].strip("'\"") if "unexpected keyword argument" in str(exc) else None
        if bad not in options:
            raise
        raise ValueError(f"controller {name!r} on {rig_kind(rig)!r} has no option {bad!r} "
                         f"(given: {', '.join(sorted(options))})") from None
