"""Finger hidden-effect datasets: the package's own finger diagram with one effect on one tendon.

:func:`make_finger_dataset` simulates :func:`~awiwi_drake.hand.diagrams.finger_diagram` (nominal: the
ideal finger, ``with_physics`` all off, unless ``params`` says otherwise) in closed loop with the motor
position PD (:func:`~awiwi_drake.control.motor_position.motor_position_controller`) at the logging rate,
and records what the real hand measures: the commanded motor torques (inputs), the motor angles and the
tendon forces (outputs); joint angles only on request (the hand has no joint sensors).

The hidden effect acts at one place (tendon ``place``, 1-based in the finger's tendon order):

==================== =========================================================================
``motor_friction``    Stribeck friction on that motor (:func:`~awiwi_drake.components.friction.stribeck_friction`;
                      the catalog's form is (3.8), an arctangent)
``guide_friction``    friction of that tendon's path between the force sensor and the joints, constant plus
                      capstan part: the package's guides (a Dahl state, ``FingerDriveParams.tendon_guides``
                      entry of the truth finger) on that path only
``motor_ripple``      two harmonics on that motor, orders drawn from 1..6 and 100 per revolution
``spring_hysteresis`` that tendon's spring mechanism with the package's hysteresis (Fig 4.8b; a
                      force-proportional loop, ``HysteresisParams.width_ratio``; the catalog's loop has a
                      constant width): a ``tendon_springs`` entry of the truth finger
==================== =========================================================================

Motor friction and ripple are torques on the motor from a block in front of the drive's ``motor_torque`` input
(:class:`FingerHiddenTorque_`). Guide friction is where the thesis has it: "the tendon force measurements are
performed into the forearm", so "the friction introduced by the guidings from the fingers to the spring
mechanisms" (ch. 4, introduction) acts between the force sensor and the joints: the joints feel ``-P^T (f + g)``
while the sensor reads ``f``.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
from pydrake.systems.framework import DiagramBuilder, LeafSystem_
from pydrake.systems.primitives import Adder, ConstantVectorSource
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.analysis import Samples, SimulationEventError, simulate
from awiwi_drake.components.friction import stribeck_friction
from awiwi_drake.control import closed_loop
from awiwi_drake.control.motor_position import motor_position_controller
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
from awiwi_drake.parameters.components import HysteresisParams, TendonGuideParams
from awiwi_drake.parameters.discrepancy import FingerTruthParams
from awiwi_drake.parameters.hand import FINGERS, FingerRigParams, HandRigParams
from awiwi_drake.parameters.rigs import MotorPositionGains

from . import laws
from .data import Dataset, finger_rig_name
from .truth import ripple_draw, sensor_reading, stribeck_draw

__all__ = ["FINGER_HIDDEN_EFFECTS", "FingerHiddenTorque_", "nominal_finger_params", "make_finger_dataset"]

FINGER_HIDDEN_EFFECTS = ("motor_friction", "guide_friction", "motor_ripple", "spring_hysteresis")
_TORQUE_EFFECTS = ("motor_friction", "motor_ripple")


def nominal_finger_params(finger: str):
    """The nominal finger of a dataset: the package's defaults with the thesis's physics off (the
    ideal finger; a user's JSON may give any other set); ``"hand"``: the hand's (:class:`HandRigParams`)."""
    base = HandRigParams() if finger == "hand" else FingerRigParams.for_finger(finger)
    return base.with_physics(ripple=False, hysteresis=False, guide_friction=False, motor_friction=False)


def _diagram(finger: str, params):
    """The package's finger diagram, or for ``"hand"`` the hand's with the wrist still (no wrist input: its (6.9)
    offsets are constant and in the rest lengths)."""
    return hand_diagram(params=params, wrist=False) if finger == "hand" else finger_diagram(finger=finger,
                                                                                           params=params)


def _finger_joints(finger: str, params, joint_names) -> list:
    """``[(name, FingerParams, [joint indices])]`` of the fingers in the diagram (one, or the hand's five)."""
    names = FINGERS if finger == "hand" else (finger,)
    out = []
    for f in names:
        fp = params.hand.finger(f) if finger == "hand" else params.finger
        digit = "12345"[FINGERS.index(f)]
        out.append((f, fp, [k for k, j in enumerate(joint_names) if j[1] == digit]))
    return out


@TemplateSystem.define("FingerHiddenTorque_", scope=sys.modules[__name__])
def FingerHiddenTorque_(T):

    class Impl(LeafSystem_[T]):
        """Torque of a hidden motor-side effect on one motor: input ``motor_state`` (2m: theta, omega);
        output ``torque`` (m) [N m], zero except at the effect's place."""

        def _construct(self, num_tendons: int, truth: dict, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self._m, self._truth = int(num_tendons), dict(truth)
            xs = self.DeclareVectorInputPort("motor_state", 2 * self._m)
            # declared, so Build()'s feedthrough check does not evaluate _calc on symbolic inputs (it did, and
            # np.exp/tanh on the Expression objects left the FPU's invalid flag set: numpy's "invalid value")
            self.DeclareVectorOutputPort("torque", self._m, self._calc, prerequisites_of_calc={xs.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other._m, other._truth, converter=converter)

        def _calc(self, context, output):
            xs = self.get_input_port(0).Eval(context)
            tr, m, k = self._truth, self._m, self._truth["place"] - 1
            theta, omega = xs[k], xs[m + k]
            tau = 0.0 * omega
            if "motor_friction" in tr:
                p = tr["motor_friction"]
                tau = tau + stribeck_friction(omega, p["fc"], p["fs"], p["vs"], p["eps"], p["viscous"])
            if "motor_ripple" in tr:
                tau = tau + laws.ripple(theta, tr["motor_ripple"]["harmonics"])
            out = [0.0 * omega] * m
            out[k] = tau
            output.SetFromVector(np.array(out))

    return Impl


def draw_finger_truth(hidden, place: int, num_tendons: int, rng: np.random.Generator,
                      gen: FingerTruthParams, strength: float = 1.0) -> dict:
    """Random parameters of the hidden effects at tendon ``place`` (1-based)."""
    for h in hidden:
        if h not in FINGER_HIDDEN_EFFECTS:
            raise ValueError(f"--hide {h}: not a finger effect (finger effects: {', '.join(FINGER_HIDDEN_EFFECTS)})")
    if not hidden and place is not None:
        raise ValueError(f"--place {place}: nothing hidden to place (give --hide)")
    if hidden and not (isinstance(place, int) and 1 <= place <= num_tendons):
        raise ValueError(f"--place {place!r}: a finger effect needs the tendon it acts on, 1..{num_tendons}")
    u, k = rng.uniform, float(strength)
    tr: dict = {"hidden": list(hidden), "place": int(place) if hidden else None, "strength": k}
    if "motor_friction" in hidden:
        tr["motor_friction"] = stribeck_draw(k * u(*gen.motor_coulomb_range), gen.motor_viscous_range, rng, k)
    if "guide_friction" in hidden:
        tr["guide_friction"] = dict(c0=k * u(*gen.guide_c0_range), mu_angle=k * u(*gen.guide_mu_range))
    if "motor_ripple" in hidden:
        tr["motor_ripple"] = dict(harmonics=ripple_draw(gen.ripple_amplitude_range, 1, rng, k)[0])
    if "spring_hysteresis" in hidden:
        tr["spring_hysteresis"] = dict(width_ratio=k * u(*gen.hysteresis_ratio_range))
    return tr


def with_loop(params, tendon: str, h: HysteresisParams):
    """``params`` (FingerRigParams) with the hysteresis loop ``h`` on ``tendon``'s ``tendon_springs`` entry."""
    own = dict(params.tendon_springs)
    own[tendon] = own.get(tendon, params.spring).replace(hysteresis=h)
    return params.replace(tendon_springs=tuple(own.items()))


def _truth_rig(finger: str, nominal: FingerRigParams, truth: dict):
    """The finger rig with the hidden guides/loop in its parameters, and that rig with the hidden motor torques
    added in front of its ``motor_torque`` (the same states and handles; its operating points are the finger's
    without those torques)."""
    p = nominal
    placed = {"spring_hysteresis", "guide_friction"} & set(truth)
    tendon = _diagram(finger, p).tendon_names[truth["place"] - 1] if placed else None
    if "spring_hysteresis" in truth:      # the package's hysteresis on the spring mechanism of that tendon
        p = with_loop(p, tendon, HysteresisParams(enabled=True, width_ratio=truth["spring_hysteresis"]["width_ratio"]))
    if "guide_friction" in truth:         # the package's guides (between sensor and joints) on that path only
        g = truth["guide_friction"]
        p = p.replace(tendon_guides=tuple(dict(p.tendon_guides, **{tendon: TendonGuideParams(
            constant=g["c0"], capstan_exponent=g["mu_angle"])}).items()))
    rig = _diagram(finger, p)
    m = rig.num_tendons
    b = DiagramBuilder()
    fd = b.AddNamedSystem(f"finger_{finger}", rig.diagram)
    zero = b.AddNamedSystem("no_external_torque", ConstantVectorSource(np.zeros(rig.num_joints)))
    b.Connect(zero.get_output_port(0), fd.GetInputPort("external_torque"))
    if any(e in truth for e in _TORQUE_EFFECTS):
        hid = b.AddNamedSystem("hidden_effect", FingerHiddenTorque_[float](m, truth))
        add = b.AddNamedSystem("motor_torque_sum", Adder(2, m))
        b.Connect(fd.GetOutputPort("motor_state"), hid.get_input_port(0))
        b.Connect(hid.get_output_port(0), add.get_input_port(1))
        b.Connect(add.get_output_port(0), fd.GetInputPort("motor_torque"))
        b.ExportInput(add.get_input_port(0), "motor_torque")
    else:
        b.ExportInput(fd.GetInputPort("motor_torque"), "motor_torque")
    for name in ("motor_angle", "motor_velocity", "tendon_force", "joint_angle", "state"):
        b.ExportOutput(fd.GetOutputPort(name), name)
    return rig, dataclasses.replace(rig, name=f"truth-finger-{finger}", diagram=b.Build())


def make_finger_dataset(finger: str = "index", hidden=(), *, place: int | None = None, snr_db: float | None = 30.0,
                        seed: int = 0, gen: FingerTruthParams | None = None, strength: float = 1.0,
                        joint_angles: bool = False, name: str | None = None, keep_clean: bool = True,
                        params: FingerRigParams | None = None, progress=None) -> Dataset:
    """Simulate one closed-loop finger experiment with ``hidden`` effects at tendon ``place``.

    Parameters
    ----------
    finger : one of FINGERS
    hidden : sequence of :data:`FINGER_HIDDEN_EFFECTS`
    place : int
        The tendon (1-based, the finger's tendon order ``<finger>_h1...``) the effects act on.
    snr_db : float or None
        Sensor SNR [dB] of every output, relative to its standard deviation (None: noise-free); forces
        are quantised as in :class:`~awiwi_drake.parameters.discrepancy.TruthGeneratorParams`.
    joint_angles : bool
        Also record the joint angles (the real hand has no joint sensors).
    params : FingerRigParams, optional
        The nominal finger (default :func:`nominal_finger_params`); the truth is it plus ``hidden``.

    Returns
    -------
    Dataset (rig ``finger-<finger>``) whose ``meta["truth"]`` holds the hidden effects and place.
    """
    if finger not in FINGERS + ("hand",):
        raise ValueError(f"finger must be one of {', '.join(FINGERS)} or hand, got {finger!r}")
    gen = gen or FingerTruthParams()
    nominal = params if params is not None else nominal_finger_params(finger)
    rng = np.random.default_rng(seed)
    probe = _diagram(finger, nominal)
    m, n = probe.num_tendons, probe.num_joints
    truth = draw_finger_truth(list(hidden), place, m, rng, gen, strength)
    rig, truth_rig = _truth_rig(finger, nominal, truth)
    dt = 1.0 / gen.sample_rate
    N = int(round(gen.duration / dt))
    t = np.arange(N) * dt
    # references: each joint its own lab excitation, plus a common co-contraction of every tendon
    from .truth import _excitation, _reference_filter
    q_op = np.full(n, gen.flexion)
    amp = np.full(n, gen.joint_excursion)
    parts = _finger_joints(finger, nominal, probe.joint_names)
    for _, _, joints in parts:
        q_op[joints[0]] = 0.0  # abduction (or the thumb's first joint) centred
        amp[joints[0]] *= 0.5
    Q = np.empty((N, n))
    for j in range(n):      # two first-order reference filters
        Q[:, j] = q_op[j] + amp[j] * _reference_filter(_excitation(t + rng.uniform(0, 3.0), rng), dt,
                                                       gen.reference_time_constant, 2)
    for _, fp, joints in parts:
        if getattr(fp, "pip_dip_coupled", False):   # ring, fifth: (5.16) q_DIP = (r_x3 / r_x2) q_PIP, no DIP of its own
            pip, dip = (k for k in joints if probe.joint_names[k][-1] in "23")
            q_op[dip] = fp.dip_pip_ratio * q_op[pip]
            Q[:, dip] = fp.dip_pip_ratio * Q[:, pip]
    op = probe.operating_point(joint_angles=q_op)
    r_m = nominal.motor.pulley_radius
    laws_t = probe.spring_laws
    f_cc = nominal.pretension + gen.force_modulation * np.sin(2 * np.pi * gen.modulation_hz * t
                                                              + rng.uniform(0, 2 * np.pi))
    h = probe.coupling.h
    h0 = np.asarray(h(np.zeros(n)), float)
    X = np.stack([np.asarray(law.inverse_force(f_cc), float) for law in laws_t], axis=1)   # (N, m)
    ref = np.empty((N, m))
    for k in range(N):
        ref[k] = (X[k] - probe.offsets - (np.asarray(h(Q[k]), float) - h0)) / r_m
    X0 = np.asarray(op.state, float).copy()
    X0[2 * n:2 * n + m] = ref[0]
    # the joints start where the first reference sample puts them: with the joints at q_op instead, each tendon
    # starts stretched by P (Q[0] - q_op), on the thumb's base (long moment arms) 0-109 N and slack within 50 ms,
    # and with a hysteresis loop on a thumb tendon the state diverged within 25 ms (fixed step 1/3000 s or 1/6000 s)
    X0[:n] = Q[0]
    gains = MotorPositionGains(kp=gen.kp, kd=gen.kd, rate_hz=gen.sample_rate)
    ctrl = motor_position_controller(truth_rig, gains, pulley_radius=r_m)
    loop = closed_loop(truth_rig, ctrl, rate_hz=gen.sample_rate, estimator=None)
    full = np.zeros(truth_rig.diagram.num_continuous_states())
    full[:len(X0)] = X0          # the Dahl states (hysteresis of the hidden tendon) start at rest
    u0 = r_m * nominal.pretension   # the PD holds the pretension: u = r f_pre at the reference
    ctx = loop.create_context(state=full, motor_torque=np.full(m, u0))
    res = simulate(loop, ctx, t[-1], inputs={"motor_angle_reference": Samples(t, ref, hold="zoh"),
                                             "tendon_force_reference": np.full(m, nominal.pretension)},
                   log=("motor_angle", "tendon_force", "joint_angle", "motor_torque_command"), log_period=dt,
                   mode="fixed_step", step=1.0 / 3000.0 if gen.sample_rate <= 3000 else dt, progress=progress)
    U = res["motor_torque_command"]
    if U.shape[0] != N:
        raise RuntimeError(f"finger truth simulation logged {U.shape[0]} samples, expected {N}")
    clean = {}
    for i in range(m):
        clean[f"motor_angle_{i + 1}"] = res["motor_angle"][:, i].copy()
        clean[f"tendon_force_{i + 1}"] = res["tendon_force"][:, i].copy()
    if joint_angles:
        for j in range(n):
            clean[f"joint_angle_{j + 1}"] = res["joint_angle"][:, j].copy()
    meas = {key: y.copy() if snr_db is None else sensor_reading(key, y, y.std() * 10 ** (-snr_db / 20.0), rng)
            for key, y in clean.items()}
    if np.any(np.abs(U) >= nominal.motor.torque_limit) and nominal.motor.saturation:
        t_sat = float(t[np.nonzero(np.any(np.abs(U) >= nominal.motor.torque_limit, axis=1))[0][0]])
        raise SimulationEventError(f"finger truth: the commanded torque reaches the motor limit "
                                   f"{nominal.motor.torque_limit} N m at t = {t_sat:.6g} s; the logged command would "
                                   f"not be the applied one", kind="actuator_saturation", t=t_sat)
    inputs = {f"motor_torque_{i + 1}": U[:, i].copy() for i in range(m)}
    tag = "-".join(hidden) if hidden else "none"
    where = f"_t{place}" if hidden else ""
    rig_name = "hand" if finger == "hand" else finger_rig_name(finger)
    name = name or f"{rig_name}_{tag}{where}_snr{'inf' if snr_db is None else int(snr_db)}_s{seed}"
    meta = {"truth": dict(truth, tendon=rig.tendon_names[place - 1] if hidden else None),
            "generator": {"snr_db": snr_db, "seed": seed, "sample_rate": gen.sample_rate, "duration": gen.duration}}
    from .data import finger_parameters_to_json
    ds = Dataset(name, rig_name, t, inputs, meas, finger_parameters_to_json(finger, nominal), {}, meta)
    if keep_clean:
        ds.meta["clean_outputs"] = clean
    return ds
