"""Tendon force distribution (ch. 7, Algorithm 2): exact torque, bounds, stiffness, explicit infeasibility."""

import numpy as np
import pytest

from awiwi_drake.control.force_distribution import (
    TendonForceDistribution, TendonStiffnessMap, coupling_nullspace, index_finger_coupling, joint_stiffness)
from awiwi_drake.parameters.hand_control import ForceDistributionParams

C1, C2 = 1e4, 5e6   # quadratic test spring f = c1 x + c2 x^2: k_t(f) = sqrt(c1^2 + 4 c2 f) in closed form


def _kmap():
    return TendonStiffnessMap.from_function(lambda f: np.sqrt(C1 ** 2 + 4 * C2 * np.maximum(f, 0.0)), 0.0, 200.0)


def _thumb_like(q):
    """Position-dependent 4 x 2 coupling (tensegrity-like base, lengths |A(q) - A0|) and its Hessian."""
    A0 = np.array([[0.01, 0.01, -0.03], [-0.01, 0.01, -0.03], [0.01, -0.01, -0.03], [-0.01, -0.01, -0.03]])
    def h(qq):
        c0, s0, c1, s1 = np.cos(qq[0]), np.sin(qq[0]), np.cos(qq[1]), np.sin(qq[1])
        R = np.array([[c1, 0, s1], [0, 1, 0], [-s1, 0, c1]]) @ np.array([[1, 0, 0], [0, c0, -s0], [0, s0, c0]])
        A = (R @ np.array([[0.008, 0.008, 0.0], [-0.008, 0.008, 0.0], [0.008, -0.008, 0.0],
                           [-0.008, -0.008, 0.0]]).T).T
        return np.linalg.norm(A - A0, axis=1)
    eps = 1e-5
    P = np.stack([(h(q + eps * e) - h(q - eps * e)) / (2 * eps) for e in np.eye(2)], axis=1)
    H = np.stack([np.stack([(h(q + eps * (ei + ej)) - h(q + eps * (ei - ej)) - h(q - eps * (ei - ej))
                             + h(q - eps * (ei + ej))) / (4 * eps ** 2) for ej in np.eye(2)], axis=1)
                  for ei in np.eye(2)], axis=2)
    return P, H


def test_nullspace_produces_no_torque_and_pinv_inverts():
    P = index_finger_coupling()
    pinv_PT, W, rank = coupling_nullspace(P)
    assert rank == 4 and W.shape == (8, 4)
    np.testing.assert_allclose(P.T @ W, 0.0, atol=1e-15)
    np.testing.assert_allclose(P.T @ pinv_PT, np.eye(4), atol=1e-12)


def test_index_finger_exact_torque_bounds_and_reachable_stiffness():
    P = index_finger_coupling()
    kmap = _kmap()
    fd = TendonForceDistribution(kmap, coupling=P)
    rng = np.random.default_rng(3)
    for _ in range(6):
        f_star = rng.uniform(20.0, 150.0, 8)
        tau = -P.T @ f_star                      # tau = -P^T f (ARCHITECTURE.md)
        K_des = joint_stiffness(P, kmap(f_star)[0], f_star)
        res = fd.solve(tau, K_des)
        assert res.status == "ok"
        assert res.torque_error < 1e-12 * max(1.0, np.linalg.norm(tau))   # numerical precision
        assert res.bound_violation == 0.0
        p = fd.params
        assert np.all(res.forces >= p.f_min) and np.all(res.forces <= p.f_max)
        assert res.stiffness_error < 1e-3        # a reachable stiffness is found
        np.testing.assert_allclose(res.stiffness, res.stiffness.T, atol=1e-12)
        assert np.all(np.linalg.eigvalsh(res.stiffness) > 0)


def test_unreachable_stiffness_is_approximated_with_exact_torque():
    P = index_finger_coupling()
    fd = TendonForceDistribution(_kmap(), coupling=P)
    tau = np.array([0.1, -0.05, 0.08, 0.02])
    res_lo = fd.solve(tau, 0.01 * np.eye(4))     # far below what f >= f_min allows
    res_hi = fd.solve(tau, 1e3 * np.eye(4))      # far above what f <= f_max allows
    for res in (res_lo, res_hi):
        assert res.status == "ok" and res.torque_error < 1e-12
        assert res.bound_violation == 0.0
    # the stiffness error pushes forces towards the lower (upper) bound
    assert res_lo.forces.mean() < 40.0 < 130.0 < res_hi.forces.mean()


def test_infeasible_request_is_reported_not_clipped():
    P = index_finger_coupling()
    fd = TendonForceDistribution(_kmap(), coupling=P)
    tau = np.array([5.0, 0.0, 0.0, 0.0])          # needs ~300 N differences: outside [5, 170] N
    res = fd.solve(tau, np.eye(4))
    assert res.status == "infeasible"
    assert res.torque_error < 1e-12                # the torque is still exact ...
    assert res.bound_violation > 10.0              # ... and the violation is reported
    assert np.any(res.forces < fd.params.f_min)


def test_online_svd_position_dependent_coupling_with_geometric_stiffness():
    kmap = _kmap()
    fd = TendonForceDistribution(kmap, ForceDistributionParams(f_min=5.0, f_max=170.0))
    q = np.array([0.3, -0.2])
    P, H = _thumb_like(q)
    f_star = np.array([40.0, 70.0, 90.0, 60.0])
    K_des = joint_stiffness(P, kmap(f_star)[0], f_star, H)
    res = fd.solve(-P.T @ f_star, K_des, P=P, hessian=H)
    assert res.status == "ok" and res.torque_error < 1e-12
    assert res.stiffness_error < 1e-3
    # the geometric term is included: the same forces without it give a different stiffness
    assert np.linalg.norm(joint_stiffness(P, kmap(res.forces)[0], res.forces) - res.stiffness) > 1e-3


def test_offline_and_online_agree_for_constant_coupling():
    P = index_finger_coupling()
    kmap = _kmap()
    tau = np.array([0.2, 0.1, -0.1, 0.05])
    K_des = 8.0 * np.eye(4)
    a = TendonForceDistribution(kmap, coupling=P).solve(tau, K_des)
    b = TendonForceDistribution(kmap).solve(tau, K_des, P=P)
    # the null-space basis may differ by an orthogonal transform; the forces must not
    np.testing.assert_allclose(a.forces, b.forces, rtol=1e-6, atol=1e-6)


def test_bad_input_names_the_argument():
    fd = TendonForceDistribution(_kmap(), coupling=index_finger_coupling())
    with pytest.raises(ValueError, match="tau_des"):
        fd.solve(np.zeros(3), np.eye(4))
    with pytest.raises(ValueError, match="symmetric"):
        fd.solve(np.zeros(4), np.triu(np.ones((4, 4))))
    with pytest.raises(ValueError, match="coupling P"):
        TendonForceDistribution(_kmap(), coupling=np.ones((2, 4)))
    with pytest.raises(ValueError, match="f_min"):
        ForceDistributionParams(f_min=100.0, f_max=50.0)
