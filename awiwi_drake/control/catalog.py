"""Built-in controller registrations (imported lazily by :mod:`.registry`).

Factories import their modules on call so that listing names stays cheap.
"""

from __future__ import annotations

from awiwi_drake.control.registry import register_controller

_JOINTS = ("flexible_joint", "joint_rig")
_SAMPLED = {"rate_hz": 3000.0}


def _tendon_pd(rig):
    from awiwi_drake.control.tendon_force import tendon_pd_controller
    return tendon_pd_controller(rig)


def _tendon_scheduled(rig):
    from awiwi_drake.control.tendon_force import tendon_scheduled_controller
    return tendon_scheduled_controller(rig)


def _tendon_sdre(rig):
    from awiwi_drake.control.sdre import tendon_sdre_controller
    return tendon_sdre_controller(rig)


def _impedance(mode):
    def factory(rig):
        from awiwi_drake.control.impedance import impedance_controller
        return impedance_controller(rig, mode=mode)
    factory.__name__ = f"_impedance_{mode.replace('-', '_')}"
    return factory


def _pole_placement(rig):
    from awiwi_drake.control.pole_placement import pole_placement_controller
    return pole_placement_controller(rig)


def _lqr(rig):
    from awiwi_drake.control.lqr import lqr_controller
    return lqr_controller(rig)


def _sdre(rig):
    from awiwi_drake.control.sdre import joint_sdre_controller
    return joint_sdre_controller(rig)


register_controller("tendon-pd", _tendon_pd, rigs=("tendon_rig",), loop_options=_SAMPLED,
                    description="(10.2) PD + force/friction feed-forward, gains (10.11) fixed at 30 N")
register_controller("tendon-scheduled", _tendon_scheduled, rigs=("tendon_rig",), loop_options=_SAMPLED,
                    description="(10.2) with gains (10.11) scheduled on the reference force (10.12)")
register_controller("tendon-sdre", _tendon_sdre, rigs=("tendon_rig",), loop_options=_SAMPLED,
                    description="SDRE tendon force control (14.7)-(14.9), Table 14.1, gains at 200 Hz")
register_controller("pd", _impedance("pd"), rigs=_JOINTS, loop_options=_SAMPLED,
                    description="PD on the motor angles towards the link reference (baseline)")
register_controller("two-time-scale", _impedance("two-time-scale"), rigs=_JOINTS, loop_options=_SAMPLED,
                    description="joint impedance (11.4) over a motor-position tendon loop (11.3)")
register_controller("cascaded", _impedance("cascaded"), rigs=_JOINTS, loop_options=_SAMPLED,
                    description="joint impedance (11.4) over a linearising force loop (11.16)")
register_controller("pole-placement", _pole_placement, rigs=_JOINTS, loop_options=_SAMPLED,
                    description="state feedback placing a double oscillator (12.13), Table 12.1")
register_controller("lqr", _lqr, rigs=_JOINTS, loop_options=_SAMPLED,
                    description="LQR on the linearised rig, Table 13.1 (Q=diag(10,.01,1,.01), R=0.01)")
register_controller("sdre", _sdre, rigs=_JOINTS, loop_options=_SAMPLED,
                    description="SDRE state feedback (14.10)-(14.12), Table 14.2, gains at 200 Hz")
