"""Sensor models inserted by :func:`awiwi_drake.control.base.closed_loop` (``sensors=``).

:func:`force_sensor` models the tendon force sensor of the hand (ch. 4, 10.4):
white Gaussian noise (Drake ``RandomSource``, sampled at 3 kHz) added to the
true force, then quantisation to ``full_scale / 2**bits``.
:func:`with_external_torque_sensor` gives a link rig an ideal external-torque
sensor (the measurement the backstepping design (15.62) formally requires).
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import DiagramBuilder, LeafSystem_
from pydrake.systems.primitives import PassThrough, RandomSource
from pydrake.systems.scalar_conversion import TemplateSystem
from pydrake.autodiffutils import AutoDiffXd

from awiwi_drake._math import is_float
from awiwi_drake.parameters.control import ForceSensorParams

__all__ = ["quantize", "Quantizer_", "Quantizer", "force_sensor", "with_external_torque_sensor"]


def quantize(x, resolution: float):
    """Round to the nearest multiple of ``resolution``.

    float: exact rounding.  AutoDiffXd: the value is rounded and the
    derivatives pass through unchanged (straight-through), so a linearisation
    through a quantiser sees the identity (the quantiser's average gain).
    """
    if resolution <= 0:
        raise ValueError(f"quantize: resolution = {resolution!r} must be > 0")
    if is_float(x):
        return np.round(np.asarray(x, float) / resolution) * resolution
    arr = np.asarray(x, dtype=object)
    out = np.empty(arr.shape, dtype=object)
    for idx in np.ndindex(arr.shape):
        xi = arr[idx]
        v = xi.value()
        out[idx] = xi + (float(np.round(v / resolution)) * resolution - v)
    return out


@TemplateSystem.define("Quantizer_", scope=sys.modules[__name__], T_list=[float, AutoDiffXd])
def Quantizer_(T):
    """``measured_value = quantize(true_value + noise_std * noise, resolution)``."""

    class Impl(LeafSystem_[T]):
        def _construct(self, size: int, resolution: float, noise_std: float = 0.0, converter=None):
            LeafSystem_[T].__init__(self, converter)
            if resolution <= 0 or not np.isfinite(resolution):
                raise ValueError(f"Quantizer: resolution = {resolution!r} must be > 0")
            if noise_std < 0 or not np.isfinite(noise_std):
                raise ValueError(f"Quantizer: noise_std = {noise_std!r} must be >= 0")
            self.size, self.resolution, self.noise_std = int(size), float(resolution), float(noise_std)
            self.u = self.DeclareVectorInputPort("true_value", self.size)
            self.n = self.DeclareVectorInputPort("noise", self.size)
            self.DeclareVectorOutputPort("measured_value", self.size, self._calc,
                                         prerequisites_of_calc={self.u.ticket(), self.n.ticket()})

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.size, other.resolution, other.noise_std, converter=converter)

        def _calc(self, context, output):
            x = self.u.Eval(context) + self.noise_std * self.n.Eval(context)
            output.SetFromVector(np.asarray(quantize(x, self.resolution)).reshape(-1))

    return Impl


Quantizer = Quantizer_[None]


def force_sensor(params: ForceSensorParams | None = None, size: int = 1):
    """A diagram ``true_value -> measured_value`` (noise + 12-bit quantisation)."""
    p = params or ForceSensorParams()
    builder = DiagramBuilder()
    q = builder.AddNamedSystem("quantizer", Quantizer(size, p.full_scale / 2 ** p.bits, p.noise_std))
    noise = builder.AddNamedSystem("noise", RandomSource(RandomDistribution.kGaussian, size, p.sample_period))
    builder.Connect(noise.get_output_port(0), q.GetInputPort("noise"))
    builder.ExportInput(q.GetInputPort("true_value"), "true_value")
    builder.ExportOutput(q.GetOutputPort("measured_value"), "measured_value")
    d = builder.Build()
    d.set_name("force_sensor")
    return d


def with_external_torque_sensor(rig):
    """A copy of a link rig whose diagram also outputs the applied ``external_torque`` as
    ``external_torque_measured`` (an ideal torque sensor: the thesis's formal design (15.62)).

    The external torque input is routed through a pass-through so that the controller can
    read it as a measurement (ctrl1's closed-loop convention: measurements are rig outputs).
    """
    if not rig.diagram.HasInputPort("external_torque"):
        raise ValueError(f"with_external_torque_sensor: rig {rig.name!r} has no input 'external_torque'")
    b = DiagramBuilder()
    inner = b.AddNamedSystem("plant", rig.diagram)
    tap = b.AddNamedSystem("external_torque_tap", PassThrough(inner.GetInputPort("external_torque").size()))
    b.ExportInput(tap.get_input_port(), "external_torque")
    b.Connect(tap.get_output_port(), inner.GetInputPort("external_torque"))
    b.ExportOutput(tap.get_output_port(), "external_torque_measured")
    for i in range(rig.diagram.num_input_ports()):
        name = rig.diagram.get_input_port(i).get_name()
        if name != "external_torque":
            b.ExportInput(inner.GetInputPort(name), name)
    for i in range(rig.diagram.num_output_ports()):
        name = rig.diagram.get_output_port(i).get_name()
        b.ExportOutput(inner.GetOutputPort(name), name)
    diagram = b.Build()
    diagram.set_name(rig.name)
    return dataclasses.replace(rig, diagram=diagram)
