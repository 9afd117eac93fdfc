"""Analysis from the framework: linearisation, LQR, simulation (with monitors), sweeps."""

from awiwi_drake.analysis.linear import LinearizationResult, LqrResult, linearize, lqr, poles_table
from awiwi_drake.analysis.simulate import (
    Event, OverrangeMonitor, PairSlackMonitor, SaturationMonitor, SimulationDivergedError, SimulationResult, SlackMonitor, rig_monitors, simulate)
from awiwi_drake.analysis.sweep import run_sweep
