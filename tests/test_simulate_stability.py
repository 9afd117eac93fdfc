"""Fixed-step stability of :func:`~awiwi_drake.analysis.simulate` checked from the plant's modes before a run.

Drake's fixed-step RK3 multiplies a mode ``exp(lambda t)`` by ``R(h lambda)``, ``R(z) = 1 + z + z^2/2 + z^3/6``, per
step: measured on a spring-mass, with a numerical oscillation growing exactly where ``|R| > 1`` (the region's edge on
the imaginary axis is ``|z| = sqrt(3)`` in closed form).  The finger/hand plant reports its modes (Drake's
``Linearize`` of the plant with its inputs held, equal to the whole finger diagram's linearisation), and ``simulate``
integrates at ``h / k`` when a mode lies outside: the thumb at 40 N pretension (link mode -24.5 + 5351j 1/s,
``|R| = 1.0105`` at 3 kHz) gets ``k = 2``; the index at the default pretension keeps ``k = 1``.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pydrake.systems.framework import LeafSystem_
from pydrake.systems.primitives import LinearSystem
from pydrake.systems.scalar_conversion import TemplateSystem

from awiwi_drake.analysis import fixed_step_substeps, linearize, simulate, stability_function
from awiwi_drake.hand.diagrams import finger_diagram, hand_diagram
from awiwi_drake.parameters.control import CONTROL_RATE_HZ, FIXED_STEP_STABILITY_MARGIN

H = 1.0 / CONTROL_RATE_HZ


def _spring_mass(omega: float, zeta: float = 0.0) -> LinearSystem:
    """x'' = -omega^2 x - 2 zeta omega x' (unit mass), output the state."""
    A = np.array([[0.0, 1.0], [-omega ** 2, -2 * zeta * omega]])
    return LinearSystem(A, np.zeros((2, 1)), np.eye(2), np.zeros((2, 1)))


@pytest.mark.parametrize("y, zeta", [(np.sqrt(3) * 0.98, 0.0), (np.sqrt(3) * 1.02, 0.0), (np.sqrt(3), 0.0),
                                     (5351 / 3000, 24.5 / 5351), (1.5, 0.05)])
def test_rk3_amplifies_a_spring_mass_mode_by_the_closed_form_and_grows_exactly_where_r_exceeds_one(y, zeta):
    """Drake's fixed-step RK3 (through ``simulate``) on a spring-mass with ``h omega = y``: after N steps the mode's
    amplitude (its eigen-coordinate) is ``|R(h lambda)|^N`` to round-off; it grows iff ``|R| > 1``, and on the
    imaginary axis ``|R(iy)|^2 = 1 - y^4/12 + y^6/36`` crosses 1 at ``y = sqrt(3)``."""
    omega = y / H
    sys = _spring_mass(omega, zeta)
    lam = np.linalg.eigvals(sys.A())
    ctx = sys.CreateDefaultContext()
    ctx.SetContinuousState([1.0, 0.0])
    sys.get_input_port(0).FixValue(ctx, [0.0])
    n = 300
    res = simulate(sys, ctx, n * H, mode="fixed_step", step=H, log=("y0",), divergence_bound=1e300)
    assert res.info["substeps"] == 1 and res.info["fastest_mode"] is None   # a LinearSystem reports no modes
    V = np.linalg.eig(sys.A())[1]
    coords = np.linalg.solve(V, res["y0"].T)          # eigen-coordinates per logged step
    i = int(np.argmax(lam.imag))
    measured = abs(coords[i, n]) / abs(coords[i, 0])
    R = stability_function("runge_kutta3", H * lam[i])
    z = H * lam[i]
    assert R == pytest.approx(abs(1 + z + z ** 2 / 2 + z ** 3 / 6), rel=1e-15)
    assert measured == pytest.approx(R ** n, rel=1e-9)
    if zeta == 0.0:     # the oscillator's amplitude sqrt(x^2 + (v/omega)^2): grows iff y > sqrt(3), else constant or decays
        assert R ** 2 == pytest.approx(1 - y ** 4 / 12 + y ** 6 / 36, rel=1e-12)
        x, v = res["y0"].T
        amplitude = np.hypot(x, v / omega)
        assert amplitude[-1] / amplitude[0] == pytest.approx(R ** n, rel=1e-9)
        assert (amplitude[-1] > 1 + 1e-9) == (y > np.sqrt(3) * (1 + 1e-9))
        assert (amplitude[-1] < 1 - 1e-9) == (y < np.sqrt(3) * (1 - 1e-9))


def test_substeps_are_the_smallest_count_that_puts_every_mode_inside_with_the_margin():
    """The count is the closed form on the imaginary axis: an undamped mode with ``h omega = y`` needs the smallest
    ``k`` with ``margin y / k <= sqrt(3)``; a mode inside at ``h`` keeps ``k = 1`` however close to the edge."""
    for y in (1.0, 1.73, 1.8, 3.0, 10.0, 40.0):
        k, mode, growth = fixed_step_substeps([1j * y / H, -1j * y / H, -1.0], H)
        expected = 1 if y <= np.sqrt(3) else int(np.ceil(FIXED_STEP_STABILITY_MARGIN * y / np.sqrt(3) - 1e-9))
        assert k == expected, y
        assert abs(mode.imag) == pytest.approx(y / H) and growth == pytest.approx(
            np.sqrt(1 - y ** 4 / 12 + y ** 6 / 36))
    assert fixed_step_substeps([-1e9], H)[0] == 0          # no k up to 64 brings -3e5 h inside


def _same_modes(a, b, rel):
    gap = np.abs(a[:, None] - b[None, :])      # each mode has its twin in the other set
    scale = rel * max(1.0, np.abs(b).max())
    return a.size == b.size and gap.min(axis=0).max() <= scale and gap.min(axis=1).max() <= scale


def test_thumb_at_40_n_is_integrated_at_half_the_control_period_and_the_index_at_20_n_at_it(monkeypatch):
    """The plant's modes (the hook on ``hand_dynamics``: central differences of its compiled dynamics, or Drake's
    ``Linearize`` of it without kernels) equal the eigenvalues of the whole finger's Drake linearisation; on the thumb at 40 N the link mode -24.5 + 5351j 1/s has ``|R| = 1.0105`` at 3 kHz, so
    ``simulate`` warns, integrates at h/2 (where every mode is inside with the margin) and refuses ``substeps=1``
    with one line naming the mode; on the index at the default pretension every mode is inside at h."""
    thumb = finger_diagram(finger="thumb")
    op = thumb.operating_point(pretension=40.0)
    ctx = thumb.context(op)
    leaf = thumb.diagram.GetSubsystemByName("hand_dynamics")
    modes = leaf.integration_modes(leaf.GetMyContextFromRoot(ctx))
    full = np.linalg.eigvals(linearize(thumb, op).A)
    assert _same_modes(modes, full, 1e-6)
    with monkeypatch.context() as m:     # a drive without compiled kernels: Drake's Linearize of the plant alone
        m.setattr(type(leaf.model), "supports_symbolic", property(lambda self: False))
        exact = leaf.integration_modes(leaf.GetMyContextFromRoot(ctx))
    assert _same_modes(exact, full, 1e-9)
    k, mode, growth = fixed_step_substeps(modes, H)
    assert k == 2 and mode.real == pytest.approx(-24.46, abs=0.01) and abs(mode.imag) == pytest.approx(5350.6, abs=0.1)
    assert growth == pytest.approx(1.0105, abs=1e-4)
    assert fixed_step_substeps(FIXED_STEP_STABILITY_MARGIN * modes, H / 2)[0] == 1
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = simulate(thumb, ctx, 0.002, mode="fixed_step", step=H, log=("joint_angle",))
    assert res.info["substeps"] == 2 and res.info["step"] == pytest.approx(H / 2)
    assert res.info["fastest_mode"]["growth"] == pytest.approx(growth) and not res.events
    assert any("-24.46 + 5351j 1/s" in str(w.message) and "substeps=2" in str(w.message) for w in caught)
    with pytest.raises(ValueError, match=r"mode -24.46 \+ 5351j 1/s with \|R\(h lambda\)\| = 1.0105 .*substeps = 1 "
                                         r"is too few: 2"):
        simulate(thumb, thumb.context(op), 0.001, mode="fixed_step", step=H, substeps=1)

    index = finger_diagram(finger="index")
    res = simulate(index, index.context(), 0.002, mode="fixed_step", step=H, log=("joint_angle",))
    assert res.info["substeps"] == 1 and res.info["step"] == H
    assert res.info["fastest_mode"]["growth"] <= 1.0


def test_the_hand_plant_perturbs_one_state_of_every_finger_at_once_and_keeps_its_modes():
    """The hand's fingers are independent (the wrist is an input), so the hook's differences perturb one state of every
    finger per evaluation; its modes equal those of Drake's ``Linearize`` of the whole hand plant (one finger's
    groups would be wrong if a finger's state moved another's derivative)."""
    hand = hand_diagram()
    ctx = hand.context(hand.operating_point(pretension=40.0))
    leaf = hand.diagram.GetSubsystemByName("hand_dynamics")
    groups = leaf._finger_states()
    assert len(groups) == 5 and np.array_equal(np.sort(np.concatenate(groups)), np.arange(hand.num_states))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # the thumb at 40 N: substeps (tested above)
        full = np.linalg.eigvals(linearize(hand, hand.operating_point(pretension=40.0)).A)
    assert _same_modes(leaf.integration_modes(leaf.GetMyContextFromRoot(ctx)), full, 1e-6)


def test_substeps_is_validated():
    sys = _spring_mass(10.0)
    ctx = sys.CreateDefaultContext()
    sys.get_input_port(0).FixValue(ctx, [0.0])
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match=f"substeps = {bad!r} must be a positive integer"):
            simulate(sys, ctx, 0.01, mode="fixed_step", step=1e-3, substeps=bad)
    with pytest.raises(ValueError, match="substeps = 2 needs a fixed-step run"):
        simulate(sys, ctx, 0.01, substeps=2)
    res = simulate(sys, ctx, 0.01, mode="fixed_step", step=1e-3, substeps=4)
    assert res.info["step"] == pytest.approx(2.5e-4) and res.info["substeps"] == 4


@TemplateSystem.define("StiffeningOscillator_")
def StiffeningOscillator_(T):
    """``x'' = -w^2 x`` with ``w = w0 + s``, ``s' = rate + p``, ``p' = -swing^2 s`` (state ``[x, v, s, p]``): a mode
    ``+-i w`` that moves along the imaginary axis as the run goes (drifting, or swinging ``s = (p0 / swing)
    sin(swing t)``); ``integration_modes`` is its Jacobian's eigenvalues in closed form (block triangular:
    ``+-i w``, ``+-i swing``)."""

    class Impl(LeafSystem_[T]):
        def _construct(self, w0=1.0, rate=0.0, swing=0.0, converter=None):
            LeafSystem_[T].__init__(self, converter)
            self.w0, self.rate, self.swing = float(w0), float(rate), float(swing)
            self.DeclareContinuousState(4)

        def _construct_copy(self, other, converter=None):
            Impl._construct(self, other.w0, other.rate, other.swing, converter=converter)

        def DoCalcTimeDerivatives(self, context, derivatives):
            x, v, s, p = context.get_continuous_state_vector().CopyToVector()
            w = self.w0 + s
            derivatives.SetFromVector(np.array([v, -w * w * x, self.rate + p, -self.swing ** 2 * s]))

        def integration_modes(self, context):
            w = self.w0 + context.get_continuous_state_vector().GetAtIndex(2)
            return np.array([1j * w, -1j * w, 1j * self.swing, -1j * self.swing])

    return Impl


def test_a_mode_that_leaves_the_region_during_the_run_is_an_event_to_its_end():
    """Inside at the start (``h w = 1.5 < sqrt(3)``: no substeps), outside at the end (``h w = 2.0``): the run is
    shorter than the check interval, so the end state is its one check and the ``integrator_instability`` event is
    that instant, with ``|R(2i)| = sqrt(1 - 16/12 + 64/36)`` there, and a warning."""
    t_final = 0.05
    osc = StiffeningOscillator_[float](w0=1.5 / H, rate=0.5 / H / t_final)
    ctx = osc.CreateDefaultContext()
    ctx.SetContinuousState([1e-3, 0.0, 0.0, 0.0])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = simulate(osc, ctx, t_final, mode="fixed_step", step=H, log=())
    assert res.info["substeps"] == 1
    (event,) = res.events
    # a run shorter than FIXED_STEP_CHECK_INTERVAL is checked at its end only: the event is that instant
    assert res.info["stability_checks"] == [t_final]
    assert event.kind == "integrator_instability" and event.t_start == event.t_end == t_final
    assert event.extreme == pytest.approx(np.sqrt(1 - 16 / 12 + 64 / 36), rel=1e-6)
    assert any("outside runge_kutta3's stability region" in str(w.message) for w in caught)


def test_a_mode_that_leaves_the_region_and_comes_back_during_the_run_is_an_event_between_the_checks(monkeypatch,
                                                                                                    tmp_path):
    """``h w = 1.5 + 0.25 sin(swing t)`` over half a swing: inside at the start and at the end, outside (``h w >
    sqrt(3)``) for ``sin(swing t) > (sqrt(3) - 1.5) / 0.25``.  Checked at every chunk boundary (interval 0): one
    event from the first to the last checked instant in that window, ``|R|`` the largest at those instants (closed
    form on the imaginary axis); at the default interval (0.25 s) the checks are at its multiples, deterministic, and
    the event is the one at t = 1 s, inside the window.  The
    fastest mode is saved to JSON as numbers ``[real, imag]``."""
    import importlib
    import json
    sim_module = importlib.import_module("awiwi_drake.analysis.simulate")   # the attribute is the function

    swing, t_final, a = np.pi / 2, 2.0, 0.25          # half a swing: s = 0 at both ends
    window = np.array([np.arcsin((np.sqrt(3) - 1.5) / a), np.pi - np.arcsin((np.sqrt(3) - 1.5) / a)]) / swing

    def run():
        osc = StiffeningOscillator_[float](w0=1.5 / H, swing=swing)
        ctx = osc.CreateDefaultContext()
        ctx.SetContinuousState([1e-3, 0.0, 0.0, a / H * swing])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = simulate(osc, ctx, t_final, mode="fixed_step", step=H, log=())
        assert res.info["substeps"] == 1 and any("from t = " in str(w.message) for w in caught)
        return res

    def growth(t):
        return stability_function("runge_kutta3", 1j * (1.5 + a * np.sin(swing * np.asarray(t))))

    with monkeypatch.context() as m:
        m.setattr(sim_module, "FIXED_STEP_CHECK_INTERVAL", 0.0)
        res = run()
    checked = np.array(res.info["stability_checks"])
    assert checked.size >= 40 and checked[-1] == t_final
    out = checked[(checked > window[0]) & (checked < window[1])]
    (event,) = res.events
    assert (event.t_start, event.t_end) == (out[0], out[-1])
    assert event.extreme == pytest.approx(growth(out).max(), rel=1e-9) and 1.0 < event.extreme <= growth(t_final / 2)
    res = run()                       # the default interval: checks at its multiples, one of them in the window
    np.testing.assert_allclose(res.info["stability_checks"], np.arange(1, 9) * 0.25, rtol=1e-12)
    (event,) = res.events
    assert event.t_start == event.t_end == pytest.approx(1.0, rel=1e-12)
    assert window[0] < 1.0 < window[1] and event.extreme == pytest.approx(growth(1.0), rel=1e-9)
    res.save(tmp_path / "run.npz")
    mode = json.loads((tmp_path / "run.npz.json").read_text())["info"]["fastest_mode"]["mode"]
    assert mode == [0.0, pytest.approx(1.5 / H)]
