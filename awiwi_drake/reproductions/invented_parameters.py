"""The hand's invented parameters and how much each reproduced figure depends on them.

The thesis prints the kinematics (Table 5.1, 5.2, 6.1, 6.2), the motor (Table 3.3) and the
controllers' rigs (Tables 12.1-16.1), but not the pulley radii, link masses, the bone lengths of
the ring, fifth and thumb, the thumb metacarpal, the wrist's linkage lengths, the spring
mechanism's geometry or the tendon's modulus and section.  The package chooses them
(``awiwi_drake/parameters/``, each with its reason).  :func:`invented_parameter_sensitivity`
varies each of them by -20 % and +20 %, one at a time, and recomputes the headline number of every
reproduced figure that uses it (:data:`HEADLINES`: name, unit, function).  The lever force of Fig 4.8b
holds the spring constant fitted to 175 N at 48 deg, so a geometry change shows as a shape change; Fig 5.7's
difference is taken over 0.05 s instead of 0.2 s to keep the study cheap (``fig57=False`` skips it).

The wrist's linkage lengths are not parameters but are derived from Table 6.1 by the box
construction (:mod:`awiwi_drake.hand.wrist`); they are varied by overriding the derived property.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from awiwi_drake.components.spring import LeverSpringMechanism, tendon_spring
from awiwi_drake.parameters.hand import FingerRigParams, ThumbParams, finger_params
from awiwi_drake.parameters.rigs import SpringModelParams
from awiwi_drake.parameters.wrist import WristParams

__all__ = ["HEADLINES", "INVENTED", "InventedParameter", "SensitivityRow", "headline_values",
           "invented_parameter_sensitivity", "sensitivity_markdown", "fig_6_10_length_scale"]


@dataclass(frozen=True)
class InventedParameter:
    """One chosen parameter: where it lives and which headlines use it."""

    name: str               # "group.field", e.g. "index.pip_radius", "spring.lever_length"
    unit: str
    headlines: tuple        # headline keys that depend on it


_INDEX = ("index_link_mode_20N", "fig5_7_dip_difference")
_TENDON = ("tendon_stiffness_20N", "index_link_mode_20N")

#: The chosen parameters, in the order of the docs/REPRODUCTIONS.md table: (group, fields, unit, headlines) rows.
INVENTED = tuple(InventedParameter(f"{group}.{name}", unit, headlines) for group, names, unit, headlines in (
    ("index", ("abduction_radius", "mcp_radius", "pip_radius", "dip_radius"), "m", _INDEX),
    ("index", ("proximal_mass", "middle_mass", "distal_mass"), "kg", _INDEX),
    ("index", ("link_radius",), "m", _INDEX),
    ("ring", ("pip_radius", "dip_radius"), "m", ("ring_pip_moment_arm",)),
    ("ring", ("coupling_stiffness",), "N m/rad", ("ring_coupling_compliance",)),
    ("thumb", ("metacarpal_length",), "m", ("thumb_base_stiffness", "fig5_17_cold_error")),
    ("thumb", ("pip_radius", "dip_radius", "proximal_length", "distal_length"), "m", ()),
    ("ring", ("proximal_length",), "m", ()),
    ("fifth", ("proximal_length", "middle_length", "hmc_radius", "hmc_offset"), "m", ()),
    ("fifth", ("hmc_axis_tilt",), "rad", ()),
    ("spring", ("pulley_spacing", "lever_length", "spring_arm"), "m", ("fig4_8b_force_45deg", *_TENDON)),
    ("tendon", ("youngs_modulus",), "Pa", _TENDON),
    ("tendon", ("diameter", "rest_length"), "m", _TENDON),
    ("wrist", ("crank_length", "coupler_length", "palm_radius", "link_length"), "m", ("fig6_10_abduction_peak",)),
) for name in names)


def _scaled_wrist(prop: str, scale: float) -> WristParams:
    """WristParams whose derived linkage length ``prop`` is ``scale`` times the box construction's."""
    nominal = getattr(WristParams(), prop)
    cls = dataclass(frozen=True)(type("ScaledWristParams", (WristParams,),
                                      {prop: property(lambda self, v=nominal * scale: v)}))
    return cls()


def fig_6_10_length_scale(prop: str, scale: float) -> float:
    """Fig 6.10 abduction peak with one derived wrist length scaled, relative to the nominal peak
    (nan when the wrist cannot reach the motion with that length)."""
    from awiwi_drake.reproductions.ch06_wrist import wrist_motion_study
    base = wrist_motion_study(num_samples=61).abduction_peak
    try:
        return wrist_motion_study(num_samples=61, params=_scaled_wrist(prop, scale)).abduction_peak / base
    except ValueError:
        return math.nan


# ---------------------------------------------------------------------------
# headline numbers (each takes the full set of (possibly scaled) inputs)
@dataclass(frozen=True)
class _Inputs:
    index: object
    ring: object
    thumb: ThumbParams
    spring: SpringModelParams
    wrist: WristParams
    fifth: object = None


def _index_rig_params(x: _Inputs) -> FingerRigParams:
    return FingerRigParams.for_finger("index").replace(finger=x.index, spring=x.spring)


def _fig4_8b(x: _Inputs) -> float:
    return float(LeverSpringMechanism(x.spring.geometry).force_at_angle(math.radians(45.0)))


def _tendon_stiffness(x: _Inputs) -> float:
    s = tendon_spring(x.spring)
    return float(s.stiffness(s.inverse_force(20.0)))


def _index_mode(x: _Inputs) -> float:
    from awiwi_drake.analysis import linearize
    from awiwi_drake.hand import finger_diagram
    rig = finger_diagram(finger="index", params=_index_rig_params(x))
    return float(np.max(np.abs(linearize(rig, rig.operating_point(pretension=20.0)).poles.imag)))


def _fig5_7(x: _Inputs) -> float:
    from awiwi_drake.reproductions.ch05_fingers import coriolis_study
    r = coriolis_study("index", deflection=0.1, t_final=0.05, num_samples=51, params=_index_rig_params(x))
    return float(r.max_abs_difference[-1])


def _ring_arm(x: _Inputs) -> float:
    return float(x.ring.pip_radius + x.ring.dip_radius ** 2 / x.ring.pip_radius)


def _ring_compliance(x: _Inputs) -> float:
    from awiwi_drake.hand import finger_diagram
    from awiwi_drake.hand.plant import coupling_compliance
    rig = finger_diagram(finger="ring", params=FingerRigParams.for_finger("ring").replace(finger=x.ring,
                                                                                          spring=x.spring))
    op = rig.operating_point(pretension=20.0)
    return float(coupling_compliance(op.joint_stiffness, rig.models.coupling_vector))


def _fig6_10(x: _Inputs) -> float:
    from awiwi_drake.reproductions.ch06_wrist import wrist_motion_study
    return float(wrist_motion_study(num_samples=61, params=x.wrist).abduction_peak)


def _thumb_stiffness(x: _Inputs) -> float:
    from awiwi_drake.hand.coupling import ThumbCoupling, joint_stiffness
    c = ThumbCoupling(x.thumb)
    s = tendon_spring(x.spring)
    f = np.full(8, 20.0)
    k = np.asarray(s.stiffness(np.asarray(s.inverse_force(f), dtype=float)), dtype=float)
    return float(np.linalg.eigvalsh(joint_stiffness(c, np.array([0.5, 0.3, 0.0, 0.0]), f, k)[:2, :2]).min())


def _fig5_17(x: _Inputs) -> float:
    from awiwi_drake.hand.coupling import ThumbCoupling
    from awiwi_drake.reproductions.ch05_fingers import thumb_estimation_study
    e = thumb_estimation_study(ThumbCoupling(x.thumb), iterations=(30,), noise=(0.0,), starts=("cold",))
    return float(np.max(e.errors[(30, 0.0, "cold")]))


HEADLINES: dict[str, tuple[str, str, Callable]] = {
    "fig4_8b_force_45deg": ("Fig 4.8b: lever force at 45 deg", "N", _fig4_8b),
    "tendon_stiffness_20N": ("ch. 4: mechanism + tendon stiffness at 20 N", "N/m", _tendon_stiffness),
    "index_link_mode_20N": ("poles vs pretension: index stiffest link mode, 20 N", "rad/s", _index_mode),
    "fig5_7_dip_difference": ("Fig 5.7: DIP Coriolis difference, 0.1 rad, 0.05 s", "rad", _fig5_7),
    "ring_pip_moment_arm": ("(5.16)-(5.18): ring reduced PIP moment arm", "m", _ring_arm),
    "ring_coupling_compliance": ("coupling hold: ring DIP-torque compliance of the coupling", "rad/N m",
                                 _ring_compliance),
    "fig6_10_abduction_peak": ("Fig 6.10: largest displacement at 20 deg abduction", "m", _fig6_10),
    "thumb_base_stiffness": ("(5.12): thumb base lambda_min at (0.5, 0.3), 20 N", "N m/rad", _thumb_stiffness),
    "fig5_17_cold_error": ("Fig 5.17: thumb cold-start max error, 30 it., no noise", "rad", _fig5_17),
}


def _nominal() -> _Inputs:
    return _Inputs(finger_params("index"), finger_params("ring"), ThumbParams(), SpringModelParams(), WristParams(),
                   finger_params("fifth"))


def _holder(x: _Inputs, group: str):
    """The parameter set of ``x`` that holds the fields of ``group`` (None: the wrist's derived lengths)."""
    return {"wrist": None, "spring": x.spring.geometry, "tendon": x.spring.tendon}.get(group, getattr(x, group, None))


def _value(p: InventedParameter) -> float:
    group, field = p.name.split(".")
    x = _nominal()
    return float(getattr(x.wrist if group == "wrist" else _holder(x, group), field))


def _source(p: InventedParameter) -> str:
    group, field = p.name.split(".")
    obj = _holder(_nominal(), group)
    if obj is None:
        return "derived from Table 6.1 by the box construction (hand/wrist.py module docstring)"
    return obj.info()[field].source


def _scaled(p: InventedParameter, scale: float) -> _Inputs:
    group, field = p.name.split(".")
    x = _nominal()
    if group == "wrist":
        return dataclasses.replace(x, wrist=_scaled_wrist(field, scale))
    changed = _holder(x, group).replace(**{field: _value(p) * scale})
    if group in ("spring", "tendon"):
        return dataclasses.replace(x, spring=x.spring.replace(**{"geometry" if group == "spring" else "tendon": changed}))
    return dataclasses.replace(x, **{group: changed})


def headline_values(inputs: _Inputs | None = None, keys=None) -> dict[str, float]:
    """Headline numbers at ``inputs`` (default: the package's parameters)."""
    x = inputs or _nominal()
    return {k: HEADLINES[k][2](x) for k in (keys or HEADLINES)}


@dataclass
class SensitivityRow:
    """Relative change of one headline for -20 % / +20 % of one parameter (nan: not computable)."""

    parameter: str
    value: float
    unit: str
    source: str
    headline: str
    nominal: float
    minus: float
    plus: float


def invented_parameter_sensitivity(*, scale: float = 0.2, fig57: bool = True,
                                   parameters=None, progress: Callable[[str], object] | None = None
                                   ) -> list[SensitivityRow]:
    """One-at-a-time +-``scale`` sensitivity of each headline to each invented parameter."""
    params = [p for p in INVENTED if parameters is None or p.name in parameters]
    keys = sorted({h for p in params for h in p.headlines if fig57 or h != "fig5_7_dip_difference"})
    nominal = headline_values(keys=keys)
    rows = []
    for p in params:
        if not p.headlines:
            rows.append(SensitivityRow(p.name, _value(p), p.unit, _source(p), "", math.nan, math.nan, math.nan))
        for h in p.headlines:
            if h not in keys:
                continue
            if progress:
                progress(f"{p.name} -> {h}")
            rel = []
            for s in (1.0 - scale, 1.0 + scale):
                try:
                    v = HEADLINES[h][2](_scaled(p, s))
                except ValueError:        # e.g. a wrist that cannot reach the motion
                    v = math.nan
                rel.append(v / nominal[h] - 1.0)
            rows.append(SensitivityRow(p.name, _value(p), p.unit, _source(p), h, nominal[h], rel[0], rel[1]))
    return rows


def sensitivity_markdown(rows: list[SensitivityRow], *, threshold: float = 0.05) -> str:
    """The docs/REPRODUCTIONS.md table: one line per parameter, sensitive headlines (|change| >= threshold)."""
    by_param: dict[str, list[SensitivityRow]] = {}
    for r in rows:
        by_param.setdefault(r.parameter, []).append(r)
    lines = ["| parameter | value | why chosen | headline: change at -20 % / +20 % |", "|---|---|---|---|"]
    for name, rs in by_param.items():
        r0 = rs[0]
        cells = [] if r0.headline else ["none: no reproduced figure uses it"]
        for r in (r for r in rs if r.headline):
            mark = "" if max(abs(np.nan_to_num(r.minus, nan=1.0)), abs(np.nan_to_num(r.plus, nan=1.0))) >= threshold \
                else " (insensitive)"
            fmt = lambda v: "unreachable" if not np.isfinite(v) else f"{100 * v:+.1f} %"
            cells.append(f"{HEADLINES[r.headline][0]}: {fmt(r.minus)} / {fmt(r.plus)}{mark}")
        src = r0.source if len(r0.source) <= 160 else r0.source[:157] + "..."
        src = src.replace("|", "\\|")
        lines.append(f"| `{name}` | {r0.value:.4g} {r0.unit} | {src} | " + "; ".join(cells) + " |")
    return "\n".join(lines)
