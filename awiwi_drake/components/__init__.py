"""Physical components: laws (pure functions) and their LeafSystems (thesis ch. 3-5)."""

from awiwi_drake.components.fused_drive import DriveModel, TendonDrive
from awiwi_drake.components.motor import (
    motor_acceleration, motor_friction_torque, motor_ripple_torque, reflected_inertia,
    saturate_torque)
from awiwi_drake.components.routing import ConstantCoupling, TendonRouting, TendonRouting_, antagonistic_coupling
from awiwi_drake.components.spring import (
    AntagonisticPairSpring, LeverSpringMechanism, LinearSpring, PolynomialSpring, SpringBank, SpringBank_,
    TendonSprings, hysteresis_rate, tendon_spring)
from awiwi_drake.components.friction import (
    atan_friction, capstan_friction_force, guide_friction, guide_friction_force, regularized_sign, stribeck_friction)
from awiwi_drake.components.tendon import series_stiffness, tendon_stiffness
