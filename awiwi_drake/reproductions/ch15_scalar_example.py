"""The scalar backstepping example of section 15.1 ((15.1)-(15.10), after Khalil [84, p. 489]).

Plant (15.1): ``x1' = -x1^3 + x1^2 + x2``, ``x2' = u``.
Virtual control (15.2): ``x2* = -x1^2 - k1 x1``; error ``z2 = x2 - x2*``.

Two versions of the final law:

* ``variant="textbook"`` (default): ``u = x2*' - x1 - k2 z2``. The ``-x1`` term cancels
  the cross term ``x1 z2`` of ``V2' `` so that ``V2 = (x1^2 + z2^2)/2`` has
  ``V2' = -x1^4 - k1 x1^2 - k2 z2^2 <= 0`` (Khalil's derivation).
* ``variant="printed"``: (15.10) as printed, ``u = x2*' - k2 z2``. The thesis's
  (15.4)-(15.9) drop the cross term; the loop is still globally asymptotically
  stable (``z2`` decays exponentially and drives an input-to-state stable
  ``x1`` subsystem), but ``V2`` need not decrease monotonically; the weighted
  ``x1^2/2 + c z2^2/2`` with ``4 k1 k2 c > 1`` does.
"""

from __future__ import annotations

import sys

import numpy as np
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.parameters.backstepping import ScalarExampleGains

__all__ = ["example_dynamics", "example_control", "ScalarExamplePlant_", "ScalarExamplePlant",
           "ScalarBackstepping_", "ScalarBackstepping", "VARIANTS"]

VARIANTS = ("textbook", "printed")


def example_dynamics(x, u):
    """Right-hand side of (15.1): returns ``[x1', x2']``."""
    return [-x[0] ** 3 + x[0] ** 2 + x[1], u]


def example_control(x, gains: ScalarExampleGains, variant: str = "textbook"):
    """Control law (15.10) and Lyapunov value ``V2 = (x1^2 + z2^2)/2`` (15.6).

    Returns ``(u, V2)``.
    """
    if variant not in VARIANTS:
        raise ValueError(f"example_control: variant must be one of {VARIANTS}, got {variant!r}")
    x1, x2 = x[0], x[1]
    k1, k2 = gains.k1, gains.k2
    x1d = example_dynamics(x, 0.0)[0]
    alpha = -x1 * x1 - k1 * x1                 # (15.2)
    alpha_d = (-2.0 * x1 - k1) * x1d
    z2 = x2 - alpha
    u = alpha_d - k2 * z2                      # (15.10)
    if variant == "textbook":
        u = u - x1
    return u, 0.5 * (x1 * x1 + z2 * z2)


@TemplateSystem.define("ScalarExamplePlant_", scope=sys.modules[__name__])
def ScalarExamplePlant_(T):
    class Impl(LeafSystem_[T]):
        """Plant (15.1). Input ``motor_torque`` (1) = ``u``; output ``state`` (2) = ``[x1, x2]``."""

        def _construct(self, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.DeclareVectorInputPort("motor_torque", 1)
            state = self.DeclareContinuousState(2)
            self.DeclareStateOutputPort("state", state)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, converter=converter)

        def DoCalcTimeDerivatives(self, context, derivatives):
            x = context.get_continuous_state_vector().CopyToVector()
            u = self.get_input_port(0).Eval(context)[0]
            derivatives.get_mutable_vector().SetFromVector(np.array(example_dynamics(x, u), dtype=x.dtype))

    return Impl


ScalarExamplePlant = ScalarExamplePlant_[None]


@TemplateSystem.define("ScalarBackstepping_", scope=sys.modules[__name__])
def ScalarBackstepping_(T):
    class Impl(LeafSystem_[T]):
        """Controller (15.10). Input ``state`` (2); outputs ``motor_torque`` (1) = ``u``, ``lyapunov`` (1)."""

        def _construct(self, gains=None, variant="textbook", converter=None):
            LeafSystem_[T].__init__(self, converter)
            if variant not in VARIANTS:
                raise ValueError(f"ScalarBackstepping: variant must be one of {VARIANTS}, got {variant!r}")
            self.gains = gains or ScalarExampleGains()
            self.variant = variant
            self.DeclareVectorInputPort("state", 2)
            tickets = {self.all_input_ports_ticket()}
            self.DeclareVectorOutputPort("motor_torque", 1, self._calc_u, prerequisites_of_calc=tickets)
            self.DeclareVectorOutputPort("lyapunov", 1, self._calc_v, prerequisites_of_calc=tickets)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.gains, other.variant, converter=converter)

        def _calc_u(self, context, output):
            output.SetAtIndex(0, example_control(self.get_input_port(0).Eval(context), self.gains, self.variant)[0])

        def _calc_v(self, context, output):
            output.SetAtIndex(0, example_control(self.get_input_port(0).Eval(context), self.gains, self.variant)[1])

    return Impl


ScalarBackstepping = ScalarBackstepping_[None]
