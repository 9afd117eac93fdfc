"""The one linearisation / LQR API: closed forms (second-order damp table and Bode, scalar Riccati,
undamped flexible joint, classic margins), AutoDiff linearisation against finite differences,
python-control cross-checks, save/load."""

import math

import numpy as np
import pytest
from pydrake.systems.primitives import LinearSystem

from _fd import fd_jacobian
from awiwi_drake.analysis import LinearizationResult, LqrResult, linearize, lqr, poles_table
from awiwi_drake.analysis.linear import closed_loop_poles, lqr_gain
from awiwi_drake.parameters import FlexibleJointParams
from awiwi_drake.rigs import flexible_joint_rig, joint_rig


def _linear(A, B, C, D, name="lti"):
    sys = LinearSystem(np.atleast_2d(A), np.atleast_2d(B), np.atleast_2d(C), np.atleast_2d(D))
    sys.set_name(name)
    ctx = sys.CreateDefaultContext()
    sys.get_input_port().FixValue(ctx, np.zeros(np.atleast_2d(B).shape[1]))
    return sys, ctx


def _second_order(wn, zeta):
    """x'' + 2 zeta wn x' + wn^2 x = wn^2 u  (unit static gain)."""
    return _linear([[0, 1], [-wn ** 2, -2 * zeta * wn]], [[0], [wn ** 2]], [[1, 0]], [[0]], "second_order")


def test_second_order_damp_table_and_bode_at_resonance_match_the_closed_forms():
    wn, zeta = 40.0, 0.15
    sys, ctx = _second_order(wn, zeta)
    lin = linearize(sys, context=ctx, input="u0", outputs=("y0",))
    rows = list(lin.damp())
    assert len(rows) == 2
    for r in rows:
        assert r.natural_frequency == pytest.approx(wn, rel=1e-12)
        assert r.damping_ratio == pytest.approx(zeta, rel=1e-12)
        assert r.time_constant == pytest.approx(1.0 / (zeta * wn), rel=1e-12)
    fr = lin.bode(omega=[wn / 10, wn, 10 * wn])
    # |H(j wn)| = 1 / (2 zeta), phase -90 deg; DC gain 1 (0 dB) well below, -40 dB/decade above
    assert fr.magnitude_db[1] == pytest.approx(-20 * math.log10(2 * zeta), abs=1e-9)
    assert fr.phase_deg[1] == pytest.approx(-90.0, abs=1e-9)
    h_lo = 1.0 / complex(1 - 0.01, 2 * zeta * 0.1)
    assert fr.response[0] == pytest.approx(h_lo, rel=1e-12)
    assert fr.magnitude_db[2] == pytest.approx(20 * math.log10(1 / abs(complex(1 - 100, 2 * zeta * 10))), abs=1e-9)


def test_undamped_flexible_joint_has_the_closed_form_frequency_and_zero_poles_print_as_zero():
    p = FlexibleJointParams(link_damping=0.0, motor_damping=0.0)
    rig = flexible_joint_rig(params=p)
    lin = linearize(rig)
    w = math.sqrt(p.stiffness * (1 / p.link_inertia + 1 / p.motor_inertia))  # (12.10), two-mass oscillator
    poles = lin.poles
    assert np.sum(poles == 0) == 2                                # the rigid-body mode: exactly 0, not 1e-13
    osc = poles[poles != 0]
    np.testing.assert_allclose(np.sort(osc.imag), [-w, w], rtol=1e-9)
    assert np.all(osc.real == 0)
    assert "e-" not in poles_table(lin)
    damp = [r for r in lin.damp() if r.natural_frequency > 0]
    assert all(r.damping_ratio == 0.0 and math.isinf(r.time_constant) for r in damp)
    assert "-0 " not in str(lin.damp())
    assert lin.state_names == tuple(rig.state_names) and lin.input_names == ("motor_torque",)


def test_scalar_lqr_matches_the_riccati_closed_form():
    # xdot = a x + b u: 2 a S - b^2 S^2 / R + Q = 0  ->  S = R (a + sqrt(a^2 + b^2 Q / R)) / b^2, K = b S / R
    for a, b, Q, R in ((0.0, 1.0, 4.0, 0.25), (1.5, 2.0, 3.0, 0.5), (-2.0, 0.5, 10.0, 2.0)):
        sys, ctx = _linear([[a]], [[b]], [[1.0]], [[0.0]])
        res = lqr(sys, [[Q]], [[R]], context=ctx, input="u0")
        S = R * (a + math.sqrt(a * a + b * b * Q / R)) / (b * b)
        assert res.S[0, 0] == pytest.approx(S, rel=1e-10)
        assert res.K[0, 0] == pytest.approx(b * S / R, rel=1e-10)
        if a == 0.0:
            assert res.S[0, 0] == pytest.approx(math.sqrt(Q * R), rel=1e-10)   # S = sqrt(Q R)
        assert res.closed_loop_poles[0].real == pytest.approx(-math.sqrt(a * a + b * b * Q / R), rel=1e-10)
        assert res.closed_loop.poles[0] == res.closed_loop_poles[0]
    with pytest.raises(ValueError, match="R must be symmetric positive definite"):
        lqr_gain([[1.0]], [[1.0]], [[1.0]], [[0.0]])
    with pytest.raises(ValueError, match="Q must be 2x2"):
        lqr_gain(np.eye(2), np.ones((2, 1)), np.eye(3), [[1.0]])


def test_gain_and_phase_margins_of_the_classic_third_order_loop():
    # L(s) = k / (s (s + 1) (s + 2)): phase crossover at sqrt(2) rad/s, |L| there = k / 6 -> GM = 6 / k
    k = 1.0
    A = [[0, 1, 0], [0, 0, 1], [0, -2, -3]]
    sys, ctx = _linear(A, [[0], [0], [k]], [[1, 0, 0]], [[0]])
    fr = linearize(sys, context=ctx, input="u0", outputs=("y0",), equilibrium_tolerance=None).bode(
        omega=np.logspace(-2, 2, 4000))
    m = fr.margins()
    assert m["phase_crossover"] == pytest.approx(math.sqrt(2), rel=1e-4)
    assert m["gain_margin"] == pytest.approx(6.0 / k, rel=1e-4)
    wc = next(w for w in np.linspace(0.1, 1.0, 200001) if k / (w * math.sqrt(w * w + 1) * math.sqrt(w * w + 4)) <= 1)
    pm = 180 - 90 - math.degrees(math.atan(wc)) - math.degrees(math.atan(wc / 2))
    assert m["gain_crossover"] == pytest.approx(wc, rel=1e-4)
    assert m["phase_margin"] == pytest.approx(pm, abs=0.01)


def test_linearisation_of_the_joint_rig_equals_finite_differences_of_its_dynamics():
    """Drake's Linearize (AutoDiffXd through every system of the rig) against central differences
    of the float diagram's time derivatives, at an equilibrium and off it (f0 = xdot there)."""
    rig = joint_rig()
    op = rig.operating_point(pretension=25.0, joint_angle=0.1)
    d = rig.diagram
    for dx in (np.zeros(rig.num_states), np.array([0.02, 0.3, 0.01, -0.02, 0.5, -0.4])):
        x0 = op.state + dx
        lin = linearize(rig, op, state=x0, outputs=("state", "tendon_force"))
        ctx = rig.context(op)

        def f(xu):
            ctx.SetContinuousState(xu[:rig.num_states])
            d.GetInputPort("motor_torque").FixValue(ctx, xu[rig.num_states:])
            return d.EvalTimeDerivatives(ctx).CopyToVector()

        def g(xu):
            ctx.SetContinuousState(xu[:rig.num_states])
            d.GetInputPort("motor_torque").FixValue(ctx, xu[rig.num_states:])
            return d.GetOutputPort("tendon_force").Eval(ctx)

        xu = np.concatenate([x0, op.motor_torque])
        J = fd_jacobian(f, xu)
        scale = np.abs(J).max()
        np.testing.assert_allclose(lin.A, J[:, :rig.num_states], atol=1e-6 * scale)
        np.testing.assert_allclose(lin.B, J[:, rig.num_states:], atol=1e-6 * scale)
        Jg = fd_jacobian(g, xu)
        np.testing.assert_allclose(lin.output("tendon_force").C, Jg[:, :rig.num_states], atol=1e-6 * np.abs(Jg).max())
        np.testing.assert_allclose(lin.f0, f(xu), atol=1e-9)
    assert np.max(np.abs(linearize(rig, op).f0)) < 1e-6          # at the operating point: an equilibrium


def test_python_control_agrees_on_damp_and_frequency_response():
    control = pytest.importorskip("control")
    rig = flexible_joint_rig()
    lin = linearize(rig, outputs=("joint_angle",))
    ss = lin.to_control()
    assert ss.nstates == 4 and list(ss.state_labels) == list(rig.state_names)
    wn, zeta, poles = control.damp(ss, doprint=False)
    ours = lin.damp()
    np.testing.assert_allclose(np.sort(wn), np.sort([r.natural_frequency for r in ours]), rtol=1e-9, atol=1e-9)
    w = np.logspace(0, 4, 50)
    fr = lin.bode(omega=w)
    resp = control.frequency_response(ss, w)
    np.testing.assert_allclose(fr.response, np.asarray(resp.complex).ravel(), rtol=1e-9)


def test_results_save_load_and_plot(tmp_path):
    rig = joint_rig()
    lin = linearize(rig, outputs=("state", "joint_angle"))
    back = LinearizationResult.load(lin.save(tmp_path / "lin.json"))
    np.testing.assert_array_equal(back.A, lin.A)
    np.testing.assert_array_equal(back.poles, lin.poles)
    np.testing.assert_array_equal(back.output("joint_angle").C, lin.output("joint_angle").C)
    assert back.state_names == lin.state_names
    fr = lin.bode(input="motor_torque[0]", output="joint_angle")
    fig, (am, ap) = fr.plot()
    assert am.get_xscale() == "log" and "dB" in am.get_ylabel() and "deg" in ap.get_ylabel()
    assert "Hz" in ap.get_xlabel() and am.get_legend() is not None
    with pytest.raises(ValueError, match="unknown output 'torque'"):
        lin.bode(output="torque")
    with pytest.raises(ValueError, match="no output 'tendon_force'"):
        lin.output("tendon_force")
    design = lqr(rig, np.diag([1e3, 1e-4, 1e3, 1e3, 1e-4, 1e-4]), np.eye(2))
    back = LqrResult.load(design.save(tmp_path / "lqr.json"))
    np.testing.assert_array_equal(back.K, design.K)
    np.testing.assert_array_equal(back.closed_loop_poles, design.closed_loop_poles)
    np.testing.assert_allclose(design.closed_loop_poles, closed_loop_poles(design.linearization.A,
                                                                            design.linearization.B, design.K))
    assert np.all(design.closed_loop.poles.real < 0)


def test_cli_linearize_writes_bode_prints_damp_and_saves(tmp_path, capsys):
    import json

    from awiwi_drake.cli import main

    png, saved = tmp_path / "bode.png", tmp_path / "lin.json"
    assert main(["linearize", "flexible-joint", "--damp", "--bode", str(png), "--save", str(saved)]) == 0
    out = capsys.readouterr().out
    assert png.stat().st_size > 10_000 and "zeta" in out and "phase margin" in out
    back = LinearizationResult.load(saved)
    assert back.state_names == tuple(flexible_joint_rig().state_names)
    assert main(["linearize", "tendon-rig", "--json", "--bode", str(png)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert {"A", "B", "poles", "damp", "bode", "state_names"} <= set(data)
    assert data["bode"]["output"] == "tendon_force" and len(data["bode"]["magnitude_db"]) == 400
    for args, msg in ((["--bode", str(tmp_path / "b.txt")], "--bode .* ending in .png"),
                      (["--bode", str(tmp_path / "d.png"), "--save", str(tmp_path)], "--save .* ending in .json"),
                      (["--save", str(tmp_path / "x.txt")], "--save .* ending in .json"),
                      (["--bode", str(png), "--output", "torque"], "unknown output 'torque'")):
        assert main(["linearize", "joint-rig", *args]) == 2
        assert __import__("re").search(msg, capsys.readouterr().err)


_CONSTANT_OUTPUT_SCRIPT = r'''
import json, sys
import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, Integrator
from awiwi_drake.analysis import linearize
from awiwi_drake.hand.diagrams import hand_diagram
from awiwi_drake.hand.wrist import wrist_tendon_offsets

b = DiagramBuilder()
i = b.AddSystem(Integrator(2))
b.ExportInput(i.get_input_port(), "u")
b.ExportOutput(i.get_output_port(), "x")
b.ExportOutput(b.AddSystem(ConstantVectorSource([1.0, 2.0, 3.0])).get_output_port(), "y")
d = b.Build()
ctx = d.CreateDefaultContext()
d.GetInputPort("u").FixValue(ctx, np.zeros(2))
small = linearize(d, context=ctx, input="u", outputs=("y", "x"))
rig = hand_diagram()
op = rig.operating_point(wrist_angle=[0.2, -0.1])
hand = linearize(rig, op, outputs=("wrist_tendon_offset", "joint_angle"), equilibrium_tolerance=None)
w = hand.outputs["wrist_tendon_offset"]
print(json.dumps(dict(
    small=[small.A.tolist(), small.B.tolist(), small.outputs["y"].C.tolist(), small.outputs["y"].D.tolist(),
           small.outputs["y"].y0.tolist(), small.outputs["x"].C.tolist()],
    hand_C=float(np.abs(w.C).max()), hand_D=float(np.abs(w.D).max()), hand_CD_shape=[w.C.shape, w.D.shape],
    hand_y0_err=float(np.abs(w.y0 - wrist_tendon_offsets(0.2, -0.1)).max()),
    hand_y0_max=float(np.abs(w.y0).max()), nx=hand.A.shape[0],
    q_rows=float(np.abs(hand.outputs["joint_angle"].C[:, :21] - np.eye(21)).max()))))
'''


def test_output_independent_of_state_and_input_linearises_to_zero_instead_of_crashing():
    """Drake's Linearize segfaults on an output that depends on neither the state nor the input (the hand's
    ``wrist_tendon_offset``, fed by the fixed wrist angle only); ``linearize`` gives its exact C = D = 0.
    Run in a subprocess, so that a crash fails this test instead of killing pytest."""
    import json
    import os
    import subprocess
    import sys
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run([sys.executable, "-c", _CONSTANT_OUTPUT_SCRIPT], capture_output=True, text=True,
                          timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    A, B, C, D, y0, Cx = r["small"]
    assert np.array_equal(A, np.zeros((2, 2))) and np.array_equal(B, np.eye(2))    # the integrator
    assert np.array_equal(C, np.zeros((3, 2))) and np.array_equal(D, np.zeros((3, 2))) and y0 == [1.0, 2.0, 3.0]
    assert np.array_equal(Cx, np.eye(2))
    # hand: the offsets' rows are zero, their value the (6.9) law's at the wrist angle; the joint angles are
    # the first 21 states
    assert r["hand_C"] == 0.0 and r["hand_D"] == 0.0
    assert r["hand_CD_shape"] == [[38, r["nx"]], [38, 38]]
    assert r["hand_y0_max"] > 1e-3 and r["hand_y0_err"] < 1e-12
    assert r["q_rows"] < 1e-12


def test_a_sampled_systems_output_keeps_its_state_dependence():
    """The constant-output check seeds the discrete state too: ``x[k+1] = a x + b u``, ``y = c x`` (period h, no
    feedthrough) linearises to its own (a, b, c, 0), not to C = 0 (an output that depends only on a discrete state
    was taken for a constant)."""
    a, b, c, h = 0.5, 1.0, 2.0, 0.01
    sys_ = LinearSystem(np.array([[a]]), np.array([[b]]), np.array([[c], [3.0]]), np.zeros((2, 1)), h)
    ctx = sys_.CreateDefaultContext()
    sys_.get_input_port().FixValue(ctx, [0.0])
    res = linearize(sys_, context=ctx, input=sys_.get_input_port().get_name(),
                    outputs=(sys_.get_output_port().get_name(),))
    y = res.outputs[sys_.get_output_port().get_name()]
    assert res.A.tolist() == [[a]] and res.B.tolist() == [[b]]
    assert y.C.tolist() == [[c], [3.0]] and y.D.tolist() == [[0.0], [0.0]]


def test_a_system_with_an_abstract_input_linearises():
    """Every fixed input of the point reaches the constant-output check, abstract ones too (``FixInputPortsFrom``):
    ``xdot = u``, ``y = g x`` with the gain ``g`` on an abstract input port linearises to ``A = 0, B = 1, C = g``
    (the check used to fix vector ports only, so evaluating ``y`` failed on the unset abstract port)."""
    from pydrake.autodiffutils import AutoDiffXd
    from pydrake.common.value import Value
    from pydrake.systems.framework import LeafSystem_
    from pydrake.systems.scalar_conversion import TemplateSystem

    @TemplateSystem.define("AbstractGain_", T_list=[float, AutoDiffXd])
    def AbstractGain_(T):
        class Impl(LeafSystem_[T]):
            def _construct(self, converter=None):
                LeafSystem_[T].__init__(self, converter)
                self.DeclareVectorInputPort("u", 1)
                self.DeclareAbstractInputPort("gain", Value[object](1.0))
                self.DeclareContinuousState(1)
                self.DeclareVectorOutputPort("y", 1, lambda c, out: out.SetAtIndex(
                    0, float(self.get_input_port(1).Eval(c)) * c.get_continuous_state_vector()[0]))

            def _construct_copy(self, other, converter=None):
                Impl._construct(self, converter=converter)

            def DoCalcTimeDerivatives(self, context, derivatives):
                derivatives.get_mutable_vector().SetAtIndex(0, self.get_input_port(0).Eval(context)[0])
        return Impl

    sys_ = AbstractGain_[None]()
    ctx = sys_.CreateDefaultContext()
    sys_.get_input_port(0).FixValue(ctx, [0.0])
    sys_.get_input_port(1).FixValue(ctx, Value[object](2.5))
    ctx.SetContinuousState([0.3])
    res = linearize(sys_, context=ctx, input="u", outputs=("y",))
    assert res.A.tolist() == [[0.0]] and res.B.tolist() == [[1.0]]
    assert res.C.tolist() == [[2.5]] and res.D.tolist() == [[0.0]] and res.outputs["y"].y0.tolist() == [0.75]
