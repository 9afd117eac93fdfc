"""Built-in controller registrations (imported lazily by :mod:`.registry`).

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
    ``compare --controller-set``) and has ``takes_chain_params = True``."""
    def factory(rig, **options):
        if "chain_params" in options and chain_keyword is not None:
            options[chain_keyword] = options.pop("chain_params")
        return getattr(importlib.import_module(f"awiwi_drake.control.{module}"), function)(rig, **{**kwargs,
                                                                                              **options})
    factory.__name__ = f"{function}_factory"
    factory.takes_chain_params = chain_keyword is not None
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

# Every stage runs at the thesis's 3 kHz with the estimator at the same rate.  The full-state stages (lqr,
# pole-placement, sdre) used to need 9 kHz (at 3 kHz they saturated 82-99 % of a step): the estimate was one period
# older than the forces read with it, and its derivative, 1.5 periods late, destabilised the DIP's link mode
# (sampled loop |z| = 1.09-1.14 at ~3600-4050 rad/s on the index, control.joint_design.sampled_loop_poles); the
# estimate now comes from the current sample (hand.estimation) and the LQR/SDRE measure the motors' torque rate.
for _name, _factory, _rigs, _doc in _BUILTIN:
    register_controller(_name, _factory, rigs=_rigs, description=_doc, loop_options=_SAMPLED)

# The law at the thesis's 3 kHz: its joint gains are designed for that rate (every designed joint mode
# |h lambda| <= 1/4, HandChainParams.sampled_pole_limit). It used to run at 6 kHz: the per-DoF design put a
# pole at -6838 1/s on the index (h lambda = -2.3 at 3 kHz, sampled spectral radius 1.18, the command
# chattered between the torque limits); see control/finger_backstepping.py and issue 10 item 6.
register_controller("backstepping", _lazy("finger_backstepping", "finger_backstepping_controller",
                                          chain_keyword="params"),
                    rigs=("finger", "hand"), loop_options={"rate_hz": 3000.0},
                    description="antagonistic backstepping (15.5) per tendon, torque shared by (P S)^T+, motor "
                                "torques directly; joint modes designed for 3 kHz, joint angles estimated (5.15)")
for _variant, _doc in (("position", "position backstepping per DoF (15.2 steps on the link: z2 = e' + k1 e, "
                                     "V = |e|^2/2 + |z2|^2/2 + ...) through the 15.5 tendon steps, motor torques "
                                     "directly; 3 kHz"),
                        ("nonlinear-spring", "impedance backstepping with the steps on the joint torques (15.71)-"
                                             "(15.81), tau = -(P S)^T phi(x) with each tendon's spring law, the "
                                             "tendon forces' null space held at the pretension; 3 kHz")):
    register_controller(f"backstepping-{_variant}", _lazy("finger_backstepping", "finger_backstepping_controller",
                                                          chain_keyword="params", variant=_variant),
                        rigs=("finger", "hand"), loop_options={"rate_hz": 3000.0}, description=_doc)

# 15.5 with the (9.2) observer per DoF feeding the law's link model the external/link-side torque (15.3 "formally
# requires the measure of the external torque"): under a constant load it rests at the impedance's deflection (less
# the frictions' hold: Kp e = S^T tau_ext - (P S)^T (z + g), finger_backstepping)
register_controller("backstepping-load-observer",
                    _lazy("finger_backstepping", "finger_backstepping_controller", chain_keyword="params",
                          load_observer=FrictionObserverParams()),
                    rigs=("finger", "hand"), loop_options={"rate_hz": 3000.0},
                    description="15.5 backstepping with a (9.2) load observer per DoF (its link model gets the "
                                "link-side torque the sensed spring forces do not explain: the load and the "
                                "frictions); 3 kHz, joint angles estimated (5.15). Under a constant load it rests at "
                                "the impedance's deflection less what the guides' and the lever's friction hold")

# 15.5 with the (9.2) observer and its estimate, bounded by what the guides' friction and the lever's hysteresis can
# hold, added to the desired joint torque ((9.1), as the chain's default observer): inside the bound the rest is e = 0
# (finger_backstepping, FingerBacksteppingLaw.dead_band), where the plain law stops in its friction dead band
register_controller("backstepping-friction-observer",
                    _lazy("finger_backstepping", "finger_backstepping_controller", chain_keyword="params",
                          friction_observer=FrictionObserverParams()),
                    rigs=("finger", "hand"), loop_options={"rate_hz": 3000.0},
                    description="15.5 backstepping with the (9.2) observer per DoF in its link model and its "
                                "estimate, bounded by the guides' and the lever's friction, added to the desired "
                                "joint torque (9.1); 3 kHz, joint angles estimated (5.15)")

# Ch. 16 on every DoF of a finger/the hand: the 15.5 law above with its force-level gains (K3, K4) selected per DoF
# against a rate-limited LQR of the DoF's own one-link model (control/optimal_gains.py, select_finger_force_gains).
register_controller("optimal-backstepping", _lazy("optimal_gains", "finger_optimal_backstepping_controller",
                                                  chain_keyword="params"),
                    rigs=("finger", "hand"), loop_options={"rate_hz": 3000.0},
                    description="15.5 backstepping with K3, K4 per DoF selected by ch. 16 (least squares to the "
                                "DoF's LQR, Table 16.1 weights, R the most aggressive the 3 kHz loop follows); "
                                "impedance as backstepping")
