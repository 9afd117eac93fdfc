"""Datasets of the discrepancy workflow: ``NAME.csv`` + ``NAME.json``.

CSV: a header, first column ``time`` [s] (uniform, increasing), then one column
per signal (SI units).  JSON: ``{"rig": "tendon-rig"|"joint-rig"|"finger-<f>"|"hand", "parameters": {...},
"initial_state": {...}, "inputs": [...], "outputs": [...]}``.  Loading checks
everything and raises a ``ValueError`` naming the file, column or row.
"""

from __future__ import annotations

import json
import math
import pathlib
from dataclasses import dataclass, field

import numpy as np

__all__ = ["RigSpec", "RIGS", "Dataset", "load_dataset", "save_dataset", "dataset_paths", "check_plausibility",
           "finger_rig_name", "finger_parameters_to_json", "finger_parameters_from_json",
           "is_finger_rig", "rig_finger", "RIG_NAMES"]


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
    "tendon-rig": RigSpec(
        "tendon-rig", ("motor_torque",), ("motor_angle", "tendon_force"), ("motor_angle",),
        ("motor_inertia", "motor_damping", "motor_pulley_radius", "spring_poly"),
        ("motor_angle", "motor_velocity"), 1, False),
    "joint-rig": RigSpec(
        "joint-rig", ("motor_torque_1", "motor_torque_2"),
        ("motor_angle_1", "motor_angle_2", "tendon_force_1", "tendon_force_2", "joint_angle"),
        ("motor_angle_1", "motor_angle_2"),
        ("motor_inertia", "motor_damping", "motor_pulley_radius", "spring_poly",
         "link_inertia", "link_damping", "link_pulley_radius"),
        ("motor_angle_1", "motor_velocity_1", "motor_angle_2", "motor_velocity_2",
         "joint_angle", "joint_velocity"), 2, True),
}




def finger_rig_name(finger: str) -> str:
    """The dataset rig of one finger: ``finger-<finger>`` (e.g. ``finger-index``); the hand's is ``hand``."""
    return "hand" if finger == "hand" else f"finger-{finger}"


def is_finger_rig(rig: str) -> bool:
    """A finger's or the hand's dataset (motor torques in, motor angles and tendon forces out)."""
    return isinstance(rig, str) and (rig.startswith("finger-") or rig == "hand")


def rig_finger(rig: str) -> str:
    """``finger-index`` -> ``index``; ``hand`` -> ``hand``."""
    return "hand" if rig == "hand" else rig[len("finger-"):]


def _finger_spec(finger: str) -> RigSpec:
    """Columns of a finger dataset: the commanded torques of its ``m`` motors (inputs), their angles and
    the tendon forces (outputs, required), the ``n`` plant joint angles (optional: the hand has no joint
    sensors); numbered in the finger's tendon/joint order (``<finger>_h1...``, ``q..``)."""
    from awiwi_drake.hand.coupling import finger_coupling, hand_coupling
    c = hand_coupling() if finger == "hand" else finger_coupling(finger)
    m, n = c.num_tendons, c.num_joints
    angles = tuple(f"motor_angle_{i + 1}" for i in range(m))
    forces = tuple(f"tendon_force_{i + 1}" for i in range(m))
    return RigSpec(finger_rig_name(finger), tuple(f"motor_torque_{i + 1}" for i in range(m)),
                   angles + forces + tuple(f"joint_angle_{j + 1}" for j in range(n)), angles + forces,
                   ("finger", "finger_rig"), (), m, True)


class _Rigs(dict):
    """The dataset rigs; finger specs are built on first use (they read the finger's coupling)."""

    FINGERS = ("index", "middle", "ring", "fifth", "thumb")

    def __missing__(self, key):
        if is_finger_rig(key) and rig_finger(key) in self.FINGERS + ("hand",):
            self[key] = _finger_spec(rig_finger(key))
            return self[key]
        raise KeyError(key)

    def __contains__(self, key):
        return dict.__contains__(self, key) or (is_finger_rig(key) and rig_finger(key) in self.FINGERS + ("hand",))


RIGS = _Rigs(RIGS)


def finger_parameters_to_json(finger: str, params) -> dict:
    """The JSON ``parameters`` of a finger dataset: ``{"finger": name, "finger_rig": {...}}``, the
    :class:`~awiwi_drake.parameters.hand.FingerRigParams` as nested values (its YAML form: per-tendon
    overrides ``tendon_motors``/``tendon_springs`` as ``{tendon: {...}}``; the finger's geometry is the
    package's default of that finger and is not written). The hand (``finger`` ``"hand"``): its
    :class:`~awiwi_drake.parameters.hand.HandRigParams`, the same way (its geometry ``hand`` not written)."""
    import dataclasses
    import typing

    from awiwi_drake.parameters.yaml_io import named_overrides_class

    def plain(v):
        if dataclasses.is_dataclass(v):
            hints = typing.get_type_hints(type(v))
            return {f.name: ({k: plain(x) for k, x in getattr(v, f.name)} if named_overrides_class(hints[f.name])
                             else plain(getattr(v, f.name))) for f in dataclasses.fields(v)}
        if isinstance(v, tuple):
            return [plain(x) for x in v]
        return v
    d = {k: v for k, v in plain(params).items() if k not in ("finger", "finger_name", "hand")}
    return {"finger": finger, "finger_rig": d}


def finger_parameters_from_json(params: dict, where: str):
    """The :class:`~awiwi_drake.parameters.hand.FingerRigParams` of a finger dataset's ``parameters``
    (errors name the file and the key)."""
    from awiwi_drake.parameters.hand import FINGERS, FingerRigParams, HandRigParams
    from awiwi_drake.parameters.yaml_io import from_yaml
    if not isinstance(params, dict):
        raise ValueError(f"{where}: 'parameters' must be an object, got {type(params).__name__}")
    for k in ("finger", "finger_rig"):
        if k not in params:
            raise ValueError(f"{where}: missing parameter {k!r} (a finger dataset needs 'finger' and 'finger_rig')")
    unknown = sorted(set(params) - {"finger", "finger_rig"})
    if unknown:
        raise ValueError(f"{where}: unknown parameter {unknown[0]!r} (a finger dataset has 'finger', 'finger_rig')")
    if params["finger"] not in FINGERS + ("hand",):
        raise ValueError(f"{where}: parameter 'finger' = {params['finger']!r} is not one of {', '.join(FINGERS)}, "
                         f"hand")
    if not isinstance(params["finger_rig"], dict):
        raise ValueError(f"{where}: parameter 'finger_rig' must be an object (FingerRigParams fields)")
    rig = dict(params["finger_rig"])
    for bad in ("finger", "finger_name", "hand"):
        if bad in rig:
            raise ValueError(f"{where}: parameters.finger_rig.{bad}: not allowed (the finger is 'finger'; its "
                             f"geometry is the package's default)")
    base = HandRigParams() if params["finger"] == "hand" else FingerRigParams.for_finger(params["finger"])
    return from_yaml(base, json.dumps(rig), where=f"{where}: parameters.finger_rig")


# every dataset rig, in the package's one spelling of the rigs (Rig.name, the CLI's --rig)
RIG_NAMES = ("tendon-rig", "joint-rig", *(f"finger-{f}" for f in _Rigs.FINGERS), "hand")


@dataclass
class Dataset:
    """A measured (or generated) experiment.

    Attributes
    ----------
    name : str
        Stem of the files.
    rig : str
        One of :data:`RIG_NAMES` (``"tendon-rig"``, ``"joint-rig"``, ``"finger-<f>"``, ``"hand"``).
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


def _is_number(v) -> bool:
    """A real number that is not a bool (JSON ``true`` must not read as 1.0)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_parameters(rig: str, params, where: str, checks) -> dict:
    spec = RIGS[rig]
    if not isinstance(params, dict):
        raise ValueError(f"{where}: 'parameters' must be an object, got {type(params).__name__}")
    missing = [k for k in spec.parameters if k not in params]
    if missing:
        raise ValueError(f"{where}: missing parameter {missing[0]!r} for rig {rig!r} "
                         f"(needs {', '.join(spec.parameters)})")
    unknown = sorted(set(params) - set(spec.parameters))
    if unknown:
        raise ValueError(f"{where}: unknown parameter {unknown[0]!r} for rig {rig!r}")
    upper = {"motor_inertia": (checks.max_motor_inertia, "kg m^2"), "link_inertia": (checks.max_link_inertia, "kg m^2"),
             "motor_damping": (checks.max_damping, "Nm s/rad"), "link_damping": (checks.max_damping, "Nm s/rad"),
             "motor_pulley_radius": (checks.max_pulley_radius, "m"), "link_pulley_radius": (checks.max_pulley_radius, "m")}
    out = {}
    for k in spec.parameters:
        v = params[k]
        if k == "spring_poly":
            if not isinstance(v, list) or not v:
                raise ValueError(f"{where}: parameter 'spring_poly' must be a non-empty list [c1, c2, ...], "
                                 f"got {v!r}")
            for i, c in enumerate(v):
                if not _is_number(c):
                    raise ValueError(f"{where}: parameter 'spring_poly'[{i}] = {c!r} is not a number [N/m^{i + 1}]")
                if not math.isfinite(c) or abs(c) > checks.max_spring_coefficient:
                    raise ValueError(f"{where}: parameter 'spring_poly'[{i}] = {c!r} is not finite or larger than "
                                     f"{checks.max_spring_coefficient:g} [N/m^{i + 1}]")
            vals = [float(c) for c in v]
            if vals[0] <= 0:
                raise ValueError(f"{where}: parameter 'spring_poly' needs c1 > 0 (got {vals[0]})")
            out[k] = vals
            continue
        if not _is_number(v):
            raise ValueError(f"{where}: parameter {k!r} = {v!r} is not a number")
        x = float(v)
        if not math.isfinite(x):
            raise ValueError(f"{where}: parameter {k!r} is not finite")
        positive = k in ("motor_inertia", "motor_pulley_radius", "link_inertia", "link_pulley_radius")
        if (positive and x <= 0) or x < 0:
            raise ValueError(f"{where}: parameter {k!r} = {x} must be {'> 0' if positive else '>= 0'}")
        hi, unit = upper[k]
        if x > hi:
            raise ValueError(f"{where}: parameter {k!r} = {x:g} [{unit}] is implausibly large (> {hi:g}; "
                             f"DatasetChecks): check the unit")
        out[k] = x
    return out


def _read_text(path: pathlib.Path, read=lambda fh: fh.read()):
    """``read`` of the open file (UTF-8, a byte-order mark accepted, any line ends); errors name the file."""
    if path.is_dir():
        raise ValueError(f"{path}: is a directory, not a dataset file (a dataset is NAME.csv + NAME.json)")
    try:
        with open(path, encoding="utf-8-sig", newline=None) as fh:
            return read(fh)
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None


# columns of earlier datasets, renamed to the package's one name of the quantity (docs/ARCHITECTURE.md,
# "Joint vs link": a joint's angle and velocity are joint_*); refused with the new name, never read as an alias
RENAMED_COLUMNS = {"link_angle": "joint_angle", "link_velocity": "joint_velocity"}


def _refuse_renamed(names, where) -> None:
    old = next((n for n in names if n in RENAMED_COLUMNS), None)
    if old is not None:
        raise ValueError(f"{where}: {old!r} is now named {RENAMED_COLUMNS[old]!r} (rename it in NAME.csv's header "
                         f"and in NAME.json's outputs and initial_state)")


def _name_list(meta: dict, key: str, where) -> list:
    v = meta[key]
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise ValueError(f"{where}: {key!r} must be a list of names, e.g. [\"joint_angle\"], got {v!r}")
    return v


def _read_csv(csv_path: pathlib.Path) -> tuple[list, np.ndarray]:
    """Header and numeric table of the CSV, streamed: memory is about one float64 array.

    A bad row is named (a second, line-by-line pass runs only then).
    """
    def read(fh):
        head_line = fh.readline().strip()
        if not head_line:
            raise ValueError(f"{csv_path}: empty file (or empty header line)")
        header = [h.strip() for h in head_line.split(",")]
        try:
            return header, np.loadtxt(fh, delimiter=",", dtype=float, ndmin=2)
        except ValueError:
            return header, None

    header, data = _read_text(csv_path, read)
    ncol = len(header)
    if data is not None and (data.size == 0 or data.shape[1] == ncol):
        return header, data.reshape(-1, ncol) if data.size else np.zeros((0, ncol))
    with open(csv_path, encoding="utf-8-sig", newline=None) as fh:
        fh.readline()
        for i, line in enumerate(fh, start=2):
            if not line.strip():
                continue
            cells = line.split(",")
            if len(cells) != ncol:
                raise ValueError(f"{csv_path}: row {i} has {len(cells)} cells, header has {ncol}")
            for c, cell in zip(header, cells):
                try:
                    float(cell)
                except ValueError:
                    raise ValueError(f"{csv_path}: row {i}, column {c!r}: not a number: {cell.strip()!r}") from None
    raise ValueError(f"{csv_path}: cannot read the table")  # pragma: no cover - loadtxt and the scan disagree


def load_dataset(path, *, checks=None) -> Dataset:
    """Read and validate ``NAME.csv`` + ``NAME.json``.

    Besides the format (columns, rows, uniform time, types), the data must be
    plausible for the declared units and the nominal model
    (:func:`check_plausibility`, limits in
    :class:`~awiwi_drake.parameters.discrepancy.DatasetChecks`).  Files may be
    UTF-8 with or without a byte-order mark, with LF or CRLF line ends.

    Raises
    ------
    FileNotFoundError
        When either file is missing.
    ValueError
        Naming the file and the column/row/key at fault.
    """
    from awiwi_drake.parameters.discrepancy import DatasetChecks

    checks = checks or DatasetChecks()
    csv_path, json_path = dataset_paths(path)
    if pathlib.Path(path).is_dir():
        raise ValueError(f"{path}: is a directory; give NAME.csv (with NAME.json beside it)")
    for p in (csv_path, json_path):
        if not p.exists():
            raise FileNotFoundError(f"{p}: no such file (a dataset is NAME.csv + NAME.json)")
    try:
        meta = json.loads(_read_text(json_path))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{json_path}: invalid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{json_path}: top level must be an object")
    for key in ("rig", "parameters", "initial_state", "inputs", "outputs"):
        if key not in meta:
            raise ValueError(f"{json_path}: missing key {key!r}")
    rig = meta["rig"]
    if not isinstance(rig, str):
        raise ValueError(f"{json_path}: 'rig' must be a name ({', '.join(RIG_NAMES)}), got {rig!r}")
    if rig not in RIGS:
        raise ValueError(f"{json_path}: unknown rig {rig!r} (known: {', '.join(RIG_NAMES)})")
    spec = RIGS[rig]
    if is_finger_rig(rig):
        fp = finger_parameters_from_json(meta["parameters"], str(json_path))
        if finger_rig_name(meta["parameters"]["finger"]) != rig:
            raise ValueError(f"{json_path}: parameter 'finger' = {meta['parameters']['finger']!r} but rig is {rig!r}")
        params = finger_parameters_to_json(meta["parameters"]["finger"], fp)
    else:
        params = _check_parameters(rig, meta["parameters"], str(json_path), checks)
    inputs, outputs = _name_list(meta, "inputs", json_path), _name_list(meta, "outputs", json_path)
    if sorted(inputs) != sorted(spec.inputs):
        raise ValueError(f"{json_path}: 'inputs' must be {list(spec.inputs)} for rig {rig!r}, got {inputs}")
    _refuse_renamed(outputs + list(meta["initial_state"] if isinstance(meta["initial_state"], dict) else ()), json_path)
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
        if not _is_number(init[k]):
            raise ValueError(f"{json_path}: initial_state {k!r} = {init[k]!r} is not a number")
        if not math.isfinite(init[k]):
            raise ValueError(f"{json_path}: initial_state {k!r} is not finite")
    unknown = sorted(set(init) - set(spec.initial_state))
    if unknown:
        raise ValueError(f"{json_path}: unknown initial_state key {unknown[0]!r}")

    # ---- CSV
    header, data = _read_csv(csv_path)
    if header[0] != "time":
        raise ValueError(f"{csv_path}: first column must be 'time', got {header[0]!r}")
    if len(set(header)) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise ValueError(f"{csv_path}: duplicate column {dup!r}")
    _refuse_renamed(header, csv_path)
    expected = set(inputs) | set(outputs)
    for col in header[1:]:
        if col not in expected:
            raise ValueError(f"{csv_path}: unknown column {col!r} (JSON lists inputs {inputs} "
                             f"and outputs {outputs})")
    for col in sorted(expected):
        if col not in header:
            raise ValueError(f"{csv_path}: missing column {col!r}")
    bad_rows, bad_cols = np.nonzero(~np.isfinite(data))
    if bad_rows.size:
        i, j = int(bad_rows[0]), int(bad_cols[0])
        raise ValueError(f"{csv_path}: row {i + 2}, column {header[j]!r}: value {data[i, j]} is not finite")
    if len(data) < 3:
        raise ValueError(f"{csv_path}: needs at least 3 rows of data, got {len(data)}")
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
    check_plausibility(ds, checks, where=str(csv_path))
    return ds


def check_plausibility(ds: Dataset, checks=None, *, where: str | None = None) -> None:
    """Reject a dataset whose numbers cannot be what its JSON declares.

    Checks (limits in :class:`~awiwi_drake.parameters.discrepancy.DatasetChecks`):
    excitation present (the commanded torques vary), every measured column
    varies (a sensor is connected), magnitudes plausible for SI units (torques,
    link angle excursion, motor angle excursion times the pulley radius) and
    measured tendon forces within ``force_ratio`` of the nominal spring force
    at the largest elongation the measured angles imply.  Raises a
    ``ValueError`` naming the column and the likely unit mistake.
    """
    from awiwi_drake.parameters.discrepancy import DatasetChecks

    c = checks or DatasetChecks()
    where = where or ds.name
    u = ds.input_matrix
    if np.all(np.ptp(u, axis=0) == 0.0):
        raise ValueError(f"{where}: no excitation: the commanded torques ({', '.join(ds.spec.inputs)}) are "
                         f"constant over the whole recording; nothing can be identified")
    for k, v in list(ds.inputs.items()) + list(ds.outputs.items()):
        if np.ptp(v) == 0.0 and k in ds.outputs:
            raise ValueError(f"{where}: column {k!r} is constant ({v[0]:g}) over the whole recording: "
                             f"no sensor signal")
    big = float(np.max(np.abs(u)))
    if big > c.max_torque:
        col = ds.spec.inputs[int(np.argmax(np.max(np.abs(u), axis=0)))]
        raise ValueError(f"{where}: column {col!r} reaches {big:.3g} Nm (> {c.max_torque:g} Nm): not a motor "
                         f"torque in Nm")
    if is_finger_rig(ds.rig):
        _check_finger_plausibility(ds, c, where)
        return
    p = ds.parameters
    if "joint_angle" in ds.outputs:
        span = float(np.ptp(ds.outputs["joint_angle"]))
        if span > c.max_angle_excursion:
            raise ValueError(f"{where}: column 'joint_angle' spans {span:.3g} rad (> {c.max_angle_excursion:g}): "
                             f"angles must be in rad (degrees are 57x larger)")
    rm = p["motor_pulley_radius"]
    elong = 0.0
    for k in ds.output_names:
        if k.startswith("motor_angle"):
            travel = rm * float(np.max(np.abs(ds.outputs[k])))
            if travel > c.max_elongation:
                raise ValueError(f"{where}: column {k!r} moves the tendon by r_m * max|angle| = {travel:.3g} m "
                                 f"(> {c.max_elongation:g} m): motor angles must be in rad, or "
                                 f"motor_pulley_radius is wrong")
            elong = max(elong, travel)
    if "joint_angle" in ds.outputs:
        elong += p["link_pulley_radius"] * float(np.max(np.abs(ds.outputs["joint_angle"])))
    forces = [k for k in ds.output_names if k.startswith("tendon_force")]
    if forces and elong > 0:
        nominal = sum(ck * elong ** (i + 1) for i, ck in enumerate(p["spring_poly"]))
        for k in forces:
            peak = float(np.max(np.abs(ds.outputs[k])))
            ratio = peak / nominal if nominal > 0 else math.inf
            if not (1.0 / c.force_ratio <= ratio <= c.force_ratio):
                raise ValueError(f"{where}: column {k!r} peaks at {peak:.3g} N, {ratio:.3g}x the nominal spring "
                                 f"force at the measured elongation ({nominal:.3g} N): forces must be in N "
                                 f"(kN or mN?), or spring_poly/angles are in other units")


def _check_finger_plausibility(ds: Dataset, c, where: str) -> None:
    """Finger datasets: angles in rad (joint excursion, motor travel at the pulley), forces in N
    (within the spring mechanism's range, none far below zero)."""
    fp = finger_parameters_from_json(ds.parameters, where)
    rm = fp.motor.pulley_radius
    for k, v in ds.outputs.items():
        if k.startswith("joint_angle") and float(np.ptp(v)) > c.max_angle_excursion:
            raise ValueError(f"{where}: column {k!r} spans {float(np.ptp(v)):.3g} rad (> {c.max_angle_excursion:g}): "
                             f"angles must be in rad (degrees are 57x larger)")
        if k.startswith("motor_angle") and rm * float(np.max(np.abs(v))) > c.max_elongation:
            raise ValueError(f"{where}: column {k!r} moves the tendon by r_m * max|angle| = "
                             f"{rm * float(np.max(np.abs(v))):.3g} m (> {c.max_elongation:g} m): motor angles must "
                             f"be in rad")
        if k.startswith("tendon_force"):
            peak = float(np.max(np.abs(v)))
            if peak > c.force_ratio * fp.spring.max_force or peak < fp.spring.max_force / (100 * c.force_ratio):
                raise ValueError(f"{where}: column {k!r} peaks at {peak:.3g} N against the spring mechanism's "
                                 f"{fp.spring.max_force:g} N range: forces must be in N (kN or mN?)")


def save_dataset(ds: Dataset, directory, name: str | None = None) -> pathlib.Path:
    """Write ``NAME.csv`` + ``NAME.json`` into ``directory``; returns the CSV path.

    A generated dataset's answer (``meta["truth"]``: the hidden effects and their
    parameters) goes to a separate ``NAME.truth.json``, so that the data handed to
    :func:`~awiwi_drake.discrepancy.diagnose` does not contain it.
    """
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
    meta.update({k: v for k, v in ds.meta.items() if not k.startswith("clean_") and k != "truth"})
    (d / f"{name}.json").write_text(json.dumps(meta, indent=1, default=float))
    if "truth" in ds.meta:
        (d / f"{name}.truth.json").write_text(json.dumps(ds.meta["truth"], indent=1, default=float))
    return csv_path
