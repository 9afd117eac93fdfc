"""Finger and hand parameters (thesis ch. 5), with sources.

Index/middle bone geometry comes from Table 5.1 (read with two corrections: M32 last row ``0 0 0 1``,
M98 translation 0.0201 m rather than the printed 0.00201 m, which would make the distal phalanx 2 mm
long).  The thesis prints no pulley radii, masses or inertias per link; the values below are chosen and
say why.  The finger's links are uniform cylinders whose masses split the finger mass of section 5.2.2
(0.02 kg) in proportion to the Table 5.1 link lengths.  The link inertia 7.2e-7 kg m^2 of Tables 14.2 and
15.1 belongs to the single-joint test rig (Fig 15.14), not to a phalanx: the rigs keep it
(``parameters.rigs``).

Global tendon order (chosen: Table 6.2 numbers 38 tendons but does not say which rows belong to which
finger), used everywhere: thumb tendons 1-8, index 9-16, middle 17-24, ring 25-30, fifth 31-38; within a
finger the order of its tendon equations ((5.22) thumb, (5.5) index/middle, (5.18) ring, see
:mod:`awiwi_drake.hand.coupling` for the fifth).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

from .base import Parameters, param
from .components import GuideFrictionParams, HysteresisParams, JointFrictionParams, MotorParams, TendonGuideParams
from .rigs import SpringModelParams

__all__ = [
    "FingerParams", "IndexFingerParams", "MiddleFingerParams", "RingFingerParams",
    "FifthFingerParams", "ThumbParams", "HandParams", "FINGERS", "TENDON_SLICES",
    "finger_params", "FINGER_STRUCTURE", "check_finger_structure", "FingerDriveParams", "FingerRigParams", "HandRigParams", "JointControllerParams",
    "COMPILE_AFTER_CALLS",
]

_T51 = "Table 5.1"
_RADIUS_SRC = ("chosen: the thesis prints no pulley radii (Fig 5.8 names r20..r23); "
               "5-10 mm, of the order of the finger's link radius (link_radius, 7 mm)")
_MASS_SRC = ("chosen: finger mass 0.02 kg (section 5.2.2) less the 1 g abduction link, split in proportion "
             "to the Table 5.1 link lengths (uniform cylinders of equal radius): 0.019 kg x L_i / 90.28 mm")


@dataclass(frozen=True)
class FingerParams(Parameters):
    """A serial finger: abduction, MCP flexion, PIP, DIP (Table 5.1 structure).

    Joint ``j`` of finger ``x`` is the thesis's ``q_xj``; pulley radius
    ``r_xj`` is the moment arm of the tendons at that joint ((5.5)).
    """

    abduction_radius: float = param(0.006, unit="m", low=0.001, high=0.03, source=_RADIUS_SRC,
                                    doc="r_x0: moment arm of the base tendons about the abduction axis")
    mcp_radius: float = param(0.008, unit="m", low=0.001, high=0.03, source=_RADIUS_SRC,
                              doc="r_x1: moment arm of the base tendons about the MCP flexion axis")
    pip_radius: float = param(0.007, unit="m", low=0.001, high=0.03, source=_RADIUS_SRC,
                              doc="r_x2: PIP pulley radius")
    dip_radius: float = param(0.005, unit="m", low=0.001, high=0.03, source=_RADIUS_SRC,
                              doc="r_x3: DIP pulley radius")
    base_offset: float = param(0.006, unit="m", low=0.0, high=0.05, source=_T51 + " M32",
                               doc="abduction axis to MCP axis")
    proximal_length: float = param(0.04038, unit="m", low=0.005, high=0.1, source=_T51 + " M54")
    middle_length: float = param(0.0298, unit="m", low=0.005, high=0.1, source=_T51 + " M76 (x)")
    middle_lateral: float = param(-0.005, unit="m", low=-0.02, high=0.02, source=_T51 + " M76 (z)",
                                  doc="offset of the DIP frame along the flexion axis")
    distal_length: float = param(0.0201, unit="m", low=0.005, high=0.1,
                                 source=_T51 + " M98 (printed 0.00201; read 0.0201: a 2 mm distal phalanx)")
    distal_lateral: float = param(-0.0007, unit="m", low=-0.02, high=0.02, source=_T51 + " M98 (z)")
    link_radius: float = param(0.007, unit="m", low=0.001, high=0.02,
                               source="chosen: half the finger width (~14 mm, Fig 5.5)",
                               doc="cylinder radius for inertia and drawing")
    abduction_link_mass: float = param(0.001, unit="kg", low=0.0, high=0.1, low_inclusive=False,
                                       source=_MASS_SRC)
    proximal_mass: float = param(0.00850, unit="kg", low=0.0, high=0.1, low_inclusive=False, source=_MASS_SRC)
    middle_mass: float = param(0.00627, unit="kg", low=0.0, high=0.1, low_inclusive=False, source=_MASS_SRC)
    distal_mass: float = param(0.00423, unit="kg", low=0.0, high=0.1, low_inclusive=False, source=_MASS_SRC)
    joint_damping: float = param(
        1e-5, unit="N m s/rad", low=0.0, high=1.0,
        source=("chosen: light joint damping, of the order of the 0.1 % damping of the "
                "Fig 5.7 study (damping ratio ~1e-3 to 1e-2 with the tendon stiffness)"))
    # Ring/fifth PIP-DIP coupling (section 5.3); unused when pip_dip_coupled is False.
    pip_dip_coupled: bool = param(False, unit="-", source="section 5.3: ring and fifth only (fixed per finger: FINGER_STRUCTURE, validated)")
    coupling_stiffness: float = param(
        4.0, unit="N m/rad", low=0.0, high=1e4, low_inclusive=False,
        source=("chosen: a stiff coupling tendon, 3.1x the tendon-induced PIP stiffness of the ring at "
                "20 N pretension (2 k_t r42^2 = 1.29 N m/rad, k_t = 13.2 kN/m).  Coupling tolerance as a "
                "compliance: the DIP torque -> coupling error map c^T K_q^-1 e_DIP of the motors-held joint "
                "stiffness K_q (5.12) + k_c c c^T is 1/(k_c (1 + (r43/r42)^2)) = 0.166 rad/N m, because the "
                "PIP/DIP tendon pair acts along (r42, r43), orthogonal to c = (-r43/r42, 1) "
                "(hand.plant.coupling_compliance).  Stiffer is limited by the coupling mode sqrt(k_c/I_eff): "
                "5.9e3 rad/s (ring, I_eff = 1/(c^T M^-1 c) = 1.15e-7 kg m^2) and 6.65e3 rad/s (fifth, "
                "9.0e-8 kg m^2) at damping ratios 0.71 / 0.81, where fixed-step RK3 at the 3 kHz control period "
                "still contracts (|R(lambda h)| = 0.62 / 0.87); k_c = 6 would put the fifth at 8.1e3 rad/s, "
                "|R| = 1.6 at damping ratio 0.7: unstable"))
    coupling_damping: float = param(
        9.7e-4, unit="N m s/rad", low=0.0, high=1.0,
        source="chosen: damping ratio 0.7 of the ring's coupling mode (2 * 0.7 * sqrt(k_c I_eff) with I_eff = 1.21e-7 kg m^2 of earlier masses; 0.71 with I_eff = 1.15e-7 now)")
    # Fifth finger hematometacarpal joint (section 5.5); unused when has_hmc is False.
    has_hmc: bool = param(False, unit="-", source="section 5.5: fifth finger only (fixed per finger: FINGER_STRUCTURE, validated)")
    hmc_radius: float = param(0.008, unit="m", low=0.001, high=0.03, source=_RADIUS_SRC,
                              doc="moment arm of the two HMC tendons")
    hmc_offset: float = param(0.03, unit="m", low=0.0, high=0.1,
                              source=("chosen: the four-bar linkage (section 5.5, no dimensions) is "
                                      "replaced by a revolute joint 3 cm proximal to the abduction axis "
                                      "(axis: hmc_axis_tilt)"),
                              doc="HMC axis to abduction axis")
    hmc_axis_tilt: float = param(
        math.radians(30.0), unit="rad", low=0.0, high=math.pi / 2,
        source=("chosen: section 5.5 gives no four-bar dimensions, only the motion: 'a locking motion "
                "towards the palm center'.  The four-bar is replaced by one revolute axis perpendicular to "
                "the metacarpal (base x), tilted by this angle from the MCP flexion axis (-y) towards the "
                "palm normal (+z): hmc_axis = (0, -cos a, sin a).  Flexing the HMC then moves the finger "
                "palmar (cos a) and radially towards the palm centre (sin a); 30 deg, the obliquity of the "
                "human fifth carpometacarpal axis, is our pick"),
        doc="angle between the HMC axis and the MCP flexion axis, in the plane normal to the metacarpal")
    hmc_mass: float = param(0.005, unit="kg", low=0.0, high=0.1, low_inclusive=False,
                            source="chosen: the fifth metacarpal, a short bone of the palm")

    num_dof = property(lambda self: 4 - int(self.pip_dip_coupled) + int(self.has_hmc))

    @property
    def hmc_axis(self) -> tuple:
        """Unit HMC axis in the finger base frame (x: along the metacarpal): ``(0, -cos a, sin a)``."""
        return (0.0, -math.cos(self.hmc_axis_tilt), math.sin(self.hmc_axis_tilt))

    #: the finger whose structure (pip_dip_coupled, has_hmc) the thesis fixes (FINGER_STRUCTURE);
    #: "generic" for this base class: any structure
    FINGER: ClassVar[str] = "generic"

    def _validate(self) -> None:
        super()._validate()
        check_finger_structure(self.FINGER, self)

    @property
    def dip_pip_ratio(self) -> float:
        """(5.16): ``q_DIP = (r_x3 / r_x2) q_PIP`` for a coupled finger."""
        return self.dip_radius / self.pip_radius


@dataclass(frozen=True)
class IndexFingerParams(FingerParams):
    """Index finger: Table 5.1, (5.5)."""

    FINGER: ClassVar[str] = "index"


@dataclass(frozen=True)
class MiddleFingerParams(FingerParams):
    """Middle finger: section 5.2 models it like the index (no separate table)."""

    FINGER: ClassVar[str] = "middle"


@dataclass(frozen=True)
class RingFingerParams(FingerParams):
    """Ring finger: PIP/DIP coupled ((5.16), (5.18)), 3 DoF, 6 tendons."""

    FINGER: ClassVar[str] = "ring"

    pip_dip_coupled: bool = param(True, unit="-", source="section 5.3, (5.16)")
    proximal_length: float = param(
        0.0380, unit="m", low=0.005, high=0.1,
        source="chosen: Table 5.1 index value shortened ~6 % (ring proximal phalanx is shorter)")


@dataclass(frozen=True)
class FifthFingerParams(FingerParams):
    """Fifth finger: hematometacarpal joint + ring-like coupling, 4 DoF, 8 tendons."""

    FINGER: ClassVar[str] = "fifth"

    pip_dip_coupled: bool = param(True, unit="-", source="section 5.3, (5.17)")
    has_hmc: bool = param(True, unit="-", source="section 5.5")
    proximal_length: float = param(
        0.0320, unit="m", low=0.005, high=0.1,
        source="chosen: Table 5.1 index value scaled by ~0.8 (human fifth/index proximal phalanx)")
    middle_length: float = param(
        0.0240, unit="m", low=0.005, high=0.1,
        source="chosen: Table 5.1 index value scaled by ~0.8")


@dataclass(frozen=True)
class ThumbParams(Parameters):
    """Thumb: tensegrity base (q10 flexion, q11 abduction) + PIP (q12) + DIP (q13).

    Table 5.2 prints the same numbers for the palm points A0..D0 (frame 10)
    and the bone points A..D (frame 12); they are in different frames, and
    ``T^12_10 = Rz(q10) Ry(q11) Trans(metacarpal_length, 0, 0)`` (5.19)
    separates them.  The metacarpal length is not printed: chosen below.
    """

    palm_points: tuple = param(
        (0.002, 0.030, -0.025, 0.002, 0.030, 0.025, 0.002, -0.030, -0.025, 0.002, -0.030, 0.025),
        unit="m", low=-0.1, high=0.1, source="Table 5.2 (A0, B0, C0, D0 in frame 10)",
        doc="A0, B0, C0, D0 flattened (x, y, z each)")
    bone_points: tuple = param(
        (0.002, 0.030, -0.025, 0.002, 0.030, 0.025, 0.002, -0.030, -0.025, 0.002, -0.030, 0.025),
        unit="m", low=-0.1, high=0.1, source="Table 5.2 (A, B, C, D in frame 12)",
        doc="A, B, C, D flattened (x, y, z each)")
    metacarpal_length: float = param(
        0.045, unit="m", low=0.01, high=0.1,
        source=("chosen: not printed; 45 mm, a human thumb metacarpal length, and long "
                "enough that the base tendons (length ~45 mm at q = 0) stay clear of the bone points"))
    pip_radius: float = param(0.009, unit="m", low=0.001, high=0.03,
                              source="chosen: 'larger pulley radii' than the index (section 5.4), r12")
    dip_radius: float = param(0.007, unit="m", low=0.001, high=0.03,
                              source="chosen: 'larger pulley radii' than the index (section 5.4), r13")
    proximal_length: float = param(0.035, unit="m", low=0.005, high=0.1,
                                   source="chosen: human thumb proximal phalanx ~35 mm")
    distal_length: float = param(0.028, unit="m", low=0.005, high=0.1,
                                 source="chosen: human thumb distal phalanx ~28 mm")
    link_radius: float = param(0.008, unit="m", low=0.001, high=0.02, source="chosen: thumb is wider")
    metacarpal_mass: float = param(0.012, unit="kg", low=0.0, high=0.1, low_inclusive=False,
                                   source="chosen: a longer, thicker bone than an index phalanx")
    base_link_mass: float = param(0.001, unit="kg", low=0.0, high=0.1, low_inclusive=False,
                                  source="chosen: small intermediate link of the 2-DoF base")
    proximal_mass: float = param(0.008, unit="kg", low=0.0, high=0.1, low_inclusive=False, source=_MASS_SRC)
    distal_mass: float = param(0.006, unit="kg", low=0.0, high=0.1, low_inclusive=False, source=_MASS_SRC)
    joint_damping: float = param(2e-5, unit="N m s/rad", low=0.0, high=1.0,
                                 source="chosen: as FingerParams.joint_damping, scaled for the thumb")

    num_dof = property(lambda self: 4)

    def _validate(self) -> None:
        for name in ("palm_points", "bone_points"):
            if len(getattr(self, name)) != 12:
                raise ValueError(f"ThumbParams.{name} needs 12 numbers (4 points x 3), "
                                 f"got {len(getattr(self, name))}")


FINGERS = ("thumb", "index", "middle", "ring", "fifth")

#: Float evaluations of one finger / hand plant system by the generic path (the plant's own ``CalcMassMatrix``...
#: and the drive laws) before its compiled kernels are built (:class:`~awiwi_drake.hand.dynamics.HandDynamics_`).
#: Chosen: an operating point and a linearisation evaluate the plant in float once, a simulation thousands of times
#: and its first two control periods 6-10 times; the generic path costs 0.17 / 0.30 ms a call on the fifth finger /
#: the hand, the kernels a trace and a compile when not cached (the fifth finger 12 CPU s).
COMPILE_AFTER_CALLS = 4

# (pip_dip_coupled, has_hmc) of each serial finger: section 5.2 (index, middle), 5.3 (ring), 5.5 (fifth)
FINGER_STRUCTURE = {"index": (False, False), "middle": (False, False), "ring": (True, False),
                    "fifth": (True, True)}


def check_finger_structure(finger: str, p) -> None:
    """ValueError naming ``finger`` and the field when ``p``'s structure flags are not the thesis's."""
    if finger not in FINGER_STRUCTURE:
        return
    coupled, hmc = FINGER_STRUCTURE[finger]
    dof = 4 - int(coupled) + int(hmc)
    for name, value in zip(("pip_dip_coupled", "has_hmc"), FINGER_STRUCTURE[finger]):
        if getattr(p, name) != value:
            raise ValueError(f"{finger} finger: {type(p).__name__}.{name} must be {value} (pip_dip_coupled={coupled}, "
                             f"has_hmc={hmc}: {dof} DoF, {2 * dof} tendons; sections 5.2-5.5), got {getattr(p, name)}")

# Global tendon numbering (0-based slices of the 38 tendons, Table 6.2 order): chosen, see module doc.
TENDON_SLICES = {"thumb": slice(0, 8), "index": slice(8, 16), "middle": slice(16, 24),
                 "ring": slice(24, 30), "fifth": slice(30, 38)}


@dataclass(frozen=True)
class HandParams(Parameters):
    """The five fingers and where their bases sit in the palm.

    Base placements are chosen (the thesis gives no palm geometry besides the
    wrist's Table 6.2): fingers 20 mm apart along the palm's y axis at the
    distal palm edge, thumb at the radial side, rotated to oppose.
    """

    thumb: ThumbParams = field(default_factory=ThumbParams)
    index: IndexFingerParams = field(default_factory=IndexFingerParams)
    middle: MiddleFingerParams = field(default_factory=MiddleFingerParams)
    ring: RingFingerParams = field(default_factory=RingFingerParams)
    fifth: FifthFingerParams = field(default_factory=FifthFingerParams)
    palm_length: float = param(0.09, unit="m", low=0.03, high=0.2,
                               source="chosen: human palm length ~90 mm (Fig 5.5 scale)")
    finger_spacing: float = param(0.02, unit="m", low=0.005, high=0.05,
                                  source="chosen: ~20 mm between finger bases (human hand)")

    def _validate(self) -> None:
        super()._validate()
        for name, typ in _FINGER_PARAM_TYPES.items():   # each finger class checks its structure (FINGER_STRUCTURE)
            if not isinstance(getattr(self, name), typ):
                raise ValueError(f"HandParams.{name} must be {typ.__name__}, got {type(getattr(self, name)).__name__}")

    def finger(self, name: str):
        """The parameter set of finger ``name`` (one of FINGERS)."""
        if name not in FINGERS:
            raise ValueError(f"finger must be one of {FINGERS}, got {name!r}")
        return getattr(self, name)


def finger_params(name: str):
    """Default parameter set of finger ``name``."""
    return HandParams().finger(name)


@dataclass(frozen=True)
class FingerDriveParams(Parameters):
    """Motors, springs, pretension and routing friction shared by finger and hand diagrams.

    The thesis's physics, each switchable (``with_physics``): motor friction (3.8) and ripple, guide
    friction on every tendon path ((4.1) at each tendon's bending angle, or the capstan form), spring
    hysteresis (Fig 4.8b; hysteresis and guide friction are Dahl states), the tendon's own elasticity in
    series with each mechanism (``spring.include_tendon``), and the joints' stick-slip friction (off by
    default).  Per-name overrides, tuples of ``(name, params)`` pairs: ``tendon_springs``
    (``SpringModelParams``), ``tendon_motors`` (``MotorParams``: friction, ripple, inertia, damping of one
    motor; pulley radius, torque limit and saturation stay those of ``motor``), ``tendon_guides``
    (``TendonGuideParams``, whether ``guide_friction`` is on or off for the others) and ``joint_frictions``
    (``JointFrictionParams`` by joint name).
    """

    motor: MotorParams = field(default_factory=lambda: MotorParams(ripple=True))
    spring: SpringModelParams = field(
        default_factory=lambda: SpringModelParams(hysteresis=HysteresisParams(enabled=True)))
    tendon_springs: tuple[tuple[str, SpringModelParams], ...] = ()
    tendon_motors: tuple[tuple[str, MotorParams], ...] = ()
    tendon_guides: tuple[tuple[str, TendonGuideParams], ...] = ()
    pretension: float = param(20.0, unit="N", low=0.0, low_inclusive=False,
                              source="Fig 15.26: f_pre = 20 N (as the joint rig)",
                              doc="tendon force of every tendon at the default operating point")
    guide_friction: bool = param(
        True, unit="-",
        source=("thesis (4.1), ch. 4 and 9: routing friction on every tendon path; on by default, at the level of Fig "
                "4.10 (~2 N per path, GuideFrictionParams.c0; ch. 9 measured 10-50 % of the tendon force, so this is "
                "the least the hand has). It leaves every impedance law a dead band, the guides' friction torque over "
                "the joint stiffness, which ch. 9 names ('a deflection of the link is not corrected even without any "
                "external disturbance') and its observer (9.2) removes (tests/test_hand_control.py). The 15.5 finger "
                "backstepping is stable with it (without the link-acceleration feed-forward, see "
                "HandChainParams.link_acceleration_feedforward); with_physics(guide_friction=False) switches it off"))
    capstan_friction: bool = param(False, unit="-",
                                   source=("chosen: False = speed-independent (4.1); True = tension-"
                                           "proportional capstan law (ch. 9: 10-50 % of the force)"))
    friction: GuideFrictionParams = field(default_factory=GuideFrictionParams)
    palm_bending_angle: float = param(
        math.pi / 2, unit="rad", low=0.0, high=4 * math.pi,
        source="chosen: the tendons turn ~90 deg from the wrist into the finger (Fig 5.4)")
    joint_wrap_angle: float = param(
        math.pi / 2, unit="rad", low=0.0, high=2 * math.pi,
        source="chosen: ~90 deg wrap on each joint pulley a tendon crosses (Fig 5.10), straight finger")
    friction_smoothing_velocity: float = param(
        1e-3, unit="m/s", low=0.0, low_inclusive=False,
        source="chosen: tanh(v/v_s) replaces sign(v) below 1 mm/s tendon sliding speed (direction of the Dahl state)")
    guide_presliding_length: float = param(
        4e-4, unit="m", low=0.0, low_inclusive=False,
        source=("chosen: the thesis prints no presliding; the guide friction reaches its sliding level within a "
                "few 0.4 mm of tendon travel, the shortest length for which fixed-step RK3 at 3 kHz is stable on "
                "every finger and the hand with hysteresis on at the operating point's 20 N (not at every pretension: "
                "the thumb under joint-pd at 40 N, README; docs/REPRODUCTIONS.md, 'Thesis physics at 3 kHz')"))
    gravity: bool = param(False, unit="-", source="section 5.2.2: ~0.002 N m, negligible")
    joint_friction: bool = param(
        False, unit="-",
        source=("chosen off by default: the thesis prints no joint friction level (JointFrictionParams) while the "
                "routing friction it measured (ch. 4, ch. 9's 10-50 %) is on (guide_friction); with_physics("
                "joint_friction=True) adds the joints' stick-slip of Fig 15.25 (reproductions.ch15_pip_experiments)"))
    joint_friction_params: JointFrictionParams = field(default_factory=JointFrictionParams)
    joint_frictions: tuple[tuple[str, JointFrictionParams], ...] = ()

    def with_physics(self, *, ripple: bool | None = None, hysteresis: bool | None = None,
                     guide_friction: bool | None = None, motor_friction: bool | None = None,
                     joint_friction: bool | None = None):
        """A copy with the named thesis effects switched (None leaves one as it is).

        E.g. ``p.with_physics(hysteresis=False, guide_friction=False)`` for the per-joint design models,
        which have neither Dahl state; ``p.with_physics(ripple=False, hysteresis=False, guide_friction=False, motor_friction=False)``
        is the ideal plant (frictionless motors, elastic springs); ``joint_friction=True`` adds the joints'
        stick-slip (off by default).
        """
        p = self
        if ripple is not None or motor_friction is not None:
            p = p.replace(motor=p.motor.replace(**{k: v for k, v in (("ripple", ripple), ("friction", motor_friction))
                                                   if v is not None}))
        if hysteresis is not None:
            p = p.replace(spring=p.spring.replace(hysteresis=p.spring.hysteresis.replace(enabled=bool(hysteresis))),
                          tendon_springs=tuple((t, s.replace(hysteresis=s.hysteresis.replace(enabled=bool(hysteresis))))
                                               for t, s in p.tendon_springs))
        if guide_friction is not None:
            p = p.replace(guide_friction=bool(guide_friction), **({} if guide_friction else {"tendon_guides": ()}))
        if joint_friction is not None:
            p = p.replace(joint_friction=bool(joint_friction))
        return p

    def _validate(self) -> None:
        super()._validate()
        for name, cls in (("tendon_springs", SpringModelParams), ("tendon_motors", MotorParams),
                          ("tendon_guides", TendonGuideParams), ("joint_frictions", JointFrictionParams)):
            if not isinstance(getattr(self, name), tuple):
                raise ValueError(f"{type(self).__name__}.{name} must be a tuple of (tendon_name, {cls.__name__}) "
                                 f"pairs, got {type(getattr(self, name)).__name__}")
            for i, entry in enumerate(getattr(self, name)):
                if (not isinstance(entry, tuple) or len(entry) != 2 or not isinstance(entry[0], str)
                        or not isinstance(entry[1], cls)):
                    raise ValueError(f"{type(self).__name__}.{name}[{i}] = {entry!r} must be a "
                                     f"({name.split('_')[0].rstrip('s')}_name, {cls.__name__}) pair")
            keys = [k for k, _ in getattr(self, name)]
            if len(set(keys)) < len(keys):
                raise ValueError(f"{type(self).__name__}.{name}: {next(k for k in keys if keys.count(k) > 1)!r} is "
                                 "given twice")
            if name == "joint_frictions":       # joint names are checked where the plant is built
                continue
            names = self.tendon_names
            for tendon, _ in getattr(self, name):
                if names is not None and tendon not in names:
                    raise ValueError(f"{type(self).__name__}.{name}: unknown tendon {tendon!r}; tendons are "
                                     f"{names[0]} ... {names[-1]}")

    @property
    def tendon_names(self):
        """The tendon names the per-tendon overrides may use (None: not known at this level)."""
        return None


_FINGER_PARAM_TYPES = {"thumb": ThumbParams, "index": IndexFingerParams, "middle": MiddleFingerParams,
                       "ring": RingFingerParams, "fifth": FifthFingerParams}


@dataclass(frozen=True)
class FingerRigParams(FingerDriveParams):
    """One finger with its motors and springs.

    ``finger_name`` says which finger ``finger`` describes (checked); build the
    default set of any finger with :meth:`for_finger`.
    """

    finger: FingerParams | ThumbParams = field(default_factory=IndexFingerParams)
    finger_name: str = "index"

    @classmethod
    def for_finger(cls, name: str, **overrides) -> "FingerRigParams":
        """Defaults for finger ``name`` (one of FINGERS), with field ``overrides``."""
        if name not in FINGERS:
            raise ValueError(f"FingerRigParams.finger_name must be one of {FINGERS}, got {name!r}")
        return cls(finger=_FINGER_PARAM_TYPES[name](), finger_name=name, **overrides)

    @property
    def tendon_names(self):
        """``<finger>_h1 ... <finger>_h2n``: two antagonistic tendons per independent DoF (section 5.1; the
        order of the finger's coupling matrix rows, hand/coupling.py)."""
        return [f"{self.finger_name}_h{k + 1}" for k in range(2 * self.finger.num_dof)]

    def _validate(self) -> None:
        if self.finger_name not in FINGERS:
            raise ValueError(f"FingerRigParams.finger_name must be one of {FINGERS}, got {self.finger_name!r}")
        super()._validate()
        expected = _FINGER_PARAM_TYPES[self.finger_name]
        if not isinstance(self.finger, expected):
            raise ValueError(f"FingerRigParams.finger must be {expected.__name__} for finger_name "
                             f"{self.finger_name!r}, got {type(self.finger).__name__}")


@dataclass(frozen=True)
class HandRigParams(FingerDriveParams):
    """The whole hand: 5 fingers, 38 motors and springs."""

    hand: HandParams = field(default_factory=HandParams)

    @property
    def tendon_names(self):
        """Every finger's tendon names (:attr:`FingerRigParams.tendon_names`), fingers in FINGERS order."""
        return [f"{f}_h{k + 1}" for f in FINGERS for k in range(2 * self.hand.finger(f).num_dof)]


@dataclass(frozen=True)
class JointControllerParams(Parameters):
    """Motor-side PD with a joint-space reference (:func:`awiwi_drake.control.joint_pd.joint_pd_controller`)."""

    kp: float = param(100.0, unit="N m/rad", low=0.0,
                      source=("chosen: motor loop at sqrt(kp/B) = 224 rad/s with B = 2e-3 kg m^2 (well "
                              "below the 3 kHz rate); the Coulomb friction 0.56 N m (Table 3.3) then leaves "
                              "<= 5.6e-3 rad motor error, ~0.03 mm of tendon"))
    kd: float = param(0.6, unit="N m s/rad", low=0.0,
                      source="chosen: damping ratio ~0.67 of the motor loop (2 * 0.67 * 224 * 2e-3)")
    period: float = param(1.0 / 3000.0, unit="s", low=0.0, low_inclusive=False,
                          source="section 3.3 (\"the high control frequency of 3kHz\") and section 4.1 (lever sensors read at 3 kHz)")
