"""Model-discrepancy workflow: data contract, model physics, profile statistics (fast)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, InitializeAutoDiff

from _fd import fd_jacobian
from awiwi_drake.components.spring import PolynomialSpring
from awiwi_drake.discrepancy import Dataset, load_dataset, save_dataset
from awiwi_drake.discrepancy.catalog import PARAM_INDEX, PARAM_NAMES, default_vector
from awiwi_drake.discrepancy.model import (DiscrepancyModel_, NominalParameters, model_derivatives,
                                           model_measurements)
from awiwi_drake.discrepancy.replay import Projection, noise_floor, project
from awiwi_drake.discrepancy.truth import HiddenEffectPlant_, draw_truth

JOINT = {"motor_inertia": 2e-3, "motor_damping": 1.2e-3, "motor_pulley_radius": 0.006,
         "spring_poly": [1.2e4, 2.5e6], "link_inertia": 1e-4, "link_damping": 1.2e-3,
         "link_pulley_radius": 0.008}


def _tiny_dataset(rig="joint-rig") -> Dataset:
    t = np.arange(50) * 1e-3
    w = np.sin(2 * np.pi * 20 * t)  # some excitation (load_dataset rejects constant recordings)
    if rig == "joint-rig":
        ins = {"motor_torque_1": 0.2 + 0.05 * w, "motor_torque_2": 0.2 - 0.05 * w}
        outs = {"motor_angle_1": 0.3 + 0.01 * w, "motor_angle_2": 0.3 - 0.01 * w, "tendon_force_1": 30 + w,
                "tendon_force_2": 30 - w, "joint_angle": 0.01 * w}
        init = {k: 0.0 for k in ("motor_angle_1", "motor_velocity_1", "motor_angle_2", "motor_velocity_2",
                                 "joint_angle", "joint_velocity")}
        params = dict(JOINT)
    else:
        ins = {"motor_torque": 0.2 + 0.05 * w}
        outs = {"motor_angle": 0.3 + 0.01 * w, "tendon_force": 30 + w}
        init = {"motor_angle": 0.3, "motor_velocity": 0.0}
        params = {k: JOINT[k] for k in ("motor_inertia", "motor_damping", "motor_pulley_radius", "spring_poly")}
    return Dataset("tiny", rig, t, ins, outs, params, init)


def test_dataset_roundtrip(tmp_path):
    ds = _tiny_dataset()
    path = save_dataset(ds, tmp_path)
    back = load_dataset(path)
    assert back.rig == "joint-rig" and back.output_names == ds.output_names
    np.testing.assert_allclose(back.time, ds.time)
    np.testing.assert_allclose(back.inputs["motor_torque_2"], ds.inputs["motor_torque_2"])
    assert back.parameters["spring_poly"] == JOINT["spring_poly"]


def _corrupt(tmp_path, csv_edit=None, json_edit=None):
    path = save_dataset(_tiny_dataset(), tmp_path)
    if csv_edit:
        lines = path.read_text().splitlines()
        path.write_text("\n".join(csv_edit(lines)) + "\n")
    if json_edit:
        jp = path.with_suffix(".json")
        meta = json.loads(jp.read_text())
        json_edit(meta)
        jp.write_text(json.dumps(meta))
    return path


def _set_cell(lines, row, col, value):
    cells = lines[row].split(",")
    cells[col] = value
    lines[row] = ",".join(cells)
    return lines


@pytest.mark.parametrize("csv_edit,json_edit,message", [
    (lambda L: [L[0].replace("joint_angle", "link_angel")] + L[1:], None, "unknown column 'link_angel'"),
    (lambda L: [",".join(L[0].split(",")[:-1])] + [",".join(r.split(",")[:-1]) for r in L[1:]], None,
     "missing column 'joint_angle'"),
    (lambda L: _set_cell(L, 5, 0, "0.0035"), None, "row 6: time step"),
    (lambda L: _set_cell(L, 6, 0, "0.0"), None, "row 7: time is not increasing"),
    (lambda L: _set_cell(L, 8, 3, "nan"), None, "row 9, column 'motor_angle_1'"),
    (None, lambda m: m["parameters"].pop("link_inertia"), "missing parameter 'link_inertia'"),
    (None, lambda m: m.update(rig="finger"), "unknown rig 'finger'"),
    (None, lambda m: m["parameters"].update(motor_inertia=-1.0), "'motor_inertia' = -1.0 must be > 0"),
    (None, lambda m: m["initial_state"].pop("joint_velocity"), "initial_state misses 'joint_velocity'"),
])
def test_load_rejects_malformed_data_naming_the_place(tmp_path, csv_edit, json_edit, message):
    path = _corrupt(tmp_path, csv_edit, json_edit)
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_dataset(path)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.json"):
        (tmp_path / "nothere.csv").write_text("time\n0\n")
        load_dataset(tmp_path / "nothere.csv")


# ---------------------------------------------------------------- model physics
def _random_state(nom, rng):
    """A state in the rigs' order ``[(q, q'), theta, omega, z]``."""
    n = nom.num_motors
    x = [rng.uniform(-0.1, 0.1, 1), rng.uniform(-3, 3, 1)] if nom.has_link else []
    x += [rng.uniform(0.3, 0.5, n), rng.uniform(-2, 2, n), rng.uniform(-1, 1, n)]
    return np.concatenate(x)


def test_nominal_measurements_are_the_foundation_joint_rigs_tendon_forces():
    """All catalog switches off, the model's measurement map reads the foundation joint rig's (Fig 5.9) tendon
    forces at random states.  (The derivatives are checked against the rig in
    tests/test_cross_checks.py::test_discrepancy_model_equals_the_joint_rig_at_random_states.)"""
    from awiwi_drake.components.spring import tendon_spring
    from awiwi_drake.parameters.components import MotorParams
    from awiwi_drake.parameters.rigs import JointRigParams
    from awiwi_drake.rigs import joint_rig

    motor = MotorParams(friction=False, saturation=False, damping=1.2e-3)
    rp = JointRigParams(motor=motor, link_inertia=1e-4, link_damping=1.2e-3)
    rig = joint_rig(params=rp)
    coeffs = tuple(tendon_spring(rp.spring).coefficients)
    nom = NominalParameters("joint-rig", motor.inertia, motor.damping, motor.pulley_radius, coeffs,
                            rp.link_inertia, rp.link_damping, rp.link_pulley_radius)
    rng = np.random.default_rng(0)
    ctx = rig.diagram.CreateDefaultContext()
    for _ in range(6):
        X = _random_state(nom, rng)
        X[-2:] = 0.0
        ctx.SetContinuousState(X[:6])   # the same order [q, qd, th1, th2, w1, w2]
        f_ref = rig.diagram.GetOutputPort("tendon_force").Eval(ctx)
        y = model_measurements(nom, X[:, None], default_vector()[:, None])[:, 0]
        np.testing.assert_allclose(y[2:4], f_ref, rtol=1e-12)
        assert np.all(f_ref > 0.0)                # loaded springs: the measurement is not a trivial zero


@pytest.mark.parametrize("rig", ["joint-rig", "tendon-rig"])
def test_replay_kernel_equals_the_laws_for_every_switch(rig):
    """The replay's compiled float path (generated from replay_laws through codegen) equals the law
    functions at random states with random catalog parameters, each effect on or off per copy."""
    from awiwi_drake.discrepancy.catalog import param_specs
    from awiwi_drake.discrepancy.model import replay_kernels
    params = JOINT if rig == "joint-rig" else {k: JOINT[k] for k in ("motor_inertia", "motor_damping",
                                                                 "motor_pulley_radius", "spring_poly")}
    nom = NominalParameters.from_dataset(rig, params)
    rng = np.random.default_rng(21)
    M = 40
    specs = param_specs()
    drawn = np.array([[rng.uniform(s.low, s.high) for s in specs] for _ in range(M)]).T
    off = np.array([s.off for s in specs])[:, None]
    P = np.where(rng.random(drawn.shape) < 0.5, off, drawn)
    X = np.stack([_random_state(nom, rng) for _ in range(M)], axis=1)
    U = rng.uniform(-1, 1, (nom.num_motors, M))
    k = replay_kernels(nom)
    ref = model_derivatives(nom, X, U, P)
    got = k["derivatives_batch"](X.T.copy(), U.T.copy(), P.T.copy(), np.empty((M, nom.num_states))).T
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    y_ref = model_measurements(nom, X, P)
    y = k["measurements_batch"](X.T.copy(), P.T.copy(), np.empty((M, nom.num_measurements))).T
    np.testing.assert_allclose(y, y_ref, rtol=1e-12, atol=1e-12 * np.abs(y_ref).max())
    # the system's float path is the kernel, its AutoDiff path the laws
    sys = DiscrepancyModel_[float](nom, M)
    ctx = sys.CreateDefaultContext()
    ctx.SetContinuousState(X.ravel())
    ctx.get_mutable_numeric_parameter(0).SetFromVector(P.ravel())
    sys.get_input_port(0).FixValue(ctx, U.ravel())
    np.testing.assert_allclose(sys.EvalTimeDerivatives(ctx).CopyToVector().reshape(-1, M), ref,
                               rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_joint_backlash_is_a_dead_zone_between_link_and_pulley():
    """components.routing.joint_backlash_angle on the antagonistic pair: inside the play the link feels no
    tendon torque (the pulley rests where the torque vanishes); beyond it the pulley sits at the stop
    q + b, up to the rounding's closed-form bound e^2 / (4 (y - b)), e = smoothing * b."""
    from scipy.optimize import brentq
    from awiwi_drake.components.routing import joint_backlash_angle
    spring = PolynomialSpring(tuple(JOINT["spring_poly"]))
    r, rq, b, sm = JOINT["motor_pulley_radius"], JOINT["link_pulley_radius"], 0.02, 0.05
    theta = np.array([0.45, 0.35])

    def tau_k(a):
        x = np.array([r * theta[0] - rq * a, r * theta[1] + rq * a])
        return rq * (spring.force(x)[0] - spring.force(x)[1]), rq * rq * float(np.sum(spring.stiffness(x)))
    rest = brentq(lambda a: tau_k(a)[0], -1.0, 1.0)           # pulley angle where the tendons balance
    K = tau_k(rest)[1]
    for q in rest + np.array([-0.5, -0.2, 0.0, 0.3, 0.5]) * b:   # inside the play: no torque on the link
        qp = joint_backlash_angle(q, tau_k, b, sm)
        assert abs(tau_k(qp)[0]) < 1e-3 * K * b
    for y in (3 * b, 10 * b):                                   # beyond it: at the stop
        for sgn in (1.0, -1.0):
            q = rest - sgn * y
            qp = joint_backlash_angle(q, tau_k, b, sm)
            assert abs(qp - (q + sgn * b)) <= (sm * b) ** 2 / (4 * (y - b))
            assert np.sign(tau_k(qp)[0]) == sgn                 # the stop transmits the spring torque


def test_place_masks_put_a_per_tendon_effect_on_one_tendon_only():
    """place_1/place_2: guide friction on tendon 2 alone changes only motor 2's acceleration, by exactly the
    both-tendon model's change there; motor 1 is as without the effect."""
    nom = NominalParameters.from_dataset("joint-rig", JOINT)
    rng = np.random.default_rng(8)
    X = _random_state(nom, rng)
    X[-2:] = 0.0
    u = np.array([[0.3], [0.2]])
    p0 = default_vector()
    both = p0.copy()
    both[PARAM_INDEX["guide_c0"]], both[PARAM_INDEX["guide_mu"]] = 1.0, 0.2
    two = both.copy()
    two[PARAM_INDEX["place_1"]] = 0.0
    d0, db, d2 = (model_derivatives(nom, X[:, None], u, p[:, None])[:, 0] for p in (p0, both, two))
    theta1, omega1, theta2, omega2 = 2, 4, 3, 5          # [q, q', th1, th2, w1, w2, z1, z2]
    assert d2[omega1] == d0[omega1] and d2[omega2] == db[omega2] and db[omega1] != d0[omega1]
    np.testing.assert_array_equal(d2[[0, 1, theta1, theta2]], d0[[0, 1, theta1, theta2]])


def _energy(nom, X):
    n = nom.num_motors
    spring = PolynomialSpring(nom.spring_poly)
    from awiwi_drake.discrepancy.model import rig_kinematics, split_state
    th, om, q, qd, _ = split_state(nom, X)
    x, _ = rig_kinematics(nom, th, om, q, qd)
    e = 0.5 * nom.motor_inertia * np.sum(om ** 2) + sum(float(spring.energy(np.array([xi]))[0]) for xi in x)
    if nom.has_link:
        e += 0.5 * nom.link_inertia * qd ** 2
    return e


@pytest.mark.parametrize("effects", [{}, {"motor_coulomb": 0.2, "motor_viscous": 0.02},
                                     {"joint_coulomb": 0.02}, {"guide_c0": 1.0, "guide_mu": 0.2}])
def test_unforced_rig_is_passive(effects):
    """dE/dt = -d sum w^2 - d_q q'^2 exactly without effects; friction effects only dissipate more."""
    nom = NominalParameters.from_dataset("joint-rig", JOINT)
    p = default_vector()
    for k, v in effects.items():
        p[PARAM_INDEX[k]] = v
    rng = np.random.default_rng(1)
    for _ in range(5):
        X = _random_state(nom, rng)
        X[-2:] = 0.0
        xdot = model_derivatives(nom, X[:, None], np.zeros((2, 1)), p[:, None])[:, 0]
        grad = fd_jacobian(lambda x: _energy(nom, x), X, h=1e-6).ravel()
        dEdt = grad @ xdot
        natural = -nom.motor_damping * np.sum(X[4:6] ** 2) - nom.link_damping * X[1] ** 2   # [q, q', th, w, z]
        if not effects:
            assert dEdt == pytest.approx(natural, rel=1e-4, abs=1e-8)
        else:
            assert dEdt < natural + 1e-9


def test_hysteresis_force_loop_has_catalog_width():
    """Dahl law of the catalog: the force saturates at +-h on loading/unloading (loop width 2h)."""
    from awiwi_drake.discrepancy import laws
    h, length = 8.0, 2e-4
    for direction in (+1.0, -1.0):
        z = 0.0
        x = 3e-3
        for _ in range(4000):  # travel 2 mm in 1 um steps (10 loop lengths)
            xd = direction * 1e-3
            z += laws.hysteresis_force_rate(z, x, xd, 30.0, h, length) * 1e-3
            x += xd * 1e-3
        assert z == pytest.approx(direction * h, rel=2e-3)


def _autodiff_check(system, ctx_setup, nx):
    ad = system.ToAutoDiffXd()
    ctx = system.CreateDefaultContext()
    X = ctx_setup(system, ctx)
    f0 = system.EvalTimeDerivatives(ctx).CopyToVector()
    actx = ad.CreateDefaultContext()
    ctx_setup(ad, actx, autodiff=True)
    actx.SetContinuousState(InitializeAutoDiff(X).ravel())
    grad = ExtractGradient(ad.EvalTimeDerivatives(actx).CopyToVector())

    def xdot(x):
        ctx.SetContinuousState(x)
        return system.EvalTimeDerivatives(ctx).CopyToVector()
    fd = fd_jacobian(xdot, X)
    np.testing.assert_allclose(grad, fd, rtol=2e-5, atol=1e-4 * np.abs(fd).max())
    return grad, fd


def test_discrepancy_model_converts_to_autodiff_and_matches_finite_differences():
    nom = NominalParameters.from_dataset("joint-rig", JOINT)
    sys = DiscrepancyModel_[float](nom, 2)
    assert sys.ToAutoDiffXdMaybe() is not None
    rng = np.random.default_rng(2)
    X = np.concatenate([_random_state(nom, rng), _random_state(nom, rng)]).reshape(2, -1).T.ravel()
    p = default_vector()
    for k, v in {"motor_coulomb": 0.1, "ripple_sin1_m1": 0.05, "ripple_cos2_m2": 0.03, "hysteresis_width": 5.0,
                 "joint_coulomb": 0.02, "guide_mu": 0.1, "guide_c0": 0.5}.items():
        p[PARAM_INDEX[k]] = v
    P = np.repeat(p[:, None], 2, axis=1).ravel()

    def setup(system, ctx, autodiff=False):
        T = AutoDiffXd if autodiff else float
        ctx.get_mutable_numeric_parameter(0).SetFromVector(np.array([T(v) for v in P]) if autodiff else P)
        u = np.array([0.3, -0.2, 0.1, 0.4])
        system.get_input_port(0).FixValue(ctx, np.array([T(v) for v in u]) if autodiff else u)
        if not autodiff:
            ctx.SetContinuousState(X)
        return X

    _autodiff_check(sys, setup, len(X))


def test_truth_plant_converts_to_autodiff_and_matches_finite_differences():
    nom = NominalParameters.from_dataset("joint-rig", JOINT)
    truth = draw_truth("joint-rig", ["motor_friction", "spring_hysteresis", "joint_friction", "guide_friction",
                                 "motor_ripple"], np.random.default_rng(3))
    sys = HiddenEffectPlant_[float](nom, truth)
    rng = np.random.default_rng(4)
    X = _random_state(nom, rng)
    X[-2:] = [0.3, -0.4]

    def setup(system, ctx, autodiff=False):
        u = np.array([0.3, -0.2])
        system.get_input_port(0).FixValue(ctx, np.array([AutoDiffXd(v) for v in u]) if autodiff else u)
        if not autodiff:
            ctx.SetContinuousState(X)
        return X

    assert sys.ToAutoDiffXdMaybe() is not None
    grad, fd = _autodiff_check(sys, setup, len(X))    # asserts gradient == finite differences
    assert np.all(np.isfinite(grad)) and np.abs(fd).max() > 0


# ---------------------------------------------------------------- statistics
def test_noise_floor_estimator_recovers_white_noise_on_lab_signals():
    rng = np.random.default_rng(5)
    t = np.arange(20000) * 1e-3
    clean = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (0.3, 1.1, 3.7, 6.0))
    clean[8000:] += np.repeat(rng.uniform(-1, 1, 40), 300)  # steps
    for sigma in (0.003, 0.03, 0.3):
        est = noise_floor(clean + rng.normal(0, sigma, t.size))
        assert est == pytest.approx(sigma, rel=0.06)


def test_window_start_profile_is_generalised_least_squares():
    """|C r|^2 equals the energy minimised over the prior-weighted initial-state
    correction d*, the MAP correction's prediction change is S d*, and white noise leaves dof = m - sum s^2/(1+s^2) on average."""
    rng = np.random.default_rng(6)
    W, m, ns = 3, 40, 4
    S = rng.normal(size=(W, m, ns)) * np.array([0.1, 1.0, 10.0, 0.0])
    proj = Projection(S)
    r = rng.normal(size=(W, m))
    for w in range(W):
        A = S[w]
        d = np.linalg.solve(A.T @ A + np.eye(ns), A.T @ r[w])
        direct = np.sum((r[w] - A @ d) ** 2) + d @ d
        assert np.sum(project(r, proj)[w] ** 2) == pytest.approx(direct, rel=1e-10)
        np.testing.assert_allclose(proj.correction(r)[w], A @ d, rtol=1e-10, atol=1e-12)
    noise = rng.normal(size=(4000, W, m))
    mean_energy = (project(noise, proj) ** 2).sum(axis=2).mean(axis=0)
    np.testing.assert_allclose(mean_energy, proj.dof, rtol=0.03)


def test_catalog_names_are_the_contract():
    from awiwi_drake.discrepancy import EFFECTS, PHYSICAL_EFFECTS
    assert set(PHYSICAL_EFFECTS) == {"motor_friction", "motor_ripple", "spring_hysteresis", "joint_friction",
                                     "guide_friction", "delay", "spring_drift", "backlash"}
    assert {"force_sensor", "nominal_motor", "nominal_spring", "link_sensor", "motor_sensor"} <= set(EFFECTS)
    from awiwi_drake.discrepancy.catalog import PLACED_EFFECTS
    assert set(PLACED_EFFECTS) == {"motor_friction", "guide_friction", "spring_hysteresis"}
    assert len(PARAM_NAMES) == len(set(PARAM_NAMES))


def test_benchmark_scores_follow_their_definitions():
    """Issue-12 rows of benchmarks/bench_discrepancy.py: exact set, spurious names,
    out-of-catalog wrong names and flags, any name when nothing is hidden."""
    import importlib.util
    import pathlib
    path = pathlib.Path(__file__).parent.parent / "benchmarks" / "bench_discrepancy.py"
    spec = importlib.util.spec_from_file_location("bench_discrepancy", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    row = dict(rig="joint-rig", snr_db=30, strength=1.0, transform=None, nuisance_named=[], unexplained=False,
               seconds=1.0, cpu_seconds=1.0, baseline_named=[], baseline_calibration=[])
    rows = [dict(row, row="single_full", hidden=["delay"], named=["delay", "motor_friction"]),
            dict(row, row="single_full", hidden=["delay"], named=["delay"], baseline_named=["delay"]),
            dict(row, row="nothing", hidden=[], named=[], nuisance_named=["force_sensor"]),
            dict(row, row="nothing", hidden=[], named=[]),
            dict(row, row="out_of_catalog", hidden=[], named=["spring_hysteresis"], transform="link_bias"),
            dict(row, row="out_of_catalog", hidden=[], named=[], transform="link_bias", unexplained=True),
            dict(row, row="out_of_catalog", hidden=[], named=[], transform="motor_bias",
                 nuisance_named=["motor_sensor"]),
            dict(row, row="three", hidden=["delay", "motor_ripple", "joint_friction"],
                 named=["motor_ripple", "joint_friction", "delay"]),
            # a "not separable" class (first member = the step's name) names the hidden member, in every row alike
            dict(row, row="three", hidden=["guide_friction", "delay", "motor_ripple"],
                 named=["motor_ripple", "motor_friction", "delay"], status=["confirmed", "not separable", "confirmed"],
                 members=[[], ["motor_friction", "guide_friction"], []]),
            dict(row, row="single_full", hidden=["delay"], named=["delay", "motor_friction"],
                 status=["confirmed", "not separable"], members=[[], ["motor_friction", "guide_friction"]])]
    s = bench.summarise(rows)["workflow"]
    assert s["exact_single_full"] == (pytest.approx(1 / 3), 3)   # a class without a hidden member is a name
    assert s["spurious"] == (pytest.approx(2 / 5), 5)
    assert s["exact_by_class"] == (pytest.approx(1 / 5), 5)
    assert s["nothing_any_name"] == (0.5, 2) and s["nothing_physical_name"] == (0.0, 2)
    assert s["out_of_catalog_wrong_name"] == (pytest.approx(1 / 3), 3)
    assert s["out_of_catalog_flagged"] == (pytest.approx(2 / 3), 3)
    assert s["exact_three"] == (1.0, 2)
    b = bench.summarise(rows)["baseline"]
    assert b["exact_single_full"] == (pytest.approx(1 / 3), 3) and b["nothing_any_name"] == (0.0, 2)


def test_benchmark_is_resumable_and_claims_each_case_once(tmp_path, monkeypatch):
    """One JSON per dataset; a finished or claimed case is skipped (a second run, or a parallel one)."""
    import importlib.util
    import pathlib
    path = pathlib.Path(__file__).parent.parent / "benchmarks" / "bench_discrepancy.py"
    spec = importlib.util.spec_from_file_location("bench_discrepancy", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    calls = []
    monkeypatch.setattr(bench, "run_case",
                        lambda case, cache=None: calls.append(case) or {"row": case[0], "seed": case[4]})
    a = ("nothing", "joint-rig", [], 30, 5, 1.0, None, 10.0)
    b = ("single_full", "joint-rig", ["delay"], 30, 6, 1.0, None, 10.0)
    assert bench.run_and_store(a, str(tmp_path))["seed"] == 5
    assert bench.run_and_store(a, str(tmp_path)) is None                 # finished: skipped
    (tmp_path / f"{bench.case_id(b)}.claim").write_text("1\n")           # another process runs it
    assert bench.run_and_store(b, str(tmp_path)) is None
    assert calls == [a]
    assert [r["seed"] for r in bench.collect(tmp_path)] == [5]
    assert not list(tmp_path.glob("*.claim"))[1:] and not list(tmp_path.glob("*.tmp"))


def test_benchmark_runs_its_cases_through_run_sweep_and_scores_each(tmp_path, monkeypatch, capsys):
    """Issue 11 item 8: the discrepancy benchmark goes through the package's one sweep runner; every case is
    stored and scored once, and a bad ``--jobs`` is one line."""
    import awiwi_drake.analysis.sweep as sweep
    bench = _bench()
    seen = []
    real = sweep.run_sweep
    monkeypatch.setattr(sweep, "run_sweep", lambda fn, points, **kw: seen.append(len(points)) or real(fn, points, **kw))
    row = dict(rig="joint-rig", snr_db=30, strength=1.0, nuisance_named=[], unexplained=False, named=[], seconds=1.0,
               cpu_seconds=1.0, baseline_named=[], baseline_calibration=[], verdict="no effect",
               floor_ratio_after=1.0, generate_seconds=0.0, gap_closed=float("nan"), applied={})
    monkeypatch.setattr(bench, "run_case", lambda case, cache=None: dict(
        row, row=case[0], rig=case[1], hidden=list(case[2]), seed=case[4], transform=case[6]))
    assert bench.main(["--quick", "--jobs", "1", "--no-cache", "--out", str(tmp_path)]) == 0
    n = len(bench.cases(1, True))
    assert seen == [n] and len(list((tmp_path / "cases").glob("*.json"))) == n
    assert capsys.readouterr().out.count(" done] ") == n
    summ = json.loads((tmp_path / "discrepancy_benchmark.json").read_text())
    assert len(summ["rows"]) == n
    with pytest.raises(SystemExit) as e:
        bench.main(["--quick", "--jobs", "0", "--out", str(tmp_path)])
    assert e.value.code == 2 and "--jobs" in capsys.readouterr().err


class _LinearInAEngine:
    """A closed-form stand-in for the replay engine: window residual
    ``y - a1 phi1 - a2 phi2 - F_c tanh(v / v_s)`` (linear in the nominal_link pair ``a``, nonlinear in the
    joint_friction pair), with a random window-start profile of two states."""

    def __init__(self, truth: np.ndarray, rng):
        W, m = 8, 60
        self.train = np.arange(W) % 2 == 0
        self.test = ~self.train
        self.starts = np.arange(W)
        self.phi = rng.normal(size=(2, W, m))
        self.v = rng.normal(scale=0.1, size=(W, m))
        self.S = rng.normal(size=(W, m, 2))
        self.y = self.model(truth[None])[0]

    def model(self, P):
        a = P[:, [PARAM_INDEX["link_inertia_rel"], PARAM_INDEX["link_damping_add"]]]
        c, vs = P[:, PARAM_INDEX["joint_coulomb"]], P[:, PARAM_INDEX["joint_velocity"]]
        return (np.einsum("sk,kwm->swm", a, self.phi)
                + c[:, None, None] * np.tanh(self.v[None] / vs[:, None, None]))

    def evaluate(self, P, windows):
        return (self.y[None] - self.model(np.atleast_2d(P)))[:, windows]

    def projector(self, p, windows):
        return self.evaluate(p, windows)[0], Projection(self.S[windows])


def test_screen_estimate_is_the_parameter_change_where_the_residual_is_linear():
    """The screen regresses the residual on sensitivities per unit parameter (finite differences divided
    by their step), so its coefficient is the parameter change itself: where the residual is linear in an
    effect's parameters (the nominal_link pair of the closed-form stand-in), the screen's estimate is the
    generating value, whatever the screening step (a coefficient scaled by the step again would put it at
    step x value: 0.05 x 0.1 and 2e-4 x 0.01 here)."""
    from awiwi_drake.discrepancy.catalog import EFFECTS
    from awiwi_drake.discrepancy.screen import ResidualState, screen
    from awiwi_drake.parameters.discrepancy import CatalogBounds

    truth = default_vector()
    truth[PARAM_INDEX["link_inertia_rel"]], truth[PARAM_INDEX["link_damping_add"]] = 0.1, 0.01
    eng = _LinearInAEngine(truth, np.random.default_rng(11))
    out = screen(ResidualState(eng, default_vector()), [EFFECTS["nominal_link"]], CatalogBounds(), "joint-rig")
    assert out[0]["params"] == pytest.approx({"link_inertia_rel": 0.1, "link_damping_add": 0.01}, rel=1e-9)


def test_candidate_fit_with_accepted_parameters_free_to_first_order_reaches_the_joint_optimum():
    """Variable projection over the accepted effects' sensitivities (fit.HeldLinear): where the
    residual is linear in the accepted parameters, the candidate-only simulation fit reaches the joint
    optimum (here the generating parameters, residual zero) and carries the accepted parameters' change;
    holding them fixed instead ends elsewhere."""
    from awiwi_drake.discrepancy.fit import HeldLinear, fit_parameters
    from awiwi_drake.discrepancy.screen import ResidualState
    from awiwi_drake.parameters.discrepancy import CatalogBounds, DiscrepancySettings

    truth = default_vector()
    for name, v in (("link_inertia_rel", 0.1), ("link_damping_add", 0.01), ("joint_coulomb", 0.03),
                    ("joint_velocity", 0.08)):
        truth[PARAM_INDEX[name]] = v
    eng = _LinearInAEngine(truth, np.random.default_rng(11))
    base = default_vector()   # accepted nominal_link at zero: off by the truth
    start = base.copy()
    start[PARAM_INDEX["joint_coulomb"]], start[PARAM_INDEX["joint_velocity"]] = 0.01, 0.05
    st = ResidualState(eng, base)
    bounds, settings = CatalogBounds(), DiscrepancySettings()
    held = HeldLinear(st, ["link_inertia_rel", "link_damping_add"], bounds)
    fo = fit_parameters(st, ["joint_coulomb", "joint_velocity"], start, bounds, settings, held)
    np.testing.assert_allclose(fo.p, truth, atol=1e-6)
    assert np.abs(fo.r0).max() < 1e-5
    fixed = fit_parameters(st, ["joint_coulomb", "joint_velocity"], start, bounds, settings)
    assert np.abs(fixed.p - truth).max() > 1e-3


def test_fit_stops_at_the_resolution_of_the_data():
    """``fit_parameters(..., resolution=)`` (a candidate's fit, ``DiscrepancySettings.fit_resolution``): the
    optimiser stops at the first trial step whose Gauss-Newton predicted reduction of the training cost is below
    the resolution (squared noise units). With unit noise on the closed-form stand-in (residual in noise units),
    the training cost it ends at is within the resolution of the optimum the optimiser's own tolerances reach
    (xtol 1e-8), in fewer evaluations, and each parameter within sqrt(resolution) standard errors of it."""
    from awiwi_drake.discrepancy.fit import fit_parameters
    from awiwi_drake.discrepancy.screen import ResidualState
    from awiwi_drake.parameters.discrepancy import CatalogBounds, DiscrepancySettings

    truth = default_vector()
    for name, v in (("link_inertia_rel", 0.1), ("link_damping_add", 0.01), ("joint_coulomb", 0.03),
                    ("joint_velocity", 0.08)):
        truth[PARAM_INDEX[name]] = v
    rng = np.random.default_rng(13)
    eng = _LinearInAEngine(truth, rng)
    eng.y = eng.y + rng.normal(size=eng.y.shape)
    start = default_vector()
    start[PARAM_INDEX["joint_coulomb"]], start[PARAM_INDEX["joint_velocity"]] = 0.01, 0.05
    st = ResidualState(eng, default_vector())
    names = ["link_inertia_rel", "link_damping_add", "joint_coulomb", "joint_velocity"]
    bounds, settings = CatalogBounds(), DiscrepancySettings()
    assert settings.fit_resolution > 0
    full = fit_parameters(st, names, start, bounds, settings)
    stop = fit_parameters(st, names, start, bounds, settings, resolution=settings.fit_resolution)
    cost = {k: float((project(fo.r0, fo.projection)[eng.train] ** 2).sum()) for k, fo in (("full", full),
                                                                                          ("stop", stop))}
    assert 0.0 <= cost["stop"] - cost["full"] <= settings.fit_resolution, cost
    assert stop.nfev < full.nfev
    # near a quadratic optimum dp^T J^T J dp <= (cost difference) <= resolution, so by Cauchy-Schwarz each
    # parameter is within sqrt(resolution) standard errors (se >= sqrt([(J^T J)^-1]_ii), its s^2 >= 1)
    idx = [PARAM_INDEX[n] for n in names]
    se = np.array([full.se[n] for n in names])
    assert np.all(np.abs(stop.p[idx] - full.p[idx]) <= np.sqrt(settings.fit_resolution) * se), \
        (stop.p[idx] - full.p[idx]) / se


def test_held_parameter_taken_past_its_bound_is_reported_at_the_bound():
    """A first-order step of an accepted parameter past its physical bound is held at the bound AND named in
    ``at_bound`` (the decision's at-bound rule then sees it), never clipped silently."""
    from awiwi_drake.discrepancy.catalog import param_specs
    from awiwi_drake.discrepancy.fit import HeldLinear, fit_parameters
    from awiwi_drake.discrepancy.screen import ResidualState
    from awiwi_drake.parameters.discrepancy import CatalogBounds, DiscrepancySettings

    bounds, settings = CatalogBounds(), DiscrepancySettings()
    high = {s.name: s.high for s in param_specs(bounds)}["link_damping_add"]
    truth = default_vector()
    truth[PARAM_INDEX["link_damping_add"]] = 2.0 * high          # the data ask for twice the bound
    truth[PARAM_INDEX["joint_coulomb"]], truth[PARAM_INDEX["joint_velocity"]] = 0.03, 0.08
    eng = _LinearInAEngine(truth, np.random.default_rng(12))
    start = default_vector()
    start[PARAM_INDEX["joint_coulomb"]], start[PARAM_INDEX["joint_velocity"]] = 0.01, 0.05
    st = ResidualState(eng, default_vector())
    held = HeldLinear(st, ["link_inertia_rel", "link_damping_add"], bounds)
    fo = fit_parameters(st, ["joint_coulomb", "joint_velocity"], start, bounds, settings, held)
    assert fo.p[PARAM_INDEX["link_damping_add"]] == high
    assert "link_damping_add" in fo.at_bound


# ---------------------------------------------------------------- out-of-catalog truth effects (issue 12)
def test_out_of_catalog_truth_physics_is_its_closed_form():
    """The link spring adds ``-k_j q / m`` to the link acceleration and the torque-constant error ``e u / B``
    to each motor's, nothing else (derivatives of the truth plant at a random state)."""
    nom = NominalParameters.from_dataset("joint-rig", JOINT)
    X = _random_state(nom, np.random.default_rng(6))
    u = np.array([0.3, -0.2])

    def xdot(truth):
        sys = HiddenEffectPlant_[float](nom, truth)
        ctx = sys.CreateDefaultContext()
        ctx.SetContinuousState(X)
        sys.get_input_port(0).FixValue(ctx, u)
        return sys.EvalTimeDerivatives(ctx).CopyToVector()

    base = xdot({})
    d_spring = xdot({"link_spring": 0.2}) - base
    expect = np.zeros_like(base)
    expect[1] = -0.2 * X[0] / JOINT["link_inertia"]
    np.testing.assert_allclose(d_spring, expect, rtol=1e-12, atol=1e-12 * np.abs(base).max())
    d_kt = xdot({"torque_constant": -0.1}) - base
    expect = np.zeros_like(base)
    expect[4:6] = -0.1 * u / JOINT["motor_inertia"]
    np.testing.assert_allclose(d_kt, expect, rtol=1e-12, atol=1e-12 * np.abs(base).max())


def test_out_of_catalog_sensor_effects_are_their_closed_form_on_the_same_physics():
    """Noise-free, the same seed: the force-sensor quadratic gain reads ``f (1 + c f)`` of the clean force
    and the pickup adds ``A sigma sin(2 pi 50 t + phi)`` to one force signal only; the out-of-catalog draws
    leave every other signal bit for bit (their own random stream)."""
    from awiwi_drake.discrepancy import make_truth_dataset
    from awiwi_drake.parameters.discrepancy import TruthGeneratorParams
    gen = TruthGeneratorParams(duration=0.3)
    base = make_truth_dataset("joint-rig", [], snr_db=None, seed=9004, gen=gen)
    nl = make_truth_dataset("joint-rig", [], snr_db=None, seed=9004, gen=gen, unknown=["force_nonlinearity"])
    c = nl.meta["truth"]["force_nonlinearity"]
    assert 3e-3 <= abs(c) <= 6e-3
    for k, f in base.outputs.items():
        np.testing.assert_array_equal(nl.outputs[k], f * (1 + c * f) if k.startswith("tendon_force") else f)
    pk = make_truth_dataset("joint-rig", [], snr_db=None, seed=9004, gen=gen, unknown=["force_pickup"])
    p = pk.meta["truth"]["force_pickup"]
    ch = f"tendon_force_{p['channel']}"
    sigma = base.outputs[ch].std() * 10 ** (-30 / 20)   # noise-free: sized on the 30 dB noise
    for k, f in base.outputs.items():
        if k == ch:
            np.testing.assert_allclose(pk.outputs[k] - f, p["amplitude"] * sigma * np.sin(
                2 * np.pi * 50.0 * base.time + p["phase"]), rtol=0, atol=1e-12 * np.abs(f).max())
        else:
            np.testing.assert_array_equal(pk.outputs[k], f)
    with pytest.raises(ValueError, match="link_spring"):
        make_truth_dataset("tendon-rig", [], seed=1, gen=gen, unknown=["link_spring"])
    with pytest.raises(ValueError, match="unknown= 'gravity'"):
        make_truth_dataset("joint-rig", [], seed=1, gen=gen, unknown=["gravity"])


def _bench():
    import importlib.util
    import pathlib
    path = pathlib.Path(__file__).parent.parent / "benchmarks" / "bench_discrepancy.py"
    spec = importlib.util.spec_from_file_location("bench_discrepancy", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def test_benchmark_dataset_cache_hit_is_fresh_generation_bit_for_bit_and_a_changed_generator_misses(tmp_path,
                                                                                                    monkeypatch):
    from awiwi_drake.discrepancy import make_truth_dataset
    from awiwi_drake.parameters.discrepancy import TruthGeneratorParams
    bench = _bench()
    files = [f.as_posix() for f in bench.generator_files()]
    assert any(f.endswith("discrepancy/truth.py") for f in files)
    assert any(f.endswith("discrepancy/finger_truth.py") for f in files)
    assert any(f.endswith("parameters/yaml_io.py") for f in files)           # imported inside a function
    assert not any(f.endswith(("discrepancy/workflow.py", "discrepancy/fit.py", "discrepancy/screen.py"))
                   for f in files)                                             # the workflow is not the generator
    rig_files = [f.as_posix() for f in bench.generator_files((bench.generator_of("joint-rig"),))]
    assert any(f.endswith("hand/plant.py") for f in files) and not any(f.endswith("hand/plant.py") for f in rig_files)
    assert bench.generator_of("finger-index") == "awiwi_drake.discrepancy.finger_truth"   # the hand is the finger's
    case = ("single_full", "joint-rig", ["delay"], 30, 1001, 1.0, None, 0.2)
    gen = lambda: make_truth_dataset("joint-rig", ["delay"], snr_db=30, seed=1001,  # noqa: E731
                                     gen=TruthGeneratorParams(duration=0.2))
    fresh, hit = bench.cached_dataset(case, gen, tmp_path)
    assert not hit and len(list(tmp_path.glob("*.npz"))) == 1
    cached, hit = bench.cached_dataset(case, gen, tmp_path)
    assert hit
    assert (cached.name, cached.rig) == (fresh.name, fresh.rig)
    for a, b in ((cached.inputs, fresh.inputs), (cached.outputs, fresh.outputs),
                 (cached.meta["clean_outputs"], fresh.meta["clean_outputs"]), ({"t": cached.time}, {"t": fresh.time})):
        assert a.keys() == b.keys()
        for k in a:
            assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k])
    assert cached.parameters == fresh.parameters and cached.initial_state == fresh.initial_state
    assert json.dumps(cached.meta["truth"]) == json.dumps(fresh.meta["truth"])
    # another case misses; a changed generator source misses (what is generated does not matter for the key)
    gen = lambda: fresh   # noqa: E731
    assert not bench.cached_dataset(case[:4] + (1002,) + case[5:], gen, tmp_path)[1]
    src = tmp_path / "generator_part.py"
    src.write_text("K = 1\n")
    monkeypatch.setattr(bench, "generator_files", lambda *generators: [*files, src])
    monkeypatch.setattr(bench, "_FINGERPRINT", {})
    assert not bench.cached_dataset(case, gen, tmp_path)[1]
    monkeypatch.setattr(bench, "_FINGERPRINT", {})
    assert bench.cached_dataset(case, gen, tmp_path)[1]                 # same source: a hit
    src.write_text("K = 2\n")
    monkeypatch.setattr(bench, "_FINGERPRINT", {})
    assert not bench.cached_dataset(case, gen, tmp_path)[1]             # changed source: a miss
    src.write_text('"""A docstring."""\n\nK = 2  # a comment\n')
    monkeypatch.setattr(bench, "_FINGERPRINT", {})
    assert bench.cached_dataset(case, gen, tmp_path)[1]                 # docstring and comment only: a hit
    n = len(list(tmp_path.glob("*.npz")))
    assert not bench.cached_dataset(case, gen, None)[1] and len(list(tmp_path.glob("*.npz"))) == n  # no cache


def test_benchmark_cache_options_are_refused_together_or_on_a_file(tmp_path, capsys):
    """``--cache DIR`` with ``--no-cache`` (which used to win silently) and ``--cache`` naming a file (np.savez
    failed later, inside a worker) stop before any case runs: exit 2, one line naming the option."""
    bench = _bench()
    with pytest.raises(SystemExit) as exc:
        bench.main(["--quick", "--out", str(tmp_path), "--cache", str(tmp_path / "c"), "--no-cache"])
    assert exc.value.code == 2 and "--no-cache: not allowed with argument --cache" in capsys.readouterr().err
    (tmp_path / "f").write_text("x")
    with pytest.raises(SystemExit) as exc:
        bench.main(["--quick", "--out", str(tmp_path), "--cache", str(tmp_path / "f")])
    assert exc.value.code == 2 and f"--cache {tmp_path / 'f'}: exists and is not a folder" in capsys.readouterr().err
    assert not (tmp_path / "cases").exists()                            # nothing ran

def test_torque_constant_error_is_exactly_a_recalibration():
    """The benchmark's ``unknown`` row counts a calibration as the right answer for a torque-constant error
    (``bench_discrepancy.UNKNOWN_EXPECTED``): dividing the motor equation by ``1 + e`` makes the truth with
    applied torque ``(1 + e) u`` the catalog model with every mass, damping and the spring force scaled by
    ``1 / (1 + e)`` and a force-sensor gain ``e``, in scaled time-derivatives and measurements alike."""
    nom = NominalParameters.from_dataset("joint-rig", JOINT)
    e = -0.09
    s = 1.0 / (1.0 + e) - 1.0
    P = default_vector()
    for name, v in (("motor_inertia_rel", s), ("link_inertia_rel", s), ("spring_scale_rel", s), ("force_gain", e),
                    ("motor_damping_add", s * JOINT["motor_damping"]), ("link_damping_add", s * JOINT["link_damping"])):
        P[PARAM_INDEX[name]] = v
    truth = HiddenEffectPlant_[float](nom, {"torque_constant": e})
    ctx = truth.CreateDefaultContext()
    rng = np.random.default_rng(8)
    for _ in range(3):
        X = _random_state(nom, rng)
        X[-2:] = 0.0
        u = rng.uniform(-0.5, 0.5, 2)
        ctx.SetContinuousState(X)
        truth.get_input_port(0).FixValue(ctx, u)
        ref = truth.EvalTimeDerivatives(ctx).CopyToVector()
        ours = model_derivatives(nom, X[:, None], u[:, None], P[:, None])[:, 0]
        np.testing.assert_allclose(ours[:6], ref[:6], rtol=1e-9, atol=1e-9 * np.abs(ref).max())
        y_ref = truth.GetOutputPort("measurement").Eval(ctx)
        y = model_measurements(nom, X[:, None], P[:, None])[:, 0]
        np.testing.assert_allclose(y, y_ref, rtol=1e-12, atol=1e-12)

