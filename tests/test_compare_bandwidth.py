"""-3 dB bandwidth of the compare tool against closed forms: from the linearisation (continuous loops)
and from the chirp response on a log-spaced frequency grid (sampled loops)."""

import math

import numpy as np
import pytest


def _lin(A, B, C, D):
    from awiwi_drake.analysis import LinearizationResult
    A = np.atleast_2d(np.asarray(A, float))
    return LinearizationResult(A, np.atleast_2d(np.asarray(B, float)).reshape(A.shape[0], 1),
                               np.atleast_2d(np.asarray(C, float)), np.atleast_2d(np.asarray(D, float)),
                               tuple(f"x{i}" for i in range(A.shape[0])), ("r[0]",), ("y[0]",))


def _second_order_bandwidth(wn, xi):
    """|wn^2 / (s^2 + 2 xi wn s + wn^2)| = 1/sqrt 2 at w = wn sqrt(1 - 2 xi^2 + sqrt(4 xi^4 - 4 xi^2 + 2))."""
    return wn * math.sqrt(1 - 2 * xi ** 2 + math.sqrt(4 * xi ** 4 - 4 * xi ** 2 + 2)) / (2 * math.pi)


def test_linear_bandwidth_of_a_first_order_loop_is_a_over_2pi():
    from awiwi_drake.control.compare import linear_bandwidth

    for a, k in ((2 * math.pi * 3.3, 1.0), (157.0, 0.8), (4000.0, 2.5)):   # DC gain k != 1 too
        bw = linear_bandwidth(_lin([[-a]], [[a * k]], [[1.0]], [[0.0]]))
        assert bw == pytest.approx(a / (2 * math.pi), rel=1e-8), (a, bw)


def test_linear_bandwidth_of_a_second_order_loop_is_its_closed_form():
    from awiwi_drake.control.compare import linear_bandwidth

    for wn, xi in ((60.0, 0.2), (60.0, 0.7), (300.0, 1.0), (25.0, 2.0)):   # resonant, flat, critical, overdamped
        A = [[0.0, 1.0], [-wn ** 2, -2 * xi * wn]]
        bw = linear_bandwidth(_lin(A, [[0.0], [wn ** 2]], [[1.0, 0.0]], [[0.0]]))
        assert bw == pytest.approx(_second_order_bandwidth(wn, xi), rel=1e-8), (wn, xi, bw)
    # a pole at the origin has no DC gain: NaN, not a number from the grid
    assert math.isnan(linear_bandwidth(_lin([[0.0]], [[1.0]], [[1.0]], [[0.0]])))


def _chirp_response(a_num, a_den, fs=3000.0, T=4.0, f0=1.0, f1=70.0):
    """A linear chirp through a transfer function, sampled at fs (a 3 kHz loop's records)."""
    from scipy import signal
    t = np.arange(0.0, T, 1.0 / fs)
    r = signal.chirp(t, f0, T, f1, method="linear", phi=-90.0)
    _, y, _ = signal.lsim((a_num, a_den), r, t)
    return t, r, y


@pytest.mark.parametrize("fc", [4.3, 9.1, 23.0])
def test_chirp_bandwidth_on_a_log_grid_matches_a_first_order_corner(fc):
    """Corners between the chirp's 1/T = 0.25 Hz FFT bins: the log-spaced estimate finds a/(2 pi).
    (Corners within ~5x of the sweep start read high: the chirp does not see the DC gain; documented
    in sweep_metrics, and why a continuous loop's bandwidth comes from its linearisation.)"""
    from awiwi_drake.control.compare import gain_diagram, sweep_metrics

    a = 2 * math.pi * fc
    t, r, y = _chirp_response([a], [1.0, a])
    f, g = gain_diagram(t, r, y, 0.5, 70.0)
    assert np.allclose(np.diff(np.log(f)), np.log(70.0 / 0.5) / (len(f) - 1))   # log-spaced
    bw = sweep_metrics(f, g)["bandwidth_hz"]
    assert bw == pytest.approx(fc, rel=0.05), (fc, bw)


def test_chirp_bandwidth_on_a_log_grid_matches_a_second_order_loop():
    from awiwi_drake.control.compare import gain_diagram, sweep_metrics

    wn, xi = 2 * math.pi * 12.0, 0.4
    t, r, y = _chirp_response([wn ** 2], [1.0, 2 * xi * wn, wn ** 2])
    m = sweep_metrics(*gain_diagram(t, r, y, 0.5, 70.0))
    assert m["bandwidth_hz"] == pytest.approx(_second_order_bandwidth(wn, xi), rel=0.05)
    assert m["resonance_hz"] == pytest.approx(wn * math.sqrt(1 - 2 * xi ** 2) / (2 * math.pi), rel=0.05)


def test_compare_reports_where_the_bandwidth_comes_from():
    """A continuous loop's sweep bandwidth is its linearisation's (source named) and agrees with the
    chirp's log-grid estimate of the same simulated loop; a 3 kHz sampled loop's comes from the chirp."""
    from awiwi_drake.control.base import closed_loop
    from awiwi_drake.control.compare import compare_test_params, run_test, sweep_metrics
    from awiwi_drake.control.registry import get_entry
    from awiwi_drake.rigs import flexible_joint_rig

    p = compare_test_params(flexible_joint_rig(), sweep_duration=2.0)
    rows, runs = {}, {}
    for rate in (None, 3000.0):
        rig = flexible_joint_rig()
        entry = get_entry("pole-placement", rig)
        loop = closed_loop(rig, entry.factory(rig), **{**entry.loop_options, "rate_hz": rate})
        runs[rate], rows[rate] = run_test(loop, "sweep", controller="pole-placement", params=p)
    assert rows[None].bandwidth_source == "linearization"
    chirp = sweep_metrics(runs[None].meta["freq"], runs[None].meta["gain"])["bandwidth_hz"]
    assert rows[None].bandwidth_hz == pytest.approx(chirp, rel=0.03)
    assert rows[3000.0].bandwidth_source == "chirp" and np.isfinite(rows[3000.0].bandwidth_hz)
    assert rows[3000.0].bandwidth_hz == sweep_metrics(runs[3000.0].meta["freq"],
                                                      runs[3000.0].meta["gain"])["bandwidth_hz"]
