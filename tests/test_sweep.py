"""The sweep runner: any Executor, input order kept, failures named or recorded."""

import concurrent.futures as cf
import math

import numpy as np
import pytest

from awiwi_drake.analysis.sweep import grid_points, monte_carlo_points, run_sweep


def damped_period(*, stiffness, inertia, damping=0.0):
    """Period of a damped torsion oscillator (closed form), a physics function to sweep."""
    wn2 = stiffness / inertia
    zeta_w = damping / (2 * inertia)
    if wn2 <= zeta_w ** 2:
        raise ValueError(f"overdamped: stiffness={stiffness}, damping={damping}")
    return 2 * math.pi / math.sqrt(wn2 - zeta_w ** 2)


def test_grid_and_executors_agree_and_keep_order():
    grid = {"stiffness": [0.5, 1.0, 2.0], "inertia": [1e-3, 2e-3]}
    serial = run_sweep(damped_period, grid, executor="serial", fixed={"damping": 1e-3})
    with cf.ThreadPoolExecutor(2) as ex:
        threads = run_sweep(damped_period, grid, executor=ex, fixed={"damping": 1e-3}, chunksize=2)
    default = run_sweep(damped_period, grid, fixed={"damping": 1e-3})           # process pool
    assert default.executor == "ProcessPoolExecutor" and threads.executor == "ThreadPoolExecutor"
    assert [p for p in serial.points] == grid_points(grid)
    for res in (threads, default):
        np.testing.assert_allclose(res.values, serial.values, rtol=0, atol=0)
    # physics: T = 2 pi sqrt(J / k) for light damping
    k, J = serial.column("stiffness"), serial.column("inertia")
    np.testing.assert_allclose(serial.values, 2 * np.pi * np.sqrt(J / k), rtol=1e-3)


def test_failures_are_named_or_recorded():
    pts = [{"stiffness": 1.0, "inertia": 1e-3, "damping": 1.0}, {"stiffness": 1.0, "inertia": 1e-3}]
    res = run_sweep(damped_period, pts, executor="serial", on_error="record")
    assert list(res.errors) == [0] and "overdamped" in res.errors[0] and res.values[1] > 0
    with pytest.raises(RuntimeError, match="stiffness"):
        run_sweep(damped_period, pts, executor="serial")
    with pytest.raises(ValueError, match="both swept and fixed"):
        run_sweep(damped_period, pts, executor="serial", fixed={"stiffness": 2.0})


def test_monte_carlo_points_are_reproducible_and_inside_the_box():
    a = monte_carlo_points({"x": 1e-3, "y": 1.0}, {"x": 1e3, "y": 2.0}, 500, seed=3, log=True)
    b = monte_carlo_points({"x": 1e-3, "y": 1.0}, {"x": 1e3, "y": 2.0}, 500, seed=3, log=True)
    assert a == b
    x = np.array([p["x"] for p in a])
    assert x.min() >= 1e-3 and x.max() <= 1e3
    assert abs(np.median(np.log10(x))) < 0.5           # log-uniform: median near the geometric centre
    with pytest.raises(ValueError, match="low\\['x'\\]"):
        monte_carlo_points({"x": 2.0}, {"x": 1.0}, 3)


def joint_rig_point(*, pretension, joint_angle):
    """Joint stiffness [Nm/rad] and slowest non-zero pole [1/s] of the joint rig (Drake in the worker)."""
    from awiwi_drake.analysis import linearize
    from awiwi_drake.rigs import joint_rig

    rig = joint_rig()
    op = rig.operating_point(pretension=pretension, joint_angle=joint_angle)
    poles = linearize(rig, op).poles
    return float(op.joint_stiffness), float(np.min(np.abs(poles[poles != 0])))


def test_sweep_on_a_local_dask_cluster_gives_the_serial_numbers():
    distributed = pytest.importorskip("dask.distributed")
    grid = {"pretension": [10.0, 20.0, 40.0], "joint_angle": [0.1]}
    serial = run_sweep(joint_rig_point, grid, executor="serial")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=40) as cluster, distributed.Client(cluster) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        res = run_sweep(joint_rig_point, grid, executor=client.get_executor(), chunksize=1)
        pids = set(client.run(__import__("os").getpid).values())
        # ch. 16 Algorithm 3 goes through the same runner in batches: the cluster finds the serial search's gains
        from awiwi_drake.control.optimal_gains import monte_carlo_gains
        from awiwi_drake.reproductions.ch16_optimal_backstepping import table_16_1_rig
        mc = monte_carlo_gains(table_16_1_rig(), samples=300, seed=4, executor=client.get_executor(), batch=100)
    mc_serial = monte_carlo_gains(table_16_1_rig(), samples=300, seed=4, executor="serial", batch=100)
    assert mc.gains == mc_serial.gains and mc.distance == mc_serial.distance
    assert len(pids) == 2 and __import__("os").getpid() not in pids          # two separate worker processes
    assert res.points == serial.points and res.values == serial.values         # bit-identical numbers
    stiff = {(p["pretension"], p["joint_angle"]): v[0] for p, v in zip(res.points, res.values)}
    assert stiff[(10.0, 0.1)] < stiff[(20.0, 0.1)] < stiff[(40.0, 0.1)]        # co-contraction stiffens the joint
