"""Datasets of the discrepancy workflow: ``NAME.csv`` + ``NAME.json``.

CSV: a header, first column ``time`` [s] (uniform, increasing), then one column
per signal (SI units).  JSON: ``{"rig": "tendon"|"joint", "parameters": {...},
"initial_state": {...}, "inputs": [...], "outputs": [...]}``.  Loading checks
everything and raises a ``ValueError`` naming the file, column or row.
"""

from __future__ import annotations

import json
import math
import pathlib
from dataclasses import dataclass, field

import numpy as np

__all__ = ["RigSpec", "RIGS", "Dataset", "load_dataset", "save_dataset", "dataset_paths"]


@dataclass(frozen=True)
class RigSpec:
    """Names of one rig's inputs, possible outputs, parameters and initial state."""

    name: str
    inputs: tuple
    outputs: tuple
    required_outputs: tuple
    parameters: tuple
    initial_state: tuple
    num_motors: int
    has_link: bool


RIGS = {
    "tendon": RigSpec(
        "tendon", ("motor_torque",), ("motor_angle", "tendon_force"), ("motor_angle",),
        ("motor_inertia", "motor_damping", "motor_pulley_radius", "spring_poly"),
        ("motor_angle", "motor_velocity"), 1, False),
    "joint": RigSpec(
        "joint", ("motor_torque_1", "motor_torque_2"),
        ("motor_angle_1", "motor_angle_2", "tendon_force_1", "tendon_force_2", "link_angle"),
        ("motor_angle_1", "motor_angle_2"),
        ("motor_inertia", "motor_damping", "motor_pulley_radius", "spring_poly",
         "link_inertia", "link_damping", "link_pulley_radius"),
        ("motor_angle_1", "motor_velocity_1", "motor_angle_2", "motor_velocity_2",
         "link_angle", "link_velocity"), 2, True),
}


@dataclass
class Dataset:
    """A measured (or generated) experiment.

    Attributes
    ----------
    name : str
        Stem of the files.
    rig : str
        ``"tendon"`` or ``"joint"``.
    time : ndarray (N,)
        Uniform sample times [s].
    inputs : dict[str, ndarray]
        Commanded motor torques [Nm] (zero-order hold between samples).
    outputs : dict[str, ndarray]
        Measured signals (SI).
    parameters : dict
        Nominal model parameters (see :data:`RIGS`).
    initial_state : dict[str, float]
        State at ``time[0]``.
    meta : dict
        Anything else of the JSON (the generator stores the hidden truth here).
    """

    name: str
    rig: str
    time: np.ndarray
    inputs: dict
    outputs: dict
    parameters: dict
    initial_state: dict
    meta: dict = field(default_factory=dict)

    @property
    def spec(self) -> RigSpec:
        return RIGS[self.rig]

    @property
    def dt(self) -> float:
        return float(self.time[1] - self.time[0])

    @property
    def input_matrix(self) -> np.ndarray:
        """Inputs as an (N, num_inputs) array in the rig's input order."""
        return np.column_stack([self.inputs[k] for k in self.spec.inputs])

    @property
    def output_names(self) -> list:
        return [k for k in self.spec.outputs if k in self.outputs]

    def slice(self, start: int, stop: int) -> "Dataset":
        """Samples ``start:stop`` as a new dataset (initial state not updated)."""
        return Dataset(self.name, self.rig, self.time[start:stop].copy(),
                       {k: v[start:stop].copy() for k, v in self.inputs.items()},
                       {k: v[start:stop].copy() for k, v in self.outputs.items()},
                       dict(self.parameters), dict(self.initial_state), dict(self.meta))


def dataset_paths(path) -> tuple[pathlib.Path, pathlib.Path]:
    """``(csv, json)`` paths of a dataset given either file or the stem."""
    p = pathlib.Path(path)
    stem = p.with_suffix("") if p.suffix.lower() in (".csv", ".json") else p
    # append, never replace: a stem may contain dots (``run_x0.5``)
    return stem.with_name(stem.name + ".csv"), stem.with_name(stem.name + ".json")


def _check_parameters(rig: str, params: dict, where: str) -> dict:
    spec = RIGS[rig]
    if not isinstance(params, dict):
        raise ValueError(f"{where}: 'parameters' must be an object")
    missing = [k for k in spec.parameters if k not in params]
    if missing:
        raise ValueError(f"{where}: missing parameter {missing[0]!r} for rig {rig!r} "
                         f"(needs {', '.join(spec.parameters)})")
    unknown = sorted(set(params) - set(spec.parameters))
    if unknown:
        raise ValueError(f"{where}: unknown parameter {unknown[0]!r} for rig {rig!r}")
    out = {}
    for k in spec.parameters:
        v = params[k]
        if k == "spring_poly":
            if not isinstance(v, (list, tuple)) or not v:
                raise ValueError(f"{where}: parameter 'spring_poly' must be a non-empty list [c1, c2, ...]")
            vals = [float(c) for c in v]
            if not all(math.isfinite(c) for c in vals):
                raise ValueError(f"{where}: parameter 'spring_poly' has a non-finite coefficient")
            if vals[0] <= 0:
                raise ValueError(f"{where}: parameter 'spring_poly' needs c1 > 0 (got {vals[0]})")
            out[k] = vals
            continue
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: parameter {k!r} = {v!r} is not a number") from None
        if not math.isfinite(x):
            raise ValueError(f"{where}: parameter {k!r} is not finite")
        positive = k in ("motor_inertia", "motor_pulley_radius", "link_inertia", "link_pulley_radius")
        if (positive and x <= 0) or x < 0:
            raise ValueError(f"{where}: parameter {k!r} = {x} must be {'> 0' if positive else '>= 0'}")
        out[k] = x
    return out


def load_dataset(path) -> Dataset:
    """Read and validate ``NAME.csv`` + ``NAME.json``.

    Raises
    ------
    FileNotFoundError
        When either file is missing.
    ValueError
        Naming the file and the column/row/key at fault.
    """
    csv_path, json_path = dataset_paths(path)
    for p in (csv_path, json_path):
        if not p.exists():
            raise FileNotFoundError(f"{p}: no such file (a dataset is NAME.csv + NAME.json)")
    try:
        meta = json.loads(json_path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{json_path}: invalid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{json_path}: top level must be an object")
    for key in ("rig", "parameters", "initial_state", "inputs", "outputs"):
        if key not in meta:
            raise ValueError(f"{json_path}: missing key {key!r}")
    rig = meta["rig"]
    if rig not in RIGS:
        raise ValueError(f"{json_path}: unknown rig {rig!r} (known: {', '.join(RIGS)})")
    spec = RIGS[rig]
    params = _check_parameters(rig, meta["parameters"], str(json_path))
    inputs, outputs = list(meta["inputs"]), list(meta["outputs"])
    if sorted(inputs) != sorted(spec.inputs):
        raise ValueError(f"{json_path}: 'inputs' must be {list(spec.inputs)} for rig {rig!r}, got {inputs}")
    bad = [o for o in outputs if o not in spec.outputs]
    if bad:
        raise ValueError(f"{json_path}: unknown output {bad[0]!r} for rig {rig!r} "
                         f"(known: {', '.join(spec.outputs)})")
    for req in spec.required_outputs:
        if req not in outputs:
            raise ValueError(f"{json_path}: output {req!r} is required by the workflow "
                             f"(window starts are re-initialised from it)")
    init = meta["initial_state"]
    if not isinstance(init, dict):
        raise ValueError(f"{json_path}: 'initial_state' must be an object")
    for k in spec.initial_state:
        if k not in init:
            raise ValueError(f"{json_path}: initial_state misses {k!r}")
        if not math.isfinite(float(init[k])):
            raise ValueError(f"{json_path}: initial_state {k!r} is not finite")
    unknown = sorted(set(init) - set(spec.initial_state))
    if unknown:
        raise ValueError(f"{json_path}: unknown initial_state key {unknown[0]!r}")

    # ---- CSV
    lines = csv_path.read_text().splitlines()
    if not lines:
        raise ValueError(f"{csv_path}: empty file")
    header = [h.strip() for h in lines[0].split(",")]
    if header[0] != "time":
        raise ValueError(f"{csv_path}: first column must be 'time', got {header[0]!r}")
    if len(set(header)) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise ValueError(f"{csv_path}: duplicate column {dup!r}")
    expected = set(inputs) | set(outputs)
    for col in header[1:]:
        if col not in expected:
            raise ValueError(f"{csv_path}: unknown column {col!r} (JSON lists inputs {inputs} "
                             f"and outputs {outputs})")
    for col in sorted(expected):
        if col not in header:
            raise ValueError(f"{csv_path}: missing column {col!r}")
    rows = []
    for i, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != len(header):
            raise ValueError(f"{csv_path}: row {i} has {len(cells)} cells, header has {len(header)}")
        try:
            vals = [float(c) for c in cells]
        except ValueError:
            raise ValueError(f"{csv_path}: row {i}: not a number in {line!r}") from None
        for c, v in zip(header, vals):
            if not math.isfinite(v):
                raise ValueError(f"{csv_path}: row {i}, column {c!r}: value {v} is not finite")
        rows.append(vals)
    if len(rows) < 3:
        raise ValueError(f"{csv_path}: needs at least 3 rows of data, got {len(rows)}")
    data = np.asarray(rows)
    t = data[:, 0]
    dts = np.diff(t)
    if np.any(dts <= 0):
        i = int(np.argmax(dts <= 0)) + 3
        raise ValueError(f"{csv_path}: row {i}: time is not increasing ({t[i - 3]} -> {t[i - 2]})")
    dt = float(np.median(dts))
    dev = np.abs(dts - dt) > 1e-6 * max(dt, 1e-12) + 1e-9
    if np.any(dev):
        i = int(np.argmax(dev)) + 3
        raise ValueError(f"{csv_path}: row {i}: time step {dts[i - 3]:.6g} s differs from "
                         f"{dt:.6g} s (time must be uniform)")
    cols = {c: data[:, j] for j, c in enumerate(header)}
    ds = Dataset(csv_path.stem, rig, t, {k: cols[k] for k in spec.inputs},
                 {k: cols[k] for k in spec.outputs if k in outputs}, params,
                 {k: float(init[k]) for k in spec.initial_state},
                 {k: v for k, v in meta.items()
                  if k not in ("rig", "parameters", "initial_state", "inputs", "outputs")})
    return ds


def save_dataset(ds: Dataset, directory, name: str | None = None) -> pathlib.Path:
    """Write ``NAME.csv`` + ``NAME.json`` into ``directory``; returns the CSV path."""
    d = pathlib.Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    name = name or ds.name
    cols = ["time"] + list(ds.spec.inputs) + ds.output_names
    table = np.column_stack([ds.time] + [ds.inputs[k] for k in ds.spec.inputs]
                            + [ds.outputs[k] for k in ds.output_names])
    csv_path = d / f"{name}.csv"
    np.savetxt(csv_path, table, delimiter=",", header=",".join(cols), comments="", fmt="%.10g")
    meta = {"rig": ds.rig, "parameters": ds.parameters, "initial_state": ds.initial_state,
            "inputs": list(ds.spec.inputs), "outputs": ds.output_names}
    meta.update({k: v for k, v in ds.meta.items() if not k.startswith("clean_")})
    (d / f"{name}.json").write_text(json.dumps(meta, indent=1, default=float))
    return csv_path
