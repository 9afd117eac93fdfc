"""Controllers of the Awiwi hand (thesis ch. 3, 7-16) and the closed-loop tools.

* :mod:`.base` -- controller port conventions, :func:`closed_loop`.
* :mod:`.registry` -- ``name -> factory(rig)`` registry (CLI ``compare``).
* :mod:`.compare` -- standard tests, metrics table, plots.
"""

from awiwi_drake.control.base import (COMMAND_PORT, ClosedLoop, StaticLaw, StaticLawController,
                                      StaticLawController_, check_gain, check_gains, closed_loop)
from awiwi_drake.control.registry import (controller_names, get_entry, make_controller, register_controller,
                                          rig_kind)

__all__ = ["COMMAND_PORT", "ClosedLoop", "StaticLaw", "StaticLawController", "StaticLawController_",
           "check_gain", "check_gains", "closed_loop", "controller_names", "get_entry", "make_controller",
           "register_controller", "rig_kind"]
