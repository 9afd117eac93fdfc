"""The standard tests on fingers and the hand (issue 10 item 8): the short mode's step window comes from the
compared loops' own designs, so that a loop that performs as designed settles inside it."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.primitives import LinearSystem

from awiwi_drake.control import closed_loop, get_entry, make_controller
from awiwi_drake.control.compare import compare_test_params, design_time_constant, dominant_time_constant
from awiwi_drake.hand.diagrams import finger_diagram
from awiwi_drake.parameters.cli import CompareShortMode


def _designed_step(design, dof, t_end):
    """The designed sampled loop of one DoF (:meth:`JointDesign.loop`: the stage's ``Phi - Gamma K`` and, with the
    chain's observer, the observer on the guides' presliding stiffness) stepped by 1 from rest, simulated by Drake;
    returns ``(t, q)``."""
    A, b = design.loop(dof)
    C = np.zeros((1, A.shape[0]))
    C[0, 0] = 1.0
    sys_ = LinearSystem(A, b[:, None], C, np.zeros((1, 1)), design.period)
    ctx = sys_.CreateDefaultContext()
    sys_.get_input_port().FixValue(ctx, [1.0])
    sim = Simulator(sys_, ctx)
    t, q = [], []
    for k in range(int(round(t_end / design.period)) + 1):
        sim.AdvanceTo(k * design.period)
        t.append(k * design.period)
        q.append(sys_.get_output_port().Eval(ctx)[0])
    return np.array(t), np.array(q)


@pytest.mark.parametrize("name", ["cascaded", "lqr"])
def test_short_window_lets_each_designed_joint_loop_settle(name):
    """On the index, the registered chain's design reports its slowest tracking time constant tau (the per-DoF
    designed sampled loops with the chain's (9.2) observer on the guides' presliding stiffness, poles weighted by
    their share of the step); each designed loop, stepped, is inside
    the 2 % settling band after 5 tau (CompareShortMode.step_time_constants) and the slowest is not yet after
    tau (the window is not padded); the compare reads tau for the sampled finger loop (no linearisation)."""
    rig = finger_diagram(finger="index")
    ctrl = make_controller(name, rig)
    d = ctrl.design.joint_design
    tau = d.tracking_time_constant()
    loop = closed_loop(rig, ctrl, **get_entry(name, rig).loop_options)
    assert design_time_constant(loop) == tau and dominant_time_constant(loop) == tau
    n_tau = CompareShortMode().step_time_constants
    band = compare_test_params(rig).settling_band
    late = []
    for j, m in enumerate(d.models):
        t, q = _designed_step(d, j, n_tau * tau)
        assert np.all(np.abs(q[t >= n_tau * tau * 0.999] - 1.0) < band), m.name
        late.append(np.max(np.abs(q[t >= tau] - 1.0)))
    assert max(late) > band            # at one tau the slowest DoF is still outside the band


def test_short_window_on_a_finger_is_five_design_time_constants():
    """``compare --short`` (``short_test_params``) on a finger: the step window is delay + 5 tau (not capped at the full window) with tau the slowest of the
    compared controllers' designs (backstepping: its joint modes M e'' + Kd e' + Kp e = 0)."""
    from awiwi_drake.control.compare import build_loops, short_test_params
    full = compare_test_params("finger-index")
    make = lambda: finger_diagram(finger="index")                                              # noqa: E731
    loops = build_loops(make, ["backstepping"])
    p = short_test_params(make, loops, full)
    law = loops["backstepping"].controller.law
    A_e = np.block([[np.zeros_like(law.M), np.eye(len(law.M))],
                    [-np.linalg.solve(law.M, law.Kp), -np.linalg.solve(law.M, law.Kd)]])
    tau = 1.0 / np.min(-np.linalg.eigvals(A_e).real)
    sm = CompareShortMode()
    assert p.step_duration == pytest.approx(max(sm.min_step_duration, full.step_delay + 5 * tau), rel=1e-12)


def test_full_compare_window_is_at_least_what_the_compared_designs_need(tmp_path, monkeypatch):
    """``awiwi-drake compare`` without ``--short`` on a finger: the step window is the chosen 0.3 s or, where the
    compared designs need more, ``design_step_duration`` (``step_delay + 5 tau``): the cascaded chain's design counts
    its observer's rest mode on the guides' presliding stiffness (index DIP, ~0.6 s), so its full window is that, not
    0.3 s; the short mode has the same window (its floor only lower)."""
    import awiwi_drake.control.compare as cmp
    import awiwi_drake.control.compare.standard_tests as st
    from awiwi_drake.cli import main
    from awiwi_drake.control.compare import build_loops, design_step_duration, short_test_params

    seen, built = {}, []

    class Stop(Exception):
        pass

    def capture(loops, *, params=None, **kw):
        seen["params"], seen["loops"] = params, loops
        raise Stop

    def counting(name, rig, **kw):
        built.append(name)
        return make(name, rig, **kw)

    make = st.make_controller
    monkeypatch.setattr(cmp, "compare", capture)       # the CLI's params, then stop before simulating
    monkeypatch.setattr(st, "make_controller", counting)
    monkeypatch.setenv("AWIWI_SHORT", "0")                         # the full tests, also under CI's short mode
    main(["compare", "--rig", "finger-index", "--controllers", "cascaded", "--quiet", "--out", str(tmp_path)])
    # each controller designed once: the window is read from the loop the run gets (it was designed twice)
    assert built == ["cascaded"]
    full = compare_test_params("finger-index")
    tau = seen["loops"]["cascaded"].controller.design.time_constant
    make_index = lambda: finger_diagram(finger="index")                                       # noqa: E731
    window = design_step_duration(make_index, seen["loops"], full)
    assert window == pytest.approx(full.step_delay + CompareShortMode().step_time_constants * tau, rel=1e-12)
    assert window > full.step_duration
    assert seen["params"].step_duration == window
    assert short_test_params(make_index, seen["loops"], full).step_duration == window
    # a loop without a known time constant (the motor PD: its link modes are not designed) beside it keeps the
    # chosen window for itself and does not shorten the chain's (the hand's 13-controller run had fallen back to 0.3 s)
    pd_loop = build_loops(make_index, ["joint-pd"])["joint-pd"]
    assert dominant_time_constant(pd_loop, full) is None
    assert design_step_duration(make_index, {**seen["loops"], "joint-pd": pd_loop}, full) == window


def test_ideal_sensor_compare_reports_the_estimators_error_without_feeding_it_back():
    """``compare --sensors ideal``: the controller reads the plant's joint state and the tendon-length estimator
    (5.15) runs beside it on the same samples, so every row still has the estimator's error (it was NaN).  Not fed
    back: the joint trajectory equals the loop's without the estimator (``estimator=None``) to round-off.  Its error
    is the estimator's own: at most one control period of the joint's motion (the estimate is from the current
    sample, the error output compares it with the held truth), as in notebook 09 with estimated sensors."""
    from awiwi_drake.analysis import simulate
    from awiwi_drake.control.compare import build_loops, run_joint_test
    from awiwi_drake.hand.coupling import dof_selection

    make = lambda: finger_diagram(finger="index")                                              # noqa: E731
    loop = build_loops(make, ["backstepping"], sensors="ideal")["backstepping"]
    rig = make()
    bare = closed_loop(rig, make_controller("backstepping", rig), **get_entry("backstepping", rig).loop_options,
                       sensors="ideal", estimator=None)
    op, S = rig.operating_point(), dof_selection(rig.coupling)
    ref = {"joint_angle_reference": op.joint_angle + S @ np.full(S.shape[1], 0.2)}
    res = [simulate(lp, lp.create_context(op), 0.05, inputs=ref, log=("joint_angle", "joint_velocity")
                    + (("joint_angle_estimation_error",) if lp is loop else ())) for lp in (loop, bare)]
    np.testing.assert_allclose(res[0]["joint_angle"], res[1]["joint_angle"], rtol=0, atol=1e-12)
    err = np.abs(res[0]["joint_angle_estimation_error"]).max(axis=0)
    assert np.all(err <= np.abs(res[0]["joint_velocity"]).max(axis=0) / 3000.0 * 1.05 + 1e-12), err
    assert np.ptp(res[0]["joint_angle"], axis=0).max() > 0.05           # the joints did move
    p = compare_test_params("finger-index", step_duration=0.05, settle_time=0.01)
    _, rows = run_joint_test(loop, "step", controller="backstepping", params=p)
    assert all(np.isfinite(r.estimation_error) for r in rows), [r.estimation_error for r in rows]
