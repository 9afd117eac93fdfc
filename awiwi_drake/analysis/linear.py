"""The one linearisation / LQR API: Drake's ``Linearize`` and ``LinearQuadraticRegulator`` on any plant.

:func:`linearize` (at a rig's operating point, its context from :meth:`Rig.context`, or any system at a
given context) returns a :class:`LinearizationResult`: named states, inputs and outputs, the point
``(x0, u0)``, ``damp()``, ``bode()`` (a :class:`FrequencyResponse`) and ``to_control()`` (python-control,
optional extra).  :func:`lqr` returns an :class:`LqrResult` (``u = u0 - K (x - x0)``, the Riccati solution
``S``, the closed loop); :func:`lqr_gain` is the same on bare matrices (state-dependent Riccati, ch. 14).
Poles within round-off of zero are reported as exactly 0 (:func:`clean_poles`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from pydrake.systems.controllers import LinearQuadraticRegulator
from pydrake.systems.framework import Context, OutputPortSelection, System
from pydrake.systems.primitives import Linearize

from awiwi_drake.analysis.results import checked_path

__all__ = ["LinearizationResult", "OutputMap", "DampRow", "DampTable", "FrequencyResponse", "LqrResult",
           "linearize", "lqr", "lqr_gain", "closed_loop_poles", "clean_poles", "poles_table", "PoleSweep",
           "poles_vs_pretension"]

_EPS = np.finfo(float).eps


def clean_poles(poles: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Poles sorted by real then imaginary part, with parts within round-off of zero set to 0.

    ``scale`` is the norm of the matrix they came from (round-off ~ ``100 n eps scale``).
    """
    p = np.asarray(poles, dtype=complex).ravel()
    tol = 100.0 * max(len(p), 1) * _EPS * max(float(scale), 1.0)
    re = np.where(np.abs(p.real) < tol, 0.0, p.real)
    im = np.where(np.abs(p.imag) < tol, 0.0, p.imag)
    p = re + 1j * im
    return p[np.lexsort((p.imag, p.real))]


def closed_loop_poles(A: np.ndarray, B: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Eigenvalues of ``A - B K`` (sorted, round-off zeros cleaned)."""
    M = np.asarray(A, float) - np.asarray(B, float) @ np.atleast_2d(np.asarray(K, float))
    return clean_poles(np.linalg.eigvals(M), np.linalg.norm(M, 1) if M.size else 1.0)


def _fmt_pole(p: complex) -> str:
    if p.imag == 0:
        return f"{p.real: .6g}"
    return f"{p.real: .6g} {'+' if p.imag >= 0 else '-'} {abs(p.imag):.6g}j"


@dataclass(frozen=True)
class OutputMap:
    """Rows of one output port: ``y = y0 + C dx + D du``; ``names`` label the channels."""

    C: np.ndarray
    D: np.ndarray
    y0: np.ndarray
    names: tuple


@dataclass(frozen=True)
class DampRow:
    """One pole: natural frequency ``wn = |p|`` [rad/s], damping ratio ``zeta = -Re p / |p|``,
    time constant ``tau = -1 / Re p`` [s] (inf on the imaginary axis, negative when unstable)."""

    pole: complex
    natural_frequency: float
    damping_ratio: float
    time_constant: float

    @property
    def natural_frequency_hz(self) -> float:
        return self.natural_frequency / (2 * math.pi)


class DampTable(tuple):
    """The damping table of a linear model (as ``damp`` in MATLAB / python-control): a tuple of :class:`DampRow`."""

    def __str__(self) -> str:
        lines = [f"{'pole [1/s]':>28} {'wn [rad/s]':>12} {'wn [Hz]':>10} {'zeta [-]':>9} {'tau [s]':>11}"]
        for r in self:
            zeta = "-" if math.isnan(r.damping_ratio) else f"{r.damping_ratio:.4g}"
            tau = "inf" if math.isinf(r.time_constant) else f"{r.time_constant:.4g}"
            lines.append(f"{_fmt_pole(r.pole):>28} {r.natural_frequency:12.5g} {r.natural_frequency_hz:10.4g} "
                         f"{zeta:>9} {tau:>11}")
        return "\n".join(lines)

    def to_json(self) -> list:
        return [dict(pole=[r.pole.real, r.pole.imag], natural_frequency=r.natural_frequency,
                     damping_ratio=None if math.isnan(r.damping_ratio) else r.damping_ratio,
                     time_constant=None if math.isinf(r.time_constant) else r.time_constant) for r in self]


def _crossings(w: np.ndarray, g: np.ndarray, level: float) -> list[tuple[int, float]]:
    """Indices and log-interpolated frequencies where ``g`` crosses ``level``."""
    s = g - level
    out = []
    for i in np.nonzero(np.sign(s[:-1]) * np.sign(s[1:]) < 0)[0]:
        a = s[i] / (s[i] - s[i + 1])
        out.append((int(i), float(np.exp(np.log(w[i]) + a * (np.log(w[i + 1]) - np.log(w[i]))))))
    return out


@dataclass(frozen=True)
class FrequencyResponse:
    """``H(j w) = C (j w I - A)^-1 B + D`` of one input channel (``input_name``) to one output channel
    (``output_name``): ``response`` ``H(j omega)`` (complex, output unit per input unit) at the log-spaced
    frequencies ``omega`` [rad/s]."""

    omega: np.ndarray
    response: np.ndarray
    input_name: str
    output_name: str

    @property
    def frequency_hz(self) -> np.ndarray:
        return self.omega / (2 * math.pi)

    @property
    def magnitude_db(self) -> np.ndarray:
        return 20.0 * np.log10(np.abs(self.response))

    @property
    def phase_deg(self) -> np.ndarray:
        """Unwrapped phase [deg], starting in (-180, 180]."""
        return np.degrees(np.unwrap(np.angle(self.response)))

    def margins(self) -> dict:
        """Gain and phase margins of the loop ``L = H`` under unity negative feedback.

        ``gain_margin`` (factor) and ``gain_margin_db`` at the first phase
        crossover (phase = -180 deg mod 360) ``phase_crossover`` [rad/s];
        ``phase_margin`` [deg] = 180 + phase at the first gain crossover
        (|H| = 1) ``gain_crossover`` [rad/s]; inf / NaN where there is no
        crossing in the frequency range.  Values are interpolated between the
        grid points (log frequency).
        """
        w, mag, ph = self.omega, np.abs(self.response), self.phase_deg
        out = dict(gain_margin=math.inf, gain_margin_db=math.inf, phase_crossover=math.nan,
                   phase_margin=math.inf, gain_crossover=math.nan)
        # phase crossovers: phase = -180 + 360 k
        best = None
        for k in range(int(np.floor((ph.min() + 180) / 360)), int(np.ceil((ph.max() + 180) / 360)) + 1):
            for i, wc in _crossings(w, ph, -180.0 + 360.0 * k):
                if best is None or wc < best[1]:
                    best = (i, wc)
        if best is not None:
            gm = 1.0 / float(np.exp(np.interp(np.log(best[1]), np.log(w), np.log(mag))))
            out.update(gain_margin=gm, gain_margin_db=20 * math.log10(gm), phase_crossover=best[1])
        cross = _crossings(w, np.log(mag), 0.0)
        if cross:
            i, wc = cross[0]
            phc = float(np.interp(np.log(wc), np.log(w), ph))
            pm = (phc + 180.0) % 360.0
            out.update(phase_margin=pm if pm <= 180.0 else pm - 360.0, gain_crossover=wc)
        return out

    def plot(self, *, ax=None, hz: bool = True, label: str | None = None, margins: bool = True):
        """Bode diagram: magnitude [dB] and phase [deg] on a log frequency axis; returns ``(fig, (ax_mag, ax_phase))``."""
        from awiwi_drake.plotting import figure_axes
        fig, ax = figure_axes(ax, nrows=2, figsize=(6.5, 5.0), sharex=True)
        x = self.frequency_hz if hz else self.omega
        lab = label or f"{self.output_name} / {self.input_name}"
        ax[0].semilogx(x, self.magnitude_db, label=lab)
        ax[1].semilogx(x, self.phase_deg, label=lab)
        ax[0].set_ylabel("magnitude [dB]")
        ax[1].set_ylabel("phase [deg]")
        ax[1].set_xlabel("frequency [Hz]" if hz else "frequency [rad/s]")
        if margins:
            m = self.margins()
            sc = 1 / (2 * math.pi) if hz else 1.0
            if math.isfinite(m["gain_crossover"]):
                ax[1].axvline(m["gain_crossover"] * sc, color="tab:green", ls=":",
                              label=f"phase margin {m['phase_margin']:.1f} deg")
            if math.isfinite(m["phase_crossover"]):
                ax[0].axvline(m["phase_crossover"] * sc, color="tab:red", ls=":",
                              label=f"gain margin {m['gain_margin_db']:.1f} dB")
        for a in ax:
            a.grid(True, which="both", alpha=0.3)
            a.legend(fontsize=8)
        return fig, ax

    def to_json(self) -> dict:
        m = {k: (None if not math.isfinite(v) else v) for k, v in self.margins().items()}
        return dict(input=self.input_name, output=self.output_name, omega=self.omega.tolist(),
                    magnitude_db=self.magnitude_db.tolist(), phase_deg=self.phase_deg.tolist(), margins=m)


class _JsonFile:
    """``save(path)`` / ``load(path)``: one ``.json`` file of ``to_json()`` / ``from_json()``."""

    def save(self, path: str | Path) -> Path:
        """Write :meth:`to_json` to ``path`` (``.json``); read it back with :meth:`load`."""
        path = checked_path(path, f"{type(self).__name__}.save", (".json",))
        path.write_text(json.dumps(self.to_json(), indent=1))
        return path

    @classmethod
    def load(cls, path: str | Path):
        path = checked_path(path, f"{cls.__name__}.load", read=True)
        try:
            return cls.from_json(json.loads(path.read_text()))
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{cls.__name__}.load: {str(path)!r} is not a saved {cls.__name__} "
                             f"({type(exc).__name__}: {exc})") from None


@dataclass(frozen=True)
class LinearizationResult(_JsonFile):
    """``xdot = f0 + A dx + B du``, ``y = y0 + C dx + D du`` around ``(x0, u0)``, from Drake's ``Linearize``.

    ``C, D`` are of the first output port (``state`` for rigs), ``outputs`` holds every linearised port (name ->
    :class:`OutputMap`); ``state_names``, ``input_names`` (``motor_torque[i]``) and ``output_names`` (the channels
    of ``C``) name the rows and columns; ``f0`` is ``xdot`` at the point (0 at an equilibrium); ``input_port`` the
    linearised input and ``operating_point`` the rig's :class:`OperatingPoint` (None for a bare system)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    state_names: tuple
    input_names: tuple = ()
    output_names: tuple = ()
    x0: np.ndarray = field(default_factory=lambda: np.zeros(0))
    u0: np.ndarray = field(default_factory=lambda: np.zeros(0))
    f0: np.ndarray = field(default_factory=lambda: np.zeros(0))
    outputs: dict = field(default_factory=dict)
    operating_point: Any = None
    input_port: str = "motor_torque"

    @property
    def poles(self) -> np.ndarray:
        """Eigenvalues of A, sorted, round-off zeros set to 0."""
        return clean_poles(np.linalg.eigvals(self.A), np.linalg.norm(self.A, 1) if self.A.size else 1.0)

    def plot(self, ax=None, *, label: str = "poles", **kw):
        """Pole map in the s-plane with rays of constant damping ratio (:func:`awiwi_drake.plotting.plot_poles`;
        ``symlog=``, ``damping=``, marker style); the numbers are :meth:`damp`; returns ``(fig, ax)``."""
        from awiwi_drake.plotting import plot_poles
        return plot_poles(self.poles, ax, label=label, **kw)

    def output(self, name: str) -> OutputMap:
        """The rows of output port ``name`` (clear error naming the linearised outputs)."""
        if name not in self.outputs:
            raise ValueError(f"linearisation has no output {name!r}; linearised outputs: {', '.join(self.outputs)} "
                             f"(pass outputs=(..., {name!r}) to linearize)")
        return self.outputs[name]

    def damp(self) -> DampTable:
        """Natural frequency, damping ratio and time constant of every pole."""
        rows = []
        for p in self.poles:
            wn = abs(p)
            zeta = -p.real / wn + 0.0 if wn > 0 else math.nan   # + 0.0: no "-0"
            tau = -1.0 / p.real if p.real != 0 else math.inf
            rows.append(DampRow(complex(p), float(wn), float(zeta), float(tau)))
        return DampTable(tuple(rows))

    def _channel(self, which, names: Sequence[str], kind: str) -> int:
        if isinstance(which, (int, np.integer)) and not isinstance(which, bool):
            if not 0 <= which < len(names):
                raise ValueError(f"bode: {kind} channel {which} out of range 0..{len(names) - 1} ({', '.join(names)})")
            return int(which)
        if which in names:
            return list(names).index(which)
        if len(names) == 1 and which in (f"{names[0]}[0]", names[0].split("[")[0]):   # x == x[0] for one channel
            return 0
        raise ValueError(f"bode: unknown {kind} {which!r}; {kind}s: {', '.join(names)}")

    def bode(self, input=0, output=None, *, omega: Sequence[float] | None = None, n: int = 400) -> FrequencyResponse:  # noqa: A002
        """Frequency response from one ``input`` channel (index or name, e.g. ``"motor_torque[0]"``) to one
        ``output`` channel: a name (of ``output_names`` or of any linearised port, e.g. ``"joint_angle"``), an index
        into ``output_names``, or None (the first channel of the first output port), at ``omega`` [rad/s] (default
        ``n`` log-spaced points from a decade below the slowest non-zero pole to a decade above the fastest)."""
        iu = self._channel(input, self.input_names, "input")
        if output is None:
            c, d, oname = self.C[0], self.D[0], self.output_names[0] if self.output_names else "y[0]"
        else:
            rows = {nm: (self.C[i], self.D[i]) for i, nm in enumerate(self.output_names)}
            for port, om in self.outputs.items():
                for i, nm in enumerate(om.names):
                    rows.setdefault(nm, (om.C[i], om.D[i]))
                if len(om.names) == 1:
                    rows.setdefault(port, (om.C[0], om.D[0]))
                    rows.setdefault(f"{port}[0]", (om.C[0], om.D[0]))
            if isinstance(output, (int, np.integer)) and not isinstance(output, bool):
                output = self.output_names[self._channel(output, self.output_names, "output")]
            if output not in rows:
                raise ValueError(f"bode: unknown output {output!r}; outputs: {', '.join(rows)}")
            (c, d), oname = rows[output], output
        if omega is None:
            mags = np.abs(self.poles)
            nz = mags[mags > 0]
            lo = 0.1 * (nz.min() if nz.size else 1.0)
            hi = 10.0 * (nz.max() if nz.size else 1.0)
            omega = np.logspace(np.log10(lo), np.log10(hi), int(n))
        w = np.asarray(omega, dtype=float).ravel()
        if w.size == 0 or np.any(~np.isfinite(w)) or np.any(w <= 0):
            raise ValueError("bode: omega must be finite frequencies > 0 [rad/s]")
        nx = self.A.shape[0]
        b = self.B[:, iu]
        H = np.array([c @ np.linalg.solve(1j * wk * np.eye(nx) - self.A, b) + d[iu] for wk in w])
        return FrequencyResponse(w, H, self.input_names[iu], oname)

    def to_control(self):
        """The model as a python-control ``StateSpace`` (``pip install awiwi_drake[control]``)."""
        try:
            import control
        except ImportError:
            raise ImportError("to_control() needs python-control: pip install 'awiwi_drake[control]'") from None
        return control.ss(self.A, self.B, self.C, self.D, states=list(self.state_names),
                          inputs=list(self.input_names), outputs=list(self.output_names))

    def to_json(self) -> dict:
        poles = [[float(p.real), float(p.imag)] for p in self.poles]
        return dict(A=self.A.tolist(), B=self.B.tolist(), C=self.C.tolist(), D=self.D.tolist(),
                    state_names=list(self.state_names), input_names=list(self.input_names),
                    output_names=list(self.output_names), x0=np.asarray(self.x0).tolist(),
                    u0=np.asarray(self.u0).tolist(), f0=np.asarray(self.f0).tolist(), poles=poles,
                    damp=self.damp().to_json(), input_port=self.input_port,
                    outputs={k: dict(C=v.C.tolist(), D=v.D.tolist(), y0=np.asarray(v.y0).tolist(), names=list(v.names))
                             for k, v in self.outputs.items()})

    @classmethod
    def from_json(cls, d: dict) -> "LinearizationResult":
        outs = {k: OutputMap(np.atleast_2d(np.array(v["C"], float)), np.atleast_2d(np.array(v["D"], float)),
                             np.array(v["y0"], float), tuple(v["names"])) for k, v in d.get("outputs", {}).items()}
        return cls(np.atleast_2d(np.array(d["A"], float)), np.atleast_2d(np.array(d["B"], float)),
                   np.atleast_2d(np.array(d["C"], float)), np.atleast_2d(np.array(d["D"], float)),
                   tuple(d["state_names"]), tuple(d.get("input_names", ())), tuple(d.get("output_names", ())),
                   np.array(d.get("x0", []), float), np.array(d.get("u0", []), float),
                   np.array(d.get("f0", []), float), outs, None, d.get("input_port", "motor_torque"))


def _channel_names(port_name: str, size: int, names: Sequence[str] = ()) -> tuple:
    if len(names) == size:
        return tuple(names)
    return (port_name,) if size == 1 else tuple(f"{port_name}[{i}]" for i in range(size))


def _constant_outputs(system, ctx, in_port, outputs) -> set:
    """The ``outputs`` that depend on neither the continuous state nor ``in_port`` (their C and D are zero).

    Drake 1.51.1's ``Linearize`` crashes the process (segmentation fault) on such a port: its AutoDiffXd
    value carries no derivatives at all, and the empty gradient is read as if it had a column per state and
    input (reproduced with an ``Integrator`` beside a ``ConstantVectorSource``; on the hand, the wrist's
    ``wrist_tendon_offset``, fed by the fixed ``wrist_angle`` input only).  Found by one AutoDiffXd
    evaluation with a single seed direction on the state (continuous or discrete) and the input: an entry that
    depends on either carries a derivative, even where it is zero.
    """
    from pydrake.autodiffutils import AutoDiffXd

    def seeded(v, d):
        return np.array([AutoDiffXd(float(a), d) for a in np.asarray(v, float).ravel()], dtype=object)

    ad = system.ToAutoDiffXd()
    actx = ad.CreateDefaultContext()
    actx.SetTimeStateAndParametersFrom(ctx)
    ad.FixInputPortsFrom(system, ctx, actx)                  # every fixed input, vector or abstract, no derivatives
    ad.get_input_port(in_port.get_index()).FixValue(actx, seeded(in_port.Eval(ctx), [1.0]))
    if ctx.num_continuous_states():
        actx.SetContinuousState(seeded(ctx.get_continuous_state_vector().CopyToVector(), [1.0]))
    for g in range(ctx.num_discrete_state_groups()):         # a sampled system's state (Linearize's discrete case)
        actx.SetDiscreteState(g, seeded(ctx.get_discrete_state(g).CopyToVector(), [1.0]))
    return {name for name in outputs
            if all(e.derivatives().size == 0 for e in np.ravel(ad.GetOutputPort(name).Eval(actx)))}


def linearize(plant, op=None, *, context: Context | None = None, input: str = "motor_torque",  # noqa: A002
              outputs: Sequence[str] | None = None, state: Sequence[float] | None = None,
              motor_torque: Sequence[float] | None = None,
              equilibrium_tolerance: float | None = 1e-6) -> LinearizationResult:
    """Linearise ``plant`` with Drake's ``Linearize``.

    A rig (finger, hand) is linearised at ``op`` (default: its default operating point) in the context
    :meth:`Rig.context` builds, or at ``context`` (one you prepared); a bare Drake System at ``context`` (default:
    its default context, inputs fixed there).  ``input``: the input port (other inputs keep their fixed values);
    ``outputs``: the output ports linearised, the first gives ``C, D`` (default: ``state`` if the system has it, else
    its first output port).  ``state`` / ``motor_torque`` override the point's state / input value (a
    non-equilibrium point: the equilibrium check is skipped and ``f0`` holds ``xdot``); otherwise Drake checks
    ``|xdot| <= equilibrium_tolerance`` at the point (None: no check).
    """
    if isinstance(plant, System):
        system, names = plant, ()
        ctx = (context.Clone() if context is not None else system.CreateDefaultContext())
        op = None
    else:
        system = getattr(plant, "diagram", None)
        if not isinstance(system, System):
            raise ValueError(f"linearize: expected a Rig or a Drake System, got {type(plant).__name__}")
        names = tuple(plant.state_names)
        if context is not None:
            ctx = context.Clone()
        else:
            op = plant.operating_point() if op is None else op
            ctx = plant.context(op)
    if not system.HasInputPort(input):
        ins = [system.get_input_port(i).get_name() for i in range(system.num_input_ports())]
        raise ValueError(f"linearize: {system.get_name()!r} has no input port {input!r}; inputs: {', '.join(ins)}")
    in_port = system.GetInputPort(input)
    if outputs is None:
        outputs = ("state",) if system.HasOutputPort("state") or system.num_output_ports() == 0 else \
            (system.get_output_port(0).get_name(),)
    outputs = tuple(outputs)
    if not outputs:
        raise ValueError("linearize: outputs must name at least one output port")
    for name in outputs:
        if not system.HasOutputPort(name):
            outs = [system.get_output_port(i).get_name() for i in range(system.num_output_ports())]
            raise ValueError(f"linearize: {system.get_name()!r} has no output port {name!r}; outputs: {', '.join(outs)}")
    if state is not None:
        x = np.asarray(state, float).reshape(-1)
        if x.size != ctx.num_continuous_states():
            raise ValueError(f"linearize: state has {x.size} entries, the system has {ctx.num_continuous_states()}")
        ctx.SetContinuousState(x)
    if motor_torque is not None:
        u = np.asarray(motor_torque, float).reshape(-1)
        if u.size != in_port.size():
            raise ValueError(f"linearize: {input} has {u.size} entries, the port has {in_port.size()}")
        in_port.FixValue(ctx, u)
    if not in_port.HasValue(ctx):
        raise ValueError(f"linearize: input port {input!r} has no value in the context (fix it or give an op)")
    tol = None if (state is not None or motor_torque is not None) else equilibrium_tolerance
    maps = {}
    A = B = None
    constant = _constant_outputs(system, ctx, in_port, outputs)
    for k, name in enumerate(outputs):
        if k > 0 and name in constant:
            lin = None
        else:
            try:
                lin = Linearize(system, ctx, input_port_index=in_port.get_index(),
                                output_port_index=(OutputPortSelection.kNoOutput if name in constant
                                                   else system.GetOutputPort(name).get_index()),
                                equilibrium_check_tolerance=tol if (k == 0 and tol is not None) else math.inf)
            except RuntimeError as exc:
                raise ValueError(f"linearize: {system.get_name()!r}: {exc}") from None
        if k == 0:
            A, B = np.array(lin.A()), np.array(lin.B())
        y0 = np.array(system.GetOutputPort(name).Eval(ctx), float).reshape(-1)
        cn = _channel_names(name, y0.size, names if name == "state" else ())
        C, D = ((np.zeros((y0.size, A.shape[0])), np.zeros((y0.size, in_port.size()))) if name in constant
                else (np.array(lin.C()), np.array(lin.D())))
        maps[name] = OutputMap(C, D, y0, cn)
    x0 = ctx.get_continuous_state_vector().CopyToVector()
    u0 = np.array(in_port.Eval(ctx), float).reshape(-1)
    f0 = system.EvalTimeDerivatives(ctx).CopyToVector() if x0.size else np.zeros(0)
    first = maps[outputs[0]]
    snames = names if len(names) == x0.size else tuple(f"x[{i}]" for i in range(x0.size))
    return LinearizationResult(A, B, first.C, first.D, snames, _channel_names(input, u0.size), first.names,
                               x0, u0, f0, maps, op, input)


def _check_weights(Q, R, n, m, owner: str = "lqr"):
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    R = np.atleast_2d(np.asarray(R, dtype=float))
    if Q.shape == (1, n) or (Q.shape == (n, 1) and n > 1):
        Q = np.diag(Q.ravel())
    if R.shape == (1, m) and m > 1:
        R = np.diag(R.ravel())
    if Q.shape != (n, n):
        raise ValueError(f"{owner}: Q must be {n}x{n} (or {n} diagonal entries), got shape {Q.shape}")
    if R.shape != (m, m):
        raise ValueError(f"{owner}: R must be {m}x{m} (or {m} diagonal entries), got shape {R.shape}")
    if not (np.all(np.isfinite(Q)) and np.all(np.isfinite(R))):
        raise ValueError(f"{owner}: Q and R must be finite")
    if not np.allclose(Q, Q.T) or np.min(np.linalg.eigvalsh(0.5 * (Q + Q.T))) < -1e-12 * max(1.0, np.abs(Q).max()):
        raise ValueError(f"{owner}: Q must be symmetric positive semi-definite")
    if not np.allclose(R, R.T) or np.min(np.linalg.eigvalsh(0.5 * (R + R.T))) <= 0:
        raise ValueError(f"{owner}: R must be symmetric positive definite")
    return Q, R


def lqr_gain(A, B, Q, R) -> tuple[np.ndarray, np.ndarray]:
    """``(K, S)`` from Drake's ``LinearQuadraticRegulator(A, B, Q, R)`` (``u = -K x``); weights validated."""
    A = np.atleast_2d(np.asarray(A, float))
    B = np.asarray(B, float).reshape(A.shape[0], -1)
    Q, R = _check_weights(Q, R, A.shape[0], B.shape[1])
    try:
        K, S = LinearQuadraticRegulator(A, B, Q, R)
    except RuntimeError as exc:
        raise ValueError(f"lqr: no stabilising solution (is (A, B) stabilisable, (A, Q) detectable?): {exc}") from None
    return np.asarray(K), np.asarray(S)


@dataclass(frozen=True)
class LqrResult(_JsonFile):
    """LQR design at an operating point: ``u = u0 - K (x - x0)``.

    ``S`` solves the continuous algebraic Riccati equation; the optimal cost
    from an initial deviation ``dx`` is ``dx^T S dx``.  ``closed_loop`` is the
    linear closed loop ``xdot = (A - B K) dx + B v`` (input ``v`` added to the
    command) with the same outputs, so ``design.closed_loop.damp()`` and
    ``.bode()`` work as for the plant.
    """

    K: np.ndarray
    S: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    linearization: LinearizationResult

    @property
    def closed_loop(self) -> LinearizationResult:
        lin = self.linearization
        BK = lin.B @ self.K
        outs = {k: replace(v, C=v.C - v.D @ self.K) for k, v in lin.outputs.items()}
        return replace(lin, A=lin.A - BK, C=lin.C - lin.D @ self.K, outputs=outs)

    @property
    def closed_loop_poles(self) -> np.ndarray:
        return closed_loop_poles(self.linearization.A, self.linearization.B, self.K)

    def plot(self, ax=None, **kw):
        """Open-loop (o) and closed-loop (x) poles on one s-plane map (:meth:`LinearizationResult.plot`)."""
        fig, ax = self.linearization.plot(ax, label="open loop", marker="o", mfc="none", **kw)
        return self.closed_loop.plot(ax, label="closed loop (LQR)", **{**kw, "damping": ()})

    def to_json(self) -> dict:
        return dict(K=self.K.tolist(), S=self.S.tolist(), Q=self.Q.tolist(), R=self.R.tolist(),
                    closed_loop_poles=[[float(p.real), float(p.imag)] for p in self.closed_loop_poles],
                    state_names=list(self.linearization.state_names), linearization=self.linearization.to_json())

    @classmethod
    def from_json(cls, d: dict) -> "LqrResult":
        return cls(np.atleast_2d(np.array(d["K"], float)), np.atleast_2d(np.array(d["S"], float)),
                   np.atleast_2d(np.array(d["Q"], float)), np.atleast_2d(np.array(d["R"], float)),
                   LinearizationResult.from_json(d["linearization"]))


def lqr(plant, Q, R, op=None, *, context: Context | None = None, input: str = "motor_torque",  # noqa: A002
        linearization: LinearizationResult | None = None) -> LqrResult:
    """LQR from Drake's ``LinearQuadraticRegulator`` on the :func:`linearize` model of ``plant`` at ``op``.

    ``Q`` (n x n or n diagonal entries), ``R`` (m x m or m entries); pass
    ``linearization`` to reuse one.  ``plant`` may be ``None`` when a
    linearisation is given.
    """
    lin = linearization if linearization is not None else linearize(plant, op, context=context, input=input)
    K, S = lqr_gain(lin.A, lin.B, Q, R)
    Qm, Rm = _check_weights(Q, R, lin.A.shape[0], lin.B.shape[1])
    return LqrResult(K, S, Qm, Rm, lin)


@dataclass
class PoleSweep:
    """Poles (rows, sorted as in :attr:`LinearizationResult.poles`) and joint stiffness of a rig's
    linearisation at each pretension [N] (``joint_stiffness``: the operating points' [Nm/rad])."""

    pretension: np.ndarray
    poles: np.ndarray
    joint_stiffness: np.ndarray

    def max_frequency(self) -> np.ndarray:
        """Largest |imag| [rad/s] per pretension (the stiffest link mode)."""
        return np.max(np.abs(self.poles.imag), axis=1)

    def plot(self, ax=None, **kw):
        """Root locus over the pretension (:func:`awiwi_drake.plotting.plot_poles`; ``symlog=``)."""
        from awiwi_drake.plotting import plot_poles
        return plot_poles(self.poles, ax, values=self.pretension, name="pretension [N]", **kw)


def poles_vs_pretension(rig, pretensions) -> PoleSweep:
    """Linearise ``rig`` (any rig, a finger, the hand) at its operating point (joints at 0) for each
    pretension [N]: stiffness tuning by co-contraction."""
    pre = np.asarray(pretensions, dtype=float)
    ops = [rig.operating_point(pretension=float(f)) for f in pre]
    return PoleSweep(pre, np.array([linearize(rig, op).poles for op in ops]),
                     np.array([op.joint_stiffness for op in ops]))


def poles_table(result: LinearizationResult) -> str:
    """Poles as text lines ``re +- im j`` (round-off zeros print as 0)."""
    return "\n".join(f"  {_fmt_pole(p)}" for p in result.poles)
