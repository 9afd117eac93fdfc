"""Analysis from the framework: simulation (schedules, monitors, results), linearisation, LQR, sweeps."""

from awiwi_drake.analysis.linear import (
    LinearizationResult, LqrResult, PoleSweep, linearize, lqr, poles_table, poles_vs_pretension)
from awiwi_drake.analysis.monitors import (
    Event, Monitor, OverrangeMonitor, PairSlackMonitor, SaturationMonitor, SlackMonitor, rig_monitors)
from awiwi_drake.analysis.results import SimulationResult
from awiwi_drake.analysis.schedules import Chirp, Constant, PerEntry, Ramp, Samples, Sine, Step
from awiwi_drake.analysis.simulate import (
    PHYSICAL_FAILURES, FlatSystem, InfeasibleForceError, SimulationDivergedError, SimulationError,
    SimulationEventError, add_flat, control_period, fixed_step_substeps, simulate, stability_function)
from awiwi_drake.analysis.sweep import run_sweep
