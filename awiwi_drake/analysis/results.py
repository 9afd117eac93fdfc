"""The result of :func:`~awiwi_drake.analysis.simulate`: named signals with units, events, plot, save/load."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from awiwi_drake.analysis.monitors import Event

__all__ = ["SimulationResult", "UNITS", "unit", "checked_path"]

#: Units of the package's quantities by name: its ports (ARCHITECTURE.md: ports are physical quantities, SI) and the
#: base names of the one state-naming scheme (``rigs.base.state_names``: ``name[label]``).
UNITS = {
    "motor_torque": "Nm", "motor_torque_command": "Nm", "applied_torque": "Nm", "external_torque": "Nm",
    "joint_torque": "Nm", "generalized_force": "Nm", "load_torque": "Nm", "joint_friction_torque": "Nm",
    "tendon_force": "N", "hysteresis_force": "N", "guide_friction_force": "N",
    "tendon_stiffness": "N/m", "elongation": "m", "tendon_velocity": "m/s",
    "joint_angle": "rad", "motor_angle": "rad",
    "joint_velocity": "rad/s", "motor_velocity": "rad/s",
    "joint_stiffness": "Nm/rad", "wrist_angle": "rad", "wrist_velocity": "rad/s",
}


def unit(name: str) -> str:
    """Unit of a port or state entry by name (``UNITS``): a state entry ``name[label]`` by its base name,
    ``*_reference``/``*_command``/``*_measured``/``*_estimate`` and ``controller_*`` by the quantity's; ``-`` if
    the name is none of the package's."""
    base = name.split("[", 1)[0]
    for suffix in ("_reference", "_command", "_measured", "_estimate"):
        if base.endswith(suffix) and base[: -len(suffix)] in UNITS:
            base = base[: -len(suffix)]
    if base.startswith("controller_"):
        base = base[len("controller_"):]
    return UNITS.get(base, "-")


def checked_path(path, owner: str, suffixes: Sequence[str] = (), *, read: bool = False) -> Path:
    """``path`` as a Path, or a ValueError naming ``owner``: a file to read must exist; a file to write
    must end in one of ``suffixes`` and sit in an existing directory."""
    path = Path(path)
    if read:
        if not path.is_file():
            raise ValueError(f"{owner}: {str(path)!r} is not a file")
        return path
    if suffixes and path.suffix not in suffixes:
        raise ValueError(f"{owner}: {str(path)!r} must end in {' or '.join(suffixes)}")
    if not path.parent.is_dir():
        raise ValueError(f"{owner}: directory {str(path.parent)!r} does not exist")
    if path.is_dir():
        raise ValueError(f"{owner}: {str(path)!r} is a directory")
    return path


def _jsonable(v: Any):
    if isinstance(v, (np.floating, float)):
        return float(v) if math.isfinite(v) else str(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, np.ndarray):
        return [_jsonable(x) for x in v.tolist()]
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if v is None or isinstance(v, (bool, int, str)):
        return v
    if isinstance(v, (complex, np.complexfloating)):     # e.g. info["fastest_mode"]["mode"]: [real, imag]
        return [_jsonable(float(v.real)), _jsonable(float(v.imag))]
    return str(v)


@dataclass
class SimulationResult:
    """Logged signals and detected events of one run: ``t`` [s] (every integrator step, or every ``log_period``);
    ``signals`` (name -> (T, k) array per logged port or input schedule), their ``units`` (one per channel where they
    differ, e.g. ``state``) and channel ``labels`` (``state_names`` for ``state``, else ``port[i]``); the monitors'
    ``events`` in time order and ``limits`` (name -> [(description, value)], the thresholds watching each logged
    signal, in its unit, drawn by :meth:`plot`); ``info``, how the run was made (``mode``, ``integrator``, ``step``
    [s], ``accuracy``, ``wall_time`` [s], ``realtime_factor``, ``steps``: integrator steps, or discrete updates
    without continuous state, ``sampled_plants``: the plants integrated inside their discrete update, ...);
    ``final_context``, the simulated diagram's context at the end, and ``final_sampled_state``, the sampled plants'
    physical state then (:attr:`final_state`; neither is saved by :meth:`save`)."""

    t: np.ndarray
    signals: dict
    events: list = field(default_factory=list)
    final_context: Any = None
    units: dict = field(default_factory=dict)
    labels: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    limits: dict = field(default_factory=dict)
    final_sampled_state: np.ndarray | None = None

    # -- access ------------------------------------------------------------
    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.signals:
            raise KeyError(f"signal {name!r} was not logged; logged: {', '.join(self.signals) or 'nothing'}")
        return self.signals[name]

    def __contains__(self, name: str) -> bool:
        return name in self.signals

    @property
    def final_state(self) -> np.ndarray | None:
        """State at the end (None if no context was kept): the continuous state, then the state of each
        sampled plant (a rig integrated inside its discrete update, ``info["sampled_plants"]``,
        :attr:`final_sampled_state`: the physical state it outputs, while its discrete state in ``final_context``
        may be in integration coordinates, see :func:`~awiwi_drake.components.rig_system.rig_integration_system`)."""
        if self.final_context is None:
            return None
        x = self.final_context.get_continuous_state_vector().CopyToVector()
        sampled = self.final_sampled_state
        return x if sampled is None or not len(sampled) else np.concatenate([x, sampled])

    def events_of(self, kind: str) -> list:
        return [e for e in self.events if e.kind == kind]

    def unit(self, name: str, channel: int = 0) -> str:
        u = self.units.get(name, "-")
        return u[channel] if isinstance(u, (list, tuple)) else u

    def channel_labels(self, name: str) -> list[str]:
        k = self[name].shape[1]
        lab = list(self.labels.get(name, []))
        return lab if len(lab) == k else [f"{name}[{i}]" for i in range(k)]

    def resample(self, t: np.ndarray) -> "SimulationResult":
        """Signals linearly interpolated at times ``t`` (for comparisons and plots)."""
        t = np.asarray(t, float)
        out = {k: np.stack([np.interp(t, self.t, v[:, j]) for j in range(v.shape[1])], axis=1)
               for k, v in self.signals.items()}
        return SimulationResult(t, out, list(self.events), self.final_context, dict(self.units),
                                dict(self.labels), dict(self.info), dict(self.limits), self.final_sampled_state)

    def plot(self, names: Sequence[str] | None = None, **kw):
        """One subplot per signal (per unit for mixed signals such as ``state``): legends, units, monitor
        thresholds and events (:func:`awiwi_drake.plotting.plot_signals`, ``kw`` as there); ``(fig, axes)``."""
        from awiwi_drake.plotting import plot_signals
        return plot_signals(self, names, **kw)

    # -- save / load -------------------------------------------------------
    def _meta(self) -> dict:
        return dict(format="awiwi_drake.SimulationResult", version=1, signals=list(self.signals),
                    units=_jsonable(self.units), labels=_jsonable(self.labels),
                    events=[e.to_json() for e in self.events], info=_jsonable(self.info),
                    limits=_jsonable(self.limits))

    def save(self, path: str | Path) -> Path:
        """Write ``path`` (``.npz``: arrays; ``.csv``: one column per channel) and ``path + '.json'`` (units, labels,
        events, info, limits).

        Returns the data file's path.  The directory must exist.  A complex number in ``info`` (the fastest mode) is
        written as ``[real, imag]``.
        """
        path = checked_path(path, "SimulationResult.save", (".npz", ".csv"))
        meta = self._meta()
        if path.suffix == ".npz":
            np.savez(path, t=self.t, **{f"signal:{k}": v for k, v in self.signals.items()})
        else:
            cols, header = [self.t], ["time"]
            for k, v in self.signals.items():
                cols.append(v)
                header += [f"{k}[{j}]" for j in range(v.shape[1])]
            meta["columns"] = {k: v.shape[1] for k, v in self.signals.items()}
            np.savetxt(path, np.column_stack(cols), delimiter=",", header=",".join(header), comments="")
        Path(str(path) + ".json").write_text(json.dumps(meta, indent=1))
        return path

    @classmethod
    def load(cls, path: str | Path) -> "SimulationResult":
        """Read a result written by :meth:`save` (``final_context`` is None)."""
        path, side = (checked_path(p, "SimulationResult.load", read=True) for p in (path, str(path) + ".json"))
        try:
            meta = json.loads(side.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"SimulationResult.load: {str(side)!r} is not valid JSON: {exc}") from None
        if not isinstance(meta, dict) or meta.get("format") != "awiwi_drake.SimulationResult":
            raise ValueError(f"SimulationResult.load: {str(side)!r} is not a SimulationResult sidecar")
        if path.suffix == ".npz":
            with np.load(path) as z:
                t = np.asarray(z["t"])
                signals = {k: np.asarray(z[f"signal:{k}"]) for k in meta["signals"]}
        elif path.suffix == ".csv":
            data = np.atleast_2d(np.loadtxt(path, delimiter=",", skiprows=1))
            t, col, signals = data[:, 0], 1, {}
            for k in meta["signals"]:
                n = int(meta["columns"][k])
                signals[k] = data[:, col:col + n]
                col += n
        else:
            raise ValueError(f"SimulationResult.load: {str(path)!r} must end in .npz or .csv")
        events = [Event(**e) for e in meta.get("events", [])]
        limits = {k: [(str(d), float(v)) for d, v in lims] for k, lims in meta.get("limits", {}).items()}
        return cls(t, signals, events, None, meta.get("units", {}), meta.get("labels", {}), meta.get("info", {}),
                   limits)
