"""Built-in controller registrations (imported lazily by :mod:`.registry`), ch. 10-16.

Factories import their modules on call so that listing names stays cheap.
"""

from __future__ import annotations

import importlib

from awiwi_drake.control.registry import register_controller
from awiwi_drake.parameters.hand_control import FrictionObserverParams

_JOINTS = ("flexible-joint", "joint-rig")
_SAMPLED = {"rate_hz": 3000.0}


def _lazy(module: str, function: str, *, chain_keyword: str | None = None, **kwargs):
    """``factory(rig)`` calling ``module.function(rig, **kwargs)`` (imported on first call).

    ``chain_keyword``: the function's keyword for its :class:`~awiwi_drake.parameters.hand_control.HandChainParams`;
    the factory then takes them as ``chain_params`` (the one name for every finger/hand controller, e.g.
    ``compare --controller-set``); ``factory.takes`` names the options ``compare --controller-set`` may give it
    (``chain_params``; the chain designs also ``stiffness_correction``)."""
    def factory(rig, **options):
        if "chain_params" in options and chain_keyword is not None:
            options[chain_keyword] = options.pop("chain_params")
        return getattr(importlib.import_module(f"awiwi_drake.control.{module}"), function)(rig, **{**kwargs,
                                                                                              **options})
    factory.__name__ = f"{function}_factory"
    factory.takes = frozenset(() if chain_keyword is None else ("chain_params",) + (
        ("stiffness_correction",) if function == "joint_stage_controller" else ()))
    return factory


_BUILTIN = [
    ("tendon-pd", _lazy("tendon_force", "tendon_pd_controller"), ("tendon-rig",),
     "(10.2) PD + force/friction feed-forward, gains (10.11) fixed at 30 N"),
    ("tendon-scheduled", _lazy("tendon_force", "tendon_scheduled_controller"), ("tendon-rig",),
     "(10.2) with gains (10.11) scheduled on the reference force (10.12)"),
    ("tendon-sdre", _lazy("sdre", "tendon_sdre_controller"), ("tendon-rig",),
     "SDRE tendon force control (14.7)-(14.9), Table 14.1, gains at 200 Hz"),
    ("pd", _lazy("impedance", "impedance_controller", mode="pd"), _JOINTS,
     "PD on the motor angles towards the link reference (baseline)"),
    ("two-time-scale", _lazy("impedance", "impedance_controller", mode="two-time-scale"), _JOINTS,
     "joint impedance (11.4) over a motor-position tendon loop (11.3)"),
    ("cascaded", _lazy("impedance", "impedance_controller", mode="cascaded"), _JOINTS,
     "joint impedance (11.4) over an exactly linearising force loop (11.16), load observer"),
    ("pole-placement", _lazy("pole_placement", "pole_placement_controller"), _JOINTS,
     "state feedback placing a double oscillator (12.13), Table 12.1"),
    ("lqr", _lazy("lqr", "lqr_controller"), _JOINTS,
     "LQR on the linearised rig, Table 13.1 (Q=diag(10,.01,1,.01), R=0.01)"),
    ("sdre", _lazy("sdre", "joint_sdre_controller"), _JOINTS,
     "SDRE state feedback (14.10)-(14.12), Table 14.2, gains at 200 Hz"),
]

_BUILTIN.append(("joint-pd", _lazy("joint_pd", "joint_pd_controller"), ("finger", "hand"),
                 "motor PD towards the motor angles of the joint reference (exact routing), pretension held"))
for _design, _doc in (
        ("cascaded", "joint impedance (11.4) -> force distribution (ch. 7) -> tendon force PD (10.2) with friction/ripple "
                     "feed-forward, joint angles estimated from tendon lengths (5.15); damping per joint from its reduced "
                     "model"),
        ("pd", "PD on the estimated joint angle per joint, (Kp, Kd) placing one pair at 60 rad/s, damping 0.7, on the "
               "joint's reduced model (torque chain, own tendons) -> force distribution (ch. 7) -> force PD (10.2)"),
        ("two-time-scale", "joint impedance (11.4) -> force distribution (ch. 7) -> motor-position loop per tendon "
                           "towards the force (11.3); damping per joint from its reduced model"),
        ("pole-placement", "per joint: double oscillator (12.13) placed on the joint's reduced model [q, qdot, tau, "
                           "tau_dot] (link through its closed force loop) -> force distribution (ch. 7) -> force PD (10.2)"),
        ("lqr", "per joint: LQR on the joint's reduced model [q, qdot, tau, tau_dot] (Bryson weights, the motors' torque "
                "rate measured) -> force distribution (ch. 7) -> force PD (10.2)"),
        ("sdre", "per joint: LQR re-solved on the pointwise-linear reduced models tabulated in the joint torque (ch. "
                 "14), gains interpolated at the measured torque -> the chain")):
    _BUILTIN.append((_design, _lazy("joint_design", "joint_stage_controller", chain_keyword="chain", design=_design),
                     ("finger", "hand"), _doc))

# Every stage runs at the thesis's 3 kHz with the estimator at the same rate (the full-state stages need the
# estimate of the current sample, hand.estimation, and the motors' torque rate: control.joint_design).
for _name, _factory, _rigs, _doc in _BUILTIN:
    register_controller(_name, _factory, rigs=_rigs, description=_doc, loop_options=_SAMPLED)

# Ch. 15 on fingers and the hand (control/finger_backstepping.py): the 15.5 law, its variants and its (9.2) observer
# options, at the thesis's 3 kHz its joint gains are designed for (HandChainParams.sampled_pole_limit); ch. 16's
# force gains per DoF (control/optimal_gains.py, select_finger_force_gains).
_FINGER_BACKSTEPPING = [
    ("backstepping", "finger_backstepping", {},
     "antagonistic backstepping (15.5) per tendon, torque shared by (P S)^T+, motor torques directly; joint modes "
     "designed for 3 kHz, joint angles estimated (5.15)"),
    ("backstepping-position", "finger_backstepping", {"variant": "position"},
     "position backstepping per DoF (15.2 steps on the link: z2 = e' + k1 e, V = |e|^2/2 + |z2|^2/2 + ...) through "
     "the 15.5 tendon steps, motor torques directly; 3 kHz"),
    ("backstepping-nonlinear-spring", "finger_backstepping", {"variant": "nonlinear-spring"},
     "impedance backstepping with the steps on the joint torques (15.71)-(15.81), tau = -(P S)^T phi(x) with each "
     "tendon's spring law, the tendon forces' null space held at the pretension; 3 kHz"),
    ("backstepping-load-observer", "finger_backstepping", {"load_observer": FrictionObserverParams()},
     "15.5 backstepping with a (9.2) load observer per DoF (its link model gets the link-side torque the sensed "
     "spring forces do not explain: the load and the frictions); 3 kHz, joint angles estimated (5.15). Under a "
     "constant load it rests at the impedance's deflection less what the guides' and the lever's friction hold"),
    ("backstepping-friction-observer", "finger_backstepping", {"friction_observer": FrictionObserverParams()},
     "15.5 backstepping with the (9.2) observer per DoF in its link model and its estimate, bounded by the guides' "
     "and the lever's friction, added to the desired joint torque (9.1); 3 kHz, joint angles estimated (5.15)"),
    ("optimal-backstepping", "optimal_gains", {},
     "15.5 backstepping with K3, K4 per DoF selected by ch. 16 (least squares to the DoF's LQR, Table 16.1 weights, "
     "R the most aggressive the 3 kHz loop follows); impedance as backstepping"),
]
for _name, _module, _options, _doc in _FINGER_BACKSTEPPING:
    _function = "finger_backstepping_controller" if _module == "finger_backstepping" else \
        "finger_optimal_backstepping_controller"
    register_controller(_name, _lazy(_module, _function, chain_keyword="params", **_options), rigs=("finger", "hand"),
                        loop_options=_SAMPLED, description=_doc)


# Ch. 15/16 on the single-joint rigs, at the thesis's 3 kHz (section 15.5 experiments) with Kd,imp limited to
# m f_s / 4: the impedance damping puts a link pole at -Kd,imp / m, and the limit keeps h lambda >= -1/4 (with a
# 30 kHz limit the 3 kHz step saturated and did not settle: docs/REPRODUCTIONS.md, ch. 15; tests/test_backstepping.py).
# The limit is conservative at higher rates (--rate 30000); --rate 0 runs it continuously.
def _rig_backstepping(rig, optimal: bool = False):
    """``backstepping`` (the rig's impedance law: flexible joint (15.51)-(15.81) with its own spring law, joint rig
    (15.82)-(15.106), external-torque observer (9.2)) or ``optimal-backstepping`` (its gains fitted, ch. 16, to the
    LQR of the rig with Table 16.1's weights in torque coordinates, ``R = 1e-3``: with Table 16.1's ``R = 0.1`` the
    LQR gain is below the structural floor of the backstepping feedback, docs/REPRODUCTIONS.md; on the joint rig
    the antagonistic law fitted at its operating point inside a gain box bounded by the loop rate)."""
    from awiwi_drake.control.backstepping import impedance_controller
    from awiwi_drake.control.optimal_gains import optimize_gains, rate_limited_case
    from awiwi_drake.parameters.backstepping import (AntagonisticBacksteppingGains, ImpedanceBacksteppingGains,
                                                     JointRigOptimalGainsCase, OptimalGainsCase)
    from awiwi_drake.parameters.rigs import JointRigParams

    joint_rig = isinstance(rig.params, JointRigParams)
    if optimal and joint_rig:
        case = rate_limited_case(JointRigOptimalGainsCase(), rig.params.link_inertia, _SAMPLED["rate_hz"])
        return impedance_controller(rig, optimize_gains(rig, case, starts=16).gains)
    if optimal:
        return impedance_controller(rig, optimize_gains(rig, OptimalGainsCase(r_weight=1e-3)).gains)
    g = AntagonisticBacksteppingGains() if joint_rig else ImpedanceBacksteppingGains()
    damping = min(g.damping, rig.params.link_inertia * _SAMPLED["rate_hz"] / 4.0)
    return impedance_controller(rig, g.replace(damping=damping))


register_controller("backstepping", _rig_backstepping, rigs=_JOINTS, loop_options=_SAMPLED,
                    description="impedance backstepping (ch. 15.3-15.5), rig's spring law, external-torque observer")
register_controller("backstepping-position", _lazy("backstepping", "position_controller"), rigs=("flexible-joint",),
                    loop_options=_SAMPLED,
                    description="position backstepping of the linear flexible joint (15.11)-(15.50)")
register_controller("optimal-backstepping", lambda rig: _rig_backstepping(rig, optimal=True), rigs=_JOINTS,
                    loop_options=_SAMPLED, description="impedance backstepping with gains fitted to the LQR (ch. 16)")
