"""Controller comparison: standard closed-loop tests, metrics table, plots.

* :mod:`.standard_tests` -- the tests (step, sine, disturbance, sweep), their defaults per rig kind
  (:func:`compare_test_params`), :func:`run_standard_tests`, :func:`compare`, :func:`compare_controllers`.
* :mod:`.metrics` -- step / sine / chirp metrics, :class:`Metrics`, :class:`MetricsTable` (CSV, Markdown).
* :mod:`.runner` -- the closed-loop simulation behind the tests (:func:`settle`).
* :mod:`.channels` -- the independent DoF of a finger/hand loop (one metrics row per joint).
* :mod:`.plots` -- :func:`plot_runs`, :func:`plot_joint_runs` (per finger), :func:`plot_gain_diagram`.

CLI: ``awiwi-drake compare``.
"""

from awiwi_drake.control.compare.metrics import (COLUMNS, NUMERIC, UNITS, Metrics, MetricsTable, fit_second_order_step,
                                                 gain_diagram, linear_bandwidth, response_bandwidth, sine_metrics,
                                                 step_metrics, sweep_metrics)
from awiwi_drake.control.compare.channels import JointChannels, joint_channels
from awiwi_drake.control.compare.plots import plot_gain_diagram, plot_joint_runs, plot_runs
from awiwi_drake.control.compare.runner import TestRun, settle
from awiwi_drake.control.compare.standard_tests import (TESTS, Comparison, build_loops, compare, compare_controllers,
                                                        compare_test_params, default_tests, design_step_duration,
                                                        design_stiffness, design_time_constant, dominant_time_constant,
                                                        factory_options, flag_run, load_stiffness_range,
                                                        run_joint_test, run_standard_tests, run_test, short_test_params,
                                                        size_loads, stopped_row)

__all__ = ["TESTS", "compare_test_params", "default_tests", "TestRun", "Metrics", "MetricsTable", "Comparison",
           "COLUMNS", "NUMERIC", "UNITS", "settle", "run_test", "flag_run", "stopped_row", "run_standard_tests",
           "compare", "build_loops", "compare_controllers", "factory_options", "step_metrics",
           "sine_metrics", "gain_diagram", "sweep_metrics", "response_bandwidth", "linear_bandwidth",
           "fit_second_order_step", "plot_runs", "plot_joint_runs", "plot_gain_diagram", "dominant_time_constant",
           "design_time_constant", "design_step_duration", "short_test_params", "run_joint_test", "joint_channels",
           "JointChannels", "design_stiffness", "size_loads", "load_stiffness_range"]
