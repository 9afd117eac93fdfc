"""One runner for parameter sweeps and Monte-Carlo studies: :func:`run_sweep` evaluates ``fn(**point)`` at each
point of a grid (or of a list of points) on any :class:`concurrent.futures.Executor` (a process pool by default;
threads, ``"serial"``, or a Dask ``client.get_executor()``: see its parameters).  Every sweep in awiwi_drake (gain
studies of ch. 15, Algorithm 3 of ch. 16, ...) goes through it.  Points are sent in chunks (``chunksize`` points per
task) to amortise the per-task overhead (pickling, scheduling: ~1 ms per task for a process pool).
"""

from __future__ import annotations

import concurrent.futures as cf
import itertools
import os
import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

__all__ = ["SweepResult", "SweepPointError", "run_sweep", "grid_points", "monte_carlo_points"]


class SweepPointError(RuntimeError):
    """A sweep point raised; the message names the point and the original error."""


@dataclass
class SweepResult:
    """Outcome of :func:`run_sweep`: the evaluated ``points`` (dicts, in input order), ``values`` (``fn(**point)``
    per point, None where it failed), ``errors`` (index -> ``"ExceptionType: message"`` of the failed points, with
    ``on_error="record"``), the whole sweep's ``wall_time`` [s] and the ``executor`` type's name."""

    points: list
    values: list
    errors: dict = field(default_factory=dict)
    wall_time: float = 0.0
    executor: str = ""

    def column(self, name: str) -> np.ndarray:
        """Values of one swept parameter as an array (in point order)."""
        try:
            return np.array([p[name] for p in self.points])
        except KeyError:
            raise ValueError(f"SweepResult: no swept parameter {name!r}; have {sorted(self.points[0])}") from None


def grid_points(grid: Mapping[str, Sequence]) -> list[dict]:
    """Cartesian product of ``{name: values}`` as a list of point dicts (last name varies fastest)."""
    if not isinstance(grid, Mapping) or not grid:
        raise ValueError("grid_points: grid must be a non-empty mapping name -> sequence of values")
    names = list(grid)
    for n in names:
        vals = grid[n]
        if isinstance(vals, (str, bytes)) or not hasattr(vals, "__len__") or len(vals) == 0:
            raise ValueError(f"grid_points: grid[{n!r}] must be a non-empty sequence of values")
    return [dict(zip(names, combo)) for combo in itertools.product(*(list(grid[n]) for n in names))]


def monte_carlo_points(low: Mapping[str, float], high: Mapping[str, float], n: int, *,
                       seed: int | None = None, log: bool = False) -> list[dict]:
    """``n`` >= 1 points drawn uniformly in the box ``[low, high]`` (mappings name -> float with the same names), or
    log-uniformly (``log=True``, needs ``low > 0``); ``seed`` seeds :func:`numpy.random.default_rng`."""
    if set(low) != set(high):
        raise ValueError(f"monte_carlo_points: low and high name different parameters: {sorted(low)} vs {sorted(high)}")
    if int(n) < 1:
        raise ValueError(f"monte_carlo_points: n = {n} must be >= 1")
    rng = np.random.default_rng(seed)
    cols = {}
    for name in low:
        lo, hi = float(low[name]), float(high[name])
        if not lo < hi:
            raise ValueError(f"monte_carlo_points: low[{name!r}] = {lo} must be below high[{name!r}] = {hi}")
        if log:
            if lo <= 0:
                raise ValueError(f"monte_carlo_points: log sampling needs low[{name!r}] > 0, got {lo}")
            cols[name] = np.exp(rng.uniform(np.log(lo), np.log(hi), int(n)))
        else:
            cols[name] = rng.uniform(lo, hi, int(n))
    return [{name: float(cols[name][i]) for name in low} for i in range(int(n))]


def _run_chunk(fn: Callable, points: list[dict], fixed: dict, record: bool) -> list[tuple[bool, Any]]:
    out = []
    for p in points:
        try:
            out.append((True, fn(**fixed, **p)))
        except Exception as exc:  # noqa: BLE001 - reported per point
            if not record:
                raise SweepPointError(f"sweep point {p}: {type(exc).__name__}: {exc}\n"
                                      f"{traceback.format_exc()}") from exc
            out.append((False, f"{type(exc).__name__}: {exc}"))
    return out


def _run_batch(fn: Callable, points: list[dict], fixed: dict, record: bool) -> list[tuple[bool, Any]]:
    """``fn(points, **fixed)`` once for a whole chunk (a batched simulation), one value per point."""
    try:
        values = list(fn(points, **fixed))
    except Exception as exc:  # noqa: BLE001 - reported for the batch
        if not record:
            raise SweepPointError(f"sweep batch of {len(points)} points from {points[0]}: {type(exc).__name__}: "
                                  f"{exc}\n{traceback.format_exc()}") from exc
        return [(False, f"{type(exc).__name__}: {exc}")] * len(points)
    if len(values) != len(points):
        raise SweepPointError(f"sweep batch: fn returned {len(values)} values for {len(points)} points")
    return [(True, v) for v in values]


def run_sweep(fn: Callable[..., Any], points: Mapping[str, Sequence] | Iterable[Mapping[str, Any]], *,
              executor: cf.Executor | str | None = None, max_workers: int | None = None,
              chunksize: int | None = None, fixed: Mapping[str, Any] | None = None,
              on_error: str = "raise", quiet: bool | None = None, batch: int | None = None) -> SweepResult:
    """Evaluate ``fn(**fixed, **point)`` at every point (or, with ``batch``, ``fn(points, **fixed)`` per chunk).

    ``points``: ``{name: values}`` for a Cartesian grid (:func:`grid_points`) or an explicit list of point dicts
    (e.g. :func:`monte_carlo_points`); ``fixed``: keyword arguments passed unchanged to every call.  ``executor``:
    None, a ProcessPoolExecutor for this call with ``max_workers`` processes (default ``min(2, os.cpu_count())``),
    shut down afterwards (``fn`` and the point values must be picklable: a module-level function, not a lambda);
    ``"serial"``: evaluate in this process (debugging, tiny sweeps); an Executor (``ThreadPoolExecutor``: cheap
    start-up, good when ``fn`` releases the GIL as Drake's C++ simulation does; a process pool;
    ``dask.distributed.Client.get_executor()``; anything with ``Executor.submit``) is used as is and left running.
    ``chunksize``: points per submitted task (default: about 4 tasks per worker).  ``on_error``: ``"raise"`` re-raises
    the first failing point (named), ``"record"`` records failures in ``SweepResult.errors``.  ``quiet``: no progress
    bar (points done / total; by default it shows on a terminal or in a notebook,
    :func:`awiwi_drake.config.progress_enabled`).  ``batch``: ``fn`` takes a *list* of up to ``batch`` point dicts (and
    ``**fixed``) and returns one value per point, e.g. by simulating them as the copies of one
    :func:`awiwi_drake.rigs.batch.batched_joint_rig`; each chunk is one task (``chunksize`` is then ``batch``) and a
    failing batch fails all its points.
    """
    from awiwi_drake.config import progress_bar

    if on_error not in ("raise", "record"):
        raise ValueError(f"run_sweep: on_error must be 'raise' or 'record', got {on_error!r}")
    if not callable(fn):
        raise ValueError(f"run_sweep: fn must be callable, got {fn!r}")
    pts = grid_points(points) if isinstance(points, Mapping) else [dict(p) for p in points]
    if not pts:
        raise ValueError("run_sweep: no points to evaluate")
    fixed = dict(fixed or {})
    clash = sorted(set(fixed) & set().union(*pts))
    if clash:
        raise ValueError(f"run_sweep: parameter {clash[0]!r} is both swept and fixed")
    record = on_error == "record"
    if batch is not None:
        if int(batch) != batch or batch < 1:
            raise ValueError(f"run_sweep: batch = {batch!r} must be a positive integer (points per call of fn)")
        if chunksize is not None:
            raise ValueError("run_sweep: give batch or chunksize, not both (a batch is one task)")
        chunksize = int(batch)
    runner = _run_chunk if batch is None else _run_batch
    t0 = time.perf_counter()

    if isinstance(executor, str):
        if executor != "serial":
            raise ValueError(f"run_sweep: executor must be an Executor, 'serial' or None, got {executor!r}")
        results = []
        with progress_bar(total=len(pts), desc="sweep", unit="point", quiet=quiet) as bar:
            step = 1 if batch is None else int(batch)
            for i in range(0, len(pts), step):
                results.extend(runner(fn, pts[i:i + step], fixed, record))
                bar.update(len(pts[i:i + step]))
        name = "serial"
    else:
        owned = executor is None
        workers = max_workers or min(2, os.cpu_count() or 1)
        ex = cf.ProcessPoolExecutor(max_workers=workers) if owned else executor
        n_workers = workers if owned else max(1, getattr(ex, "_max_workers", 2) or 2)
        size = int(chunksize) if chunksize else max(1, -(-len(pts) // (4 * n_workers)))
        if size < 1:
            raise ValueError(f"run_sweep: chunksize = {chunksize} must be >= 1")
        chunks = [pts[i:i + size] for i in range(0, len(pts), size)]
        try:
            futures = [ex.submit(runner, fn, c, fixed, record) for c in chunks]
            sizes = {f: len(c) for f, c in zip(futures, chunks)}
            with progress_bar(total=len(pts), desc="sweep", unit="point", quiet=quiet) as bar:
                for f in cf.as_completed(futures):  # points done, as chunks finish
                    bar.update(sizes[f])
            results = []
            for f in futures:  # keeps input order
                results.extend(f.result())
        finally:
            if owned:
                ex.shutdown(wait=True, cancel_futures=True)
        name = type(ex).__name__
    values = [v if ok else None for ok, v in results]
    errors = {i: v for i, (ok, v) in enumerate(results) if not ok}
    return SweepResult(points=pts, values=values, errors=errors, wall_time=time.perf_counter() - t0, executor=name)
