#!/usr/bin/env python3
"""Lines of ``awiwi_drake/`` that serve the features the package had when issue 9 was filed (commit 518f8fe).

Issue 9 asks for "fewer lines than before for the same features". This script measures that with one method on
two checkouts: the filing commit (checked out read-only with ``git worktree add --detach``) and this checkout.

1. **The same invocations on both.** ``INVOCATIONS`` below lists the filing commit's features as things a user ran:
   every CLI command of its README with its options, its README's Python blocks, and every code cell of its eight
   notebooks. Each is run on both checkouts; where the current API differs, the entry gives the current equivalent
   call beside the filing one (``main=``), with the reason in ``why``. On this checkout the notebooks are its own
   01-08 (the filing notebooks carried through every API change), with the cells and lines that show later
   features edited out (``drop``/``replace``). Bad-input invocations (one per command family) are in the list
   too, so error paths count on both sides alike.
2. **Under coverage.** Each invocation runs in its own process under ``coverage run`` (``AWIWI_SHORT=1``, an empty
   kernel cache per checkout so the law functions the compiled kernels are generated from run in Python on both).
   A numba function counts as run when its dispatcher holds a compiled signature at exit; a function whose source
   text is read by ``inspect.getsource`` (kernels generated from it) counts as run too.
3. **Lines of what ran.** Every module is cut by its syntax tree into *units*: each function or method (whole span,
   decorators to last line; nested functions belong to their enclosing one) and the module's *rest* (imports,
   constants, class headers and fields, comments and blanks between definitions). Units partition the file, so
   they sum to ``wc -l``. A function counts when a line of its body ran; a module's rest counts when the module
   was imported. *Feature lines* = lines of counted units; *code lines* = the same without blank, comment-only
   and docstring lines.

Usage (from the checkout root; about 15-25 CPU minutes per checkout, ``nice`` it)::

    python3 scripts/feature_lines.py --out /tmp/feature_lines            # both checkouts, markdown on stdout
    python3 scripts/feature_lines.py --out DIR --only main --reuse        # recount from DIR's coverage data

The markdown it prints is what docs/ARCHITECTURE.md "Lines for the same features" shows.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import io
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time
import tokenize

FILING_COMMIT = "518f8fe"
ROOT = pathlib.Path(__file__).resolve().parent.parent


# --------------------------------------------------------------------------------------------------------------
# The filing commit's features, as invocations. ``filing`` runs on 518f8fe; ``main`` (when given) is the current
# equivalent, otherwise the same text runs on both.
# --------------------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Invocation:
    id: str
    kind: str                      # "cli": argv list | "code": Python source | "notebook": notebooks/NN* stem
    filing: object
    main: object = None            # the current equivalent; None = the same as filing
    why: str = ""                  # why main's form is the same feature
    exit: object = 0               # expected exit status (bad input: 2), or (filing, main) when they differ
    replace: tuple = ()            # notebooks: (old, new) replacements removing later features from main's cells
    drop: tuple = ()               # notebooks: main's cells holding one of these strings are later features: skipped

    def payload(self, era: str):
        return self.filing if era == "filing" or self.main is None else self.main


FJ = "backstepping,backstepping-position,cascaded,lqr,optimal-backstepping,pd,pole-placement,sdre,two-time-scale"
JR = "backstepping,cascaded,lqr,pd,pole-placement,sdre,two-time-scale"       # the filing commit's joint-rig list
TR = "tendon-pd,tendon-scheduled,tendon-sdre"
TARGETS = ["tendon-rig", "flexible-joint", "joint-rig", "finger-thumb", "finger-index", "finger-middle",
           "finger-ring", "finger-fifth", "hand"]
BACKEND = "one drive implementation on main: the filing commit's --backend python|symbolic choice is gone (one way)"

README_QUICKSTART = '''
import numpy as np
from awiwi_drake.rigs import flexible_joint_rig, joint_rig
from awiwi_drake.analysis import linearize, lqr, simulate, rig_monitors

rig = flexible_joint_rig()
print(linearize(rig).A)
design = lqr(rig, np.diag([10, 0.01, 1, 0.01]), [[1e-2]])
print(design.K, design.closed_loop_poles)
rig = joint_rig()
op = rig.operating_point(pretension=30.0, link_angle=0.2)
print(op.info["joint_stiffness"], "Nm/rad")
ctx = rig.context(op)
rig.diagram.GetInputPort("motor_torque").FixValue(ctx, op.motor_torque + [0.8, -0.8])
result = simulate(rig.diagram, ctx, 0.2, log=("link_angle", "tendon_force"), monitors=rig_monitors(rig))
print(result["link_angle"][-1], *result.events, sep="\\n")
'''
README_QUICKSTART_MAIN = '''
import numpy as np
from awiwi_drake.rigs import flexible_joint_rig, joint_rig
from awiwi_drake.analysis import linearize, lqr, simulate, rig_monitors

rig = flexible_joint_rig()
print(linearize(rig).A)
design = lqr(rig, np.diag([10, 0.01, 1, 0.01]), [[1e-2]])
print(design.K, design.closed_loop_poles)
rig = joint_rig()
op = rig.operating_point(pretension=30.0, joint_angle=0.2)
print(op.joint_stiffness, "Nm/rad")
result = simulate(rig, rig.context(op), 0.2, inputs={"motor_torque": op.motor_torque + [0.8, -0.8]},
                  log=("joint_angle", "tendon_force"), monitors=rig_monitors(rig))
print(result["joint_angle"][-1], *result.events, sep="\\n")
'''
README_HAND = '''
from awiwi_drake.analysis import linearize
from awiwi_drake.hand import finger_diagram, hand_diagram, closed_loop
rig = finger_diagram(finger="thumb")
lin = linearize(rig, rig.operating_point(pretension=30, joint_angles=[0.4, -0.3, 0.2, 0.1]))
hand = hand_diagram()
loop = closed_loop(hand, wrist_compensation=True, estimator=True)
'''
README_HAND_MAIN = '''
from awiwi_drake.analysis import linearize
from awiwi_drake.hand import finger_diagram, hand_diagram
from awiwi_drake.control import closed_loop, make_controller
rig = finger_diagram(finger="thumb")
lin = linearize(rig, rig.operating_point(pretension=30, joint_angles=[0.4, -0.3, 0.2, 0.1]))
hand = hand_diagram()
loop = closed_loop(hand, make_controller("joint-pd", hand), estimator=hand.link_estimator())
'''
README_PARAMS = '''
from awiwi_drake.rigs import joint_rig
from awiwi_drake.parameters import JointRigParams
rig = joint_rig(params=JointRigParams().with_overrides({"pretension": "40"}))
try:
    JointRigParams().with_overrides({"pretension": "-5"})
except ValueError as exc:
    print(exc)
'''
README_DIAGNOSE = '''
import glob, os
from awiwi_drake.discrepancy import diagnose, load_dataset, write_report
csv = sorted(glob.glob(os.path.join(os.environ["AWIWI_DATA"], "*.csv")))[0]
dx = diagnose(load_dataset(csv), progress=print)
write_report(dx, "dx")
'''

INVOCATIONS = [
    # ---- CLI: rigs
    Invocation("demo", "cli", ["demo", "--out", "demo"]),
    Invocation("demo-python", "cli", ["demo", "--backend", "python", "--out", "demo_py"], ["demo", "--out", "demo_py"],
               why=BACKEND),
    Invocation("export-diagrams", "cli", ["export-diagrams", "--out", "diagrams"]),
    *[Invocation(f"linearize-{t}", "cli", ["linearize", t]) for t in TARGETS],
    Invocation("linearize-json-set", "cli", ["linearize", "joint-rig", "--set", "pretension=40", "--json"]),
    Invocation("lqr-flexible-joint", "cli", ["lqr", "flexible-joint", "--q", "10,0.01,1,0.01", "--r", "0.01", "--json"]),
    Invocation("lqr-joint-rig", "cli", ["lqr", "joint-rig", "--q", "100,1,1,1,0.01,0.01", "--r", "1,1"]),
    *[Invocation(f"params-{t}", "cli", ["params", t]) for t in TARGETS],
    # ---- CLI: compare, every controller the filing commit registered for each rig
    Invocation("compare-list", "cli", ["compare", "--rig", "joint-rig", "--list"]),
    Invocation("compare-tendon-rig", "cli", ["compare", "--rig", "tendon-rig", "--controllers", TR, "--short",
                                             "--out", "cmp_t"]),
    Invocation("compare-flexible-joint", "cli", ["compare", "--rig", "flexible-joint", "--controllers", FJ,
                                                 "--short", "--out", "cmp_f"], exit=(0, 1),
               why="exit 1 on main: backstepping-position's disturbance row diverges on both commits; main reports "
                   "a diverged row with a non-zero exit (non-negotiable 3), the filing commit exited 0"),
    Invocation("compare-joint-rig", "cli", ["compare", "--rig", "joint-rig", "--controllers", JR, "--short",
                                            "--out", "cmp_j"]),
    Invocation("compare-options", "cli", ["compare", "--rig", "joint-rig", "--controllers", "pd,lqr", "--tests",
                                          "step,disturbance", "--rate", "1500", "--delay", "666e-6",
                                          "--saturation", "2", "--short", "--out", "cmp_o"]),
    # ---- CLI: hand
    Invocation("animate-hand", "cli", ["animate", "--out", "hand.html", "--duration", "0.3"]),
    Invocation("animate-index", "cli", ["animate", "--out", "index.html", "--target", "index", "--duration", "0.3",
                                        "--backend", "python"],
               ["animate", "--out", "index.html", "--target", "finger-index", "--duration", "0.3"],
               why=BACKEND + "; the finger's one spelling (issue 9 item 6): index -> finger-index"),
    Invocation("export-hand-diagrams", "cli", ["export-hand-diagrams", "--out", "hand_diagrams"],
               ["export-diagrams", "--out", "hand_diagrams"],
               why="merged into export-diagrams, which writes the hand/finger graphs too (one way)"),
    # ---- CLI: discrepancy (datasets written to data/, diagnosed by the next two)
    Invocation("make-dataset-joint", "cli",
               ["make-dataset", "--rig", "joint", "--hide", "joint_friction", "--snr", "30", "--out", "data",
                "--name", "joint"],
               ["make-dataset", "--rig", "joint-rig", "--hide", "joint_friction", "--snr", "30", "--out", "data",
                "--name", "joint"], why="the rig's one spelling (issue 9 item 6): joint -> joint-rig"),
    Invocation("make-dataset-tendon", "cli",
               ["make-dataset", "--rig", "tendon", "--hide", "motor_ripple", "--nuisance", "force_sensor", "--seed", "3",
                "--duration", "6", "--out", "data", "--name", "tendon"],
               ["make-dataset", "--rig", "tendon-rig", "--hide", "motor_ripple", "--nuisance", "force_sensor", "--seed",
                "3", "--duration", "6", "--out", "data", "--name", "tendon"],
               why="the rig's one spelling (issue 9 item 6): tendon -> tendon-rig"),
    Invocation("diagnose-joint", "cli", ["diagnose", "data/joint.csv", "--report", "dx_joint", "--json",
                                         "dx_joint.json"]),
    Invocation("diagnose-tendon", "cli", ["diagnose", "data/tendon.csv", "--quiet", "--json", "dx_tendon.json"]),
    # ---- README Python blocks
    Invocation("readme-quickstart", "code", README_QUICKSTART, README_QUICKSTART_MAIN,
               why="link_angle -> joint_angle (issue 9 item 6); OperatingPoint.info -> typed field; a constant "
                   "input through simulate(inputs=...) instead of FixValue on the diagram (one simulate)"),
    Invocation("readme-hand", "code", README_HAND, README_HAND_MAIN,
               why="hand.diagrams.closed_loop (fixed PD) -> control.closed_loop with the registered joint-pd "
                   "(wrist feed-forward on by default) and the link estimator (issue 9 item 3)"),
    Invocation("readme-params", "code", README_PARAMS),
    Invocation("readme-diagnose", "code", README_DIAGNOSE),
    # ---- bad input: one per command family, exit 2 on both
    Invocation("bad-linearize-set", "cli", ["linearize", "joint-rig", "--set", "pretension=-5"], exit=2),
    Invocation("bad-lqr-q", "cli", ["lqr", "flexible-joint", "--q", "1,2", "--r", "0.01"], exit=2),
    Invocation("bad-compare-controller", "cli", ["compare", "--rig", "joint-rig", "--controllers", "nosuch",
                                                 "--out", "cmp_bad"], exit=2),
    Invocation("bad-diagnose-file", "cli", ["diagnose", "data/missing.csv"], exit=2),
    Invocation("bad-make-dataset-effect", "cli", ["make-dataset", "--rig", "joint", "--hide", "nosuch", "--out",
                                                  "data_bad"],
               ["make-dataset", "--rig", "joint-rig", "--hide", "nosuch", "--out", "data_bad"], exit=2,
               why="the rig's one spelling"),
]

# ---- the eight notebooks. main's notebooks 01-08 are the filing notebooks carried through every API change by the
# engineers who changed the API (cell for cell; `git diff 518f8fe main -- notebooks/`). What they gained since is
# removed here: cells and lines that show features added after the filing commit.
NOTEBOOKS = [
    Invocation("notebook-01", "notebook", "01", why="API moves only (closed_loop/ClosedLoop, poles_vs_pretension, "
                                                    "joint_angle)"),
    Invocation("notebook-02", "notebook", "02", why="API moves only; the pole sweep turns off the motor ripple added "
                                                    "to the finger plant since (its detent makes the open loop unstable)"),
    Invocation("notebook-03", "notebook", "03", why="API moves only; the hand's linearisation turns off ripple and "
                                                    "guide friction added since; the progress bar added since removed",
               replace=(('from awiwi_drake.config import SimulationProgress\n'
                         'from awiwi_drake.export.animation import record_animation\n\n'
                         'with SimulationProgress("grasp recording") as progress:   # a bar in Jupyter (off in short mode / CI)\n'
                         '    anim = record_animation(OUT / "hand.html", target="finger-index" if SHORT else "hand", duration=0.3 if SHORT else 1.5,\n'
                         '                            progress=progress)',
                         'from awiwi_drake.export.animation import record_animation\n'
                         'anim = record_animation(OUT / "hand.html", target="finger-index" if SHORT else "hand", '
                         'duration=0.3 if SHORT else 1.5)'),)),
    Invocation("notebook-04", "notebook", "04", why="API moves only; the hand tendon SDRE gains cell (issue 10) skipped",
               drop=("hand_tendon_sdre_gains",)),
    Invocation("notebook-05", "notebook", "05", why="API moves; Fig 12.4's study now also simulates the perturbed loop "
                                                    "and sweeps target poles (kept: one call); the progress bar removed",
               replace=(('from awiwi_drake.config import progress_bar\n'
                         'tests = ["step", "disturbance"] if SHORT else ["step", "sine", "disturbance", "sweep"]\n'
                         'with progress_bar(total=len(names) * len(tests), desc="compare", unit="test") as bar:   # off in short mode / CI\n'
                         '    result = compare_controllers(flexible_joint_rig, names, rate_hz=3000.0,\n'
                         '                                 tests=tests, params=params, progress=lambda label: bar.update(1))',
                         'result = compare_controllers(flexible_joint_rig, names, rate_hz=3000.0,\n'
                         '                             tests=["step", "disturbance"] if SHORT else None, params=params)'),)),
    Invocation("notebook-06", "notebook", "06", why="API moves; shorter runs of two studies (the same calls)"),
    Invocation("notebook-07", "notebook", "07", why="API moves; the optimal (7.6) distribution beside Algorithm 2 "
                                                    "(added since) removed",
               replace=(('opt = finger_force_distribution("index", method="optimal")\n', ''),
                        ('rng.uniform(0.5, 1.6)', 'rng.uniform(0.8, 1.2)'),
                        ('    best, dt_opt = opt.timed_solve(tau, K_des)\n'
                         '    rows.append((res.status, best.status, res.torque_error, best.torque_error, res.bound_violation,\n'
                         '                 best.bound_violation, res.stiffness_error, best.stiffness_error, dt, dt_opt))\n'
                         'status = [r[0] for r in rows] + [r[1] for r in rows]\n'
                         'err = np.array([r[2:] for r in rows])\n'
                         'dict(ok=status.count("ok"), max_torque_error=err[:, :2].max(), max_violation=err[:, 2:4].max(),\n'
                         '     median_stiffness_error_alg2=np.median(err[:, 4]), median_stiffness_error_optimal=np.median(err[:, 5]),\n'
                         '     median_time_us_alg2=1e6 * np.median(err[:, 6]), median_time_us_optimal=1e6 * np.median(err[:, 7]))',
                         '    rows.append((res.status, res.torque_error, res.bound_violation, res.stiffness_error, dt))\n'
                         'status = [r[0] for r in rows]\n'
                         'err = np.array([r[1:] for r in rows])\n'
                         'dict(ok=status.count("ok"), max_torque_error=err[:, 0].max(), max_violation=err[:, 1].max(),\n'
                         '     median_stiffness_error=np.median(err[:, 2]), median_time_us=1e6 * np.median(err[:, 3]))'),
                        ('assert status.count("ok") == len(status) and err[:, :2].max() < 1e-10 and err[:, 2:4].max() == 0.0\n'
                         'assert np.all(err[:, 5] <= err[:, 4] + 1e-9)                  # the optimum is never worse than Algorithm 2\n'
                         'fig, ax = plt.subplots(figsize=(5, 4))\n'
                         'ax.loglog(err[:, 4], np.maximum(err[:, 5], 1e-9), "o"); ax.plot([1e-9, 1], [1e-9, 1], "k--")\n'
                         'ax.set_xlabel("relative stiffness error, Algorithm 2"); ax.set_ylabel("relative stiffness error, optimal (7.6)")\n'
                         'save(fig, "ch7_distribution_alg2_vs_optimal")\n',
                         'assert status.count("ok") == len(rows) and err[:, 0].max() < 1e-10 and err[:, 1].max() == 0.0\n'),
                        ('bad_opt = opt.solve(np.array([5.0, 0, 0, 0]), np.eye(4))\n'
                         'assert bad_opt.status == "infeasible" and bad_opt.bound_violation > 0 and bad_opt.torque_error < 1e-10\n',
                         ''))),
    Invocation("notebook-08", "notebook", "08", why="the same cells (short mode: 2.5 s datasets instead of 4 s)"),
]
INVOCATIONS += NOTEBOOKS


# --------------------------------------------------------------------------------------------------------------
# Running one invocation (inside the coverage process)
# --------------------------------------------------------------------------------------------------------------

def _exec(spec_path: str) -> int:
    spec = json.loads(pathlib.Path(spec_path).read_text())
    import inspect
    source_hits: set = set()
    getsource = inspect.getsource

    def recording_getsource(obj):
        try:
            code = getattr(obj, "__code__", None)
            if code is not None:
                source_hits.add((code.co_filename, code.co_firstlineno))
        finally:
            pass
        return getsource(obj)

    inspect.getsource = recording_getsource
    failures, rc = [], 0
    t0 = time.time()
    try:
        if spec["kind"] == "cli":
            from awiwi_drake.cli import main
            try:
                rc = int(main(spec["payload"]) or 0)
            except SystemExit as exc:      # argparse
                rc = exc.code if isinstance(exc.code, int) else 2
        else:
            cells = [spec["payload"]] if spec["kind"] == "code" else spec["payload"]
            ns: dict = {"__name__": "__main__"}
            for i, cell in enumerate(cells):
                try:
                    exec(compile(cell, f"<{spec['id']} cell {i}>", "exec"), ns)
                except Exception as exc:  # noqa: BLE001 -- recorded and reported, the run goes on
                    failures.append(f"cell {i}: {type(exc).__name__}: {str(exc).strip().splitlines()[0][:200] if str(exc).strip() else ''}")
            rc = 1 if failures else 0
    finally:
        numba_hits = []
        for mod in list(sys.modules.values()):
            if not getattr(mod, "__name__", "").startswith("awiwi_drake"):
                continue
            for value in list(vars(mod).values()):
                py_func = getattr(value, "py_func", None)
                if py_func is not None and getattr(value, "signatures", None):
                    numba_hits.append((py_func.__code__.co_filename, py_func.__code__.co_firstlineno))
        pathlib.Path(spec["extras"]).write_text(json.dumps({
            "rc": rc, "failures": failures, "seconds": time.time() - t0,
            "numba_hits": numba_hits, "source_hits": sorted(source_hits)}))
    return 0


# --------------------------------------------------------------------------------------------------------------
# Notebooks: the filing commit's code cells; on main with the replacements of each entry
# --------------------------------------------------------------------------------------------------------------

def _notebook_cells(tree: pathlib.Path, stem: str) -> list[str]:
    nb = json.loads(next((tree / "notebooks").glob(f"{stem}*.ipynb")).read_text())
    cells = []
    for c in nb["cells"]:
        if c["cell_type"] != "code":
            continue
        src = "".join(c["source"])
        # IPython magics have no meaning outside a kernel
        cells.append("\n".join(line for line in src.splitlines() if not line.lstrip().startswith(("%", "!"))))
    return cells


def _payload(inv: Invocation, era: str, tree: pathlib.Path):
    if inv.kind != "notebook":
        return inv.payload(era)
    cells = _notebook_cells(tree, inv.filing)
    if era == "main":
        cells = [c for c in cells if not any(d in c for d in inv.drop)]
        for old, new in inv.replace:
            joined = "\n\x00\n".join(cells)
            if old not in joined:
                raise SystemExit(f"feature_lines: notebook {inv.filing}: the text to replace is not in main's "
                                 f"notebook any more: {old.splitlines()[0]!r}")
            cells = joined.replace(old, new).split("\n\x00\n")
    return cells


# --------------------------------------------------------------------------------------------------------------
# Running every invocation on one checkout
# --------------------------------------------------------------------------------------------------------------

def run_era(era: str, tree: pathlib.Path, work: pathlib.Path, jobs: int, only: set | None) -> None:
    era_dir = work / era
    cov_dir = era_dir / "coverage"
    for sub in ("coverage", "extras", "kernels", "run"):   # a full run starts empty (kernel cache included)
        if only is None and (era_dir / sub).exists():
            shutil.rmtree(era_dir / sub)
        (era_dir / sub).mkdir(parents=True, exist_ok=True)
    for inv_id in only or ():                              # a partial run replaces those invocations' data
        for f in list(cov_dir.glob(f"{inv_id}.*")) + list((era_dir / "extras").glob(f"{inv_id}.*")):
            f.unlink()
    rc_file = era_dir / "coveragerc"
    rc_file.write_text(f"[run]\nsource = {tree / 'awiwi_drake'}\nparallel = true\n"
                       f"concurrency = thread,multiprocessing\n")
    env = dict(os.environ, PYTHONPATH=str(tree), AWIWI_SHORT="1", MPLBACKEND="Agg",
               AWIWI_KERNEL_CACHE=str(era_dir / "kernels"), AWIWI_DATA=str(era_dir / "run" / "data"))
    env.pop("COVERAGE_PROCESS_START", None)
    run_dir = era_dir / "run"          # one folder: make-dataset writes data/ that diagnose reads
    pending = [inv for inv in INVOCATIONS if only is None or inv.id in only]
    running: list = []
    while pending or running:
        while pending and len(running) < jobs and not (running and _depends(pending[0], running)):
            inv = pending.pop(0)
            spec = era_dir / "extras" / f"{inv.id}.spec.json"
            spec.write_text(json.dumps({"id": inv.id, "kind": "code" if inv.kind == "code" else inv.kind,
                                        "payload": _payload(inv, era, tree),
                                        "extras": str(era_dir / "extras" / f"{inv.id}.json")}))
            cmd = [sys.executable, "-m", "coverage", "run", f"--rcfile={rc_file}",
                   f"--data-file={cov_dir / inv.id}", str(pathlib.Path(__file__).resolve()), "_exec", str(spec)]
            log = open(era_dir / "extras" / f"{inv.id}.log", "w")
            env_i = dict(env, AWIWI_OUT=str(run_dir / f"out_{inv.id}"))
            running.append((inv, subprocess.Popen(cmd, cwd=run_dir, env=env_i, stdout=log, stderr=subprocess.STDOUT),
                            time.time()))
        time.sleep(0.2)
        for item in list(running):
            inv, proc, t0 = item
            if proc.poll() is not None:
                running.remove(item)
                print(f"[{era}] {inv.id}: {time.time() - t0:.0f} s", file=sys.stderr, flush=True)


def _depends(inv: Invocation, running) -> bool:
    """diagnose-* and readme-diagnose read what make-dataset-* writes: wait for them."""
    if inv.id.startswith(("diagnose", "readme-diagnose", "bad-diagnose")):
        return any(r[0].id.startswith("make-dataset") for r in running)
    return False


# --------------------------------------------------------------------------------------------------------------
# Counting
# --------------------------------------------------------------------------------------------------------------

@dataclasses.dataclass
class Unit:
    name: str
    start: int                     # first line (decorators included), 1-based
    end: int
    body: tuple                    # (first body line, last line): a line run here means the function ran


def _units(tree: ast.Module) -> list[Unit]:
    units: list[Unit] = []

    def visit(body, prefix):
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                start = min([node.lineno] + [d.lineno for d in node.decorator_list])
                first = node.body[0]
                if _is_docstring(first) and len(node.body) > 1:
                    first = node.body[1]
                units.append(Unit(prefix + node.name, start, node.end_lineno, (first.lineno, node.end_lineno)))
            elif isinstance(node, ast.ClassDef):
                visit(node.body, prefix + node.name + ".")

    visit(tree.body, "")
    return units


def _is_docstring(node) -> bool:
    return isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)


def _code_lines(source: str, tree: ast.Module) -> set[int]:
    """Lines holding code: not blank, not only a comment, not part of a string statement (docstring)."""
    doc = set()
    for node in ast.walk(tree):
        if _is_docstring(node):
            doc.update(range(node.lineno, node.end_lineno + 1))
    code = set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type in (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
                        tokenize.ENDMARKER):
            continue
        for line in range(tok.start[0], tok.end[0] + 1):
            if line not in doc:
                code.add(line)
    return code


def _in_package(path: str) -> str:
    """``awiwi_drake/...`` of a measured file, whichever checkout folder it was measured in (``--reuse``)."""
    return path[path.rindex("/awiwi_drake/") + 1:] if "/awiwi_drake/" in path else path


def count_era(era: str, tree: pathlib.Path, work: pathlib.Path) -> dict:
    import coverage
    era_dir = work / era
    pkg = tree / "awiwi_drake"
    executed: dict[str, set] = {}
    per_inv: dict[str, dict] = {}
    for f in sorted((era_dir / "coverage").glob("*")):
        inv_id = f.name.split(".")[0]
        data = coverage.CoverageData(basename=str(f))
        data.read()
        for path in data.measured_files():
            lines = set(data.lines(path) or ())
            executed.setdefault(_in_package(path), set()).update(lines)
            per_inv.setdefault(inv_id, {}).setdefault(path, set()).update(lines)
    extra: dict[str, set] = {}
    runs = {}
    for f in sorted((era_dir / "extras").glob("*.json")):
        if f.name.endswith(".spec.json"):
            continue
        ex = json.loads(f.read_text())
        runs[f.stem] = {"rc": ex["rc"], "failures": ex["failures"], "seconds": round(ex["seconds"], 1)}
        for path, line in ex["numba_hits"] + ex["source_hits"]:
            extra.setdefault(_in_package(path), set()).add(line)
    files = {}
    for path in sorted(pkg.rglob("*.py")):
        source = path.read_text()
        mod = ast.parse(source)
        n = len(source.splitlines())
        code = _code_lines(source, mod)
        units = _units(mod)
        run = executed.get(_in_package(str(path)), set())
        hits = extra.get(_in_package(str(path)), set())
        in_unit = set()
        defs = []
        for u in units:
            span = set(range(u.start, u.end + 1))
            in_unit |= span
            ran = bool(run & set(range(u.body[0], u.body[1] + 1))) or bool(hits & span)
            defs.append({"name": u.name, "lines": len(span), "code": len(span & code), "reached": ran,
                         "start": u.start})
        rest = set(range(1, n + 1)) - in_unit
        imported = bool(run)
        files[str(path.relative_to(tree))] = {
            "lines": n, "code": len(code), "imported": imported, "executed": len(run),
            "rest": len(rest), "rest_code": len(rest & code), "defs": defs}
    inv_lines = {}
    for inv_id, cov in per_inv.items():
        inv_lines[inv_id] = sum(len(v) for v in cov.values())
    bench = sum(len(f.read_text().splitlines()) for f in (tree / "benchmarks").glob("*.py"))
    return {"era": era, "tree": str(tree), "commit": _commit(tree), "files": files, "runs": runs,
            "executed_statements": inv_lines, "benchmark_lines": bench}


def _commit(tree: pathlib.Path) -> str:
    """HEAD, and the git tree of awiwi_drake/ (equal trees = the same package, whichever commit holds it)."""
    out = [subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", rev], capture_output=True,
                          text=True).stdout.strip() for rev in ("HEAD", "HEAD:awiwi_drake")]
    dirty = subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "--", "awiwi_drake"],
                           capture_output=True, text=True).stdout.strip()
    return f"{out[0]}, package tree {out[1]}" + (" + uncommitted edits" if dirty else "")


def summarise(count: dict) -> dict:
    tot = {"lines": 0, "code": 0, "defs_reached": 0, "defs_reached_code": 0, "rest_imported": 0,
           "rest_imported_code": 0, "modules": 0, "modules_imported": 0}
    by_pkg: dict[str, dict] = {}
    for rel, f in count["files"].items():
        parts = pathlib.PurePath(rel).parts
        pkg = parts[1] if len(parts) > 2 else parts[1].removesuffix(".py")
        b = by_pkg.setdefault(pkg, {"lines": 0, "reached": 0, "code": 0, "reached_code": 0})
        tot["lines"] += f["lines"]
        tot["code"] += f["code"]
        tot["modules"] += 1
        b["lines"] += f["lines"]
        b["code"] += f["code"]
        if f["imported"]:
            tot["modules_imported"] += 1
            tot["rest_imported"] += f["rest"]
            tot["rest_imported_code"] += f["rest_code"]
            b["reached"] += f["rest"]
            b["reached_code"] += f["rest_code"]
        for d in f["defs"]:
            if d["reached"]:
                tot["defs_reached"] += d["lines"]
                tot["defs_reached_code"] += d["code"]
                b["reached"] += d["lines"]
                b["reached_code"] += d["code"]
    tot["reached"] = tot["defs_reached"] + tot["rest_imported"]
    tot["reached_code"] = tot["defs_reached_code"] + tot["rest_imported_code"]
    later = {m for mods in LATER_FEATURES.values() for m in mods}
    tot["reached_in_later_modules"] = sum(
        (f["rest"] if f["imported"] else 0) + sum(d["lines"] for d in f["defs"] if d["reached"])
        for rel, f in count["files"].items() if rel.removeprefix("awiwi_drake/") in later)
    tot["executed_statements"] = sum(f["executed"] for f in count["files"].values())
    return {"total": tot, "by_package": by_pkg}


# --------------------------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------------------------

def report(counts: dict[str, dict]) -> str:
    out = []
    sums = {era: summarise(c) for era, c in counts.items()}
    eras = list(counts)
    head = " | ".join(f"{e} ({counts[e]['commit']})" for e in eras)
    out.append(f"| lines of `awiwi_drake/` | {head} |")
    out.append("|---|" + "---:|" * len(eras))
    rows = [("all (`wc -l`)", "lines"), ("  code only", "code"),
            ("**reached by the filing-era features**", "reached"), ("  code only", "reached_code"),
            ("  of which: functions/methods that ran", "defs_reached"),
            ("  of which: module rest of imported modules", "rest_imported"),
            ("not reached by them", None)]
    for label, key in rows:
        if key is None:
            vals = [s["total"]["lines"] - s["total"]["reached"] for s in sums.values()]
        else:
            vals = [s["total"][key] for s in sums.values()]
        out.append(f"| {label} | " + " | ".join(f"{v:,}" for v in vals) + " |")
    out.append("| modules imported / all | " + " | ".join(
        f"{s['total']['modules_imported']} / {s['total']['modules']}" for s in sums.values()) + " |")
    out.append("| `benchmarks/*.py` (not counted above) | " + " | ".join(
        f"{c['benchmark_lines']:,}" for c in counts.values()) + " |")
    out.append("")
    if len(eras) == 2:
        f, m = (sums[e]["total"] for e in eras)
        variants = [
            ("feature lines (functions that ran + rest of imported modules)", f["reached"], m["reached"]),
            ("the same, code only", f["reached_code"], m["reached_code"]),
            ("functions/methods that ran only (no module rest: no eager-import bias)", f["defs_reached"],
             m["defs_reached"]),
            ("feature lines without any line in modules of later features (upper bound of 'extra work')",
             f["reached"] - f["reached_in_later_modules"], m["reached"] - m["reached_in_later_modules"]),
            ("statements coverage saw run (no whole-function rounding)", f["executed_statements"],
             m["executed_statements"]),
        ]
        out.append(f"| measure of the same features | {eras[0]} | {eras[1]} | {eras[1]} / {eras[0]} |")
        out.append("|---|---:|---:|---:|")
        for label, a, b in variants:
            out.append(f"| {label} | {a:,} | {b:,} | {b / a:.2f} |")
        out.append("")
    pkgs = sorted({p for s in sums.values() for p in s["by_package"]})
    out.append("| subpackage | " + " | ".join(f"{e}: reached / all" for e in eras) + " |")
    out.append("|---|" + "---:|" * len(eras))
    for p in pkgs:
        cells = []
        for s in sums.values():
            b = s["by_package"].get(p)
            cells.append("-" if b is None else f"{b['reached']:,} / {b['lines']:,}")
        out.append(f"| `{p}` | " + " | ".join(cells) + " |")
    out.append("")
    for era, c in counts.items():
        bad = {k: v for k, v in c["runs"].items()
               if v["failures"] or v["rc"] != _expected_exit(k, era)}
        out.append(f"{era}: {len(c['runs'])} invocations, " + (
            "all ran as expected" if not bad else "not as expected: " + "; ".join(
                f"{k} rc {v['rc']} {' / '.join(v['failures'])}" for k, v in bad.items())))
    return "\n".join(out)


def _expected_exit(inv_id: str, era: str) -> int:
    code = next((inv.exit for inv in INVOCATIONS if inv.id == inv_id), 0)
    return code if isinstance(code, int) else code[era != "filing"]


# Modules added after the filing commit for features it did not have, by the feature they serve (for the
# complementary count; code moved from modules of the filing commit is grouped where it lives now).
LATER_FEATURES = {
    "control on the fingers and the hand (issue 10): chain, joint design/stage, finger backstepping, fused and "
    "compiled control, joint PD, tendon SDRE bank, co-contraction and PIP studies": (
        "control/chain.py", "control/joint_design.py", "control/joint_stage.py", "parameters/joint_design.py",
        "control/finger_backstepping.py", "control/fused.py", "control/compiled.py", "control/joint_pd.py",
        "reproductions/ch07_cocontraction.py", "reproductions/ch15_pip_experiments.py"),
    "model discrepancy II and on fingers (issue 12 and later)": (
        "discrepancy/finger.py", "discrepancy/finger_truth.py", "discrepancy/decide.py", "discrepancy/fit.py",
        "discrepancy/result.py", "discrepancy/screen.py", "discrepancy/augment.py"),
    "compiled kernels, fused drive, one-system rigs, batched rigs (speed)": (
        "components/codegen.py", "components/fused_drive.py", "components/rig_system.py", "hand/dynamics.py",
        "rigs/batch.py"),
    "`reproduce` CLI, figure registry, later reproductions (fifth HMC, invented-parameter sensitivity)": (
        "cli/reproduce.py", "reproductions/__init__.py", "reproductions/invented_parameters.py",
        "reproductions/ch05_fifth_hmc.py"),
    "YAML configuration and CLI limits": ("parameters/yaml_io.py", "parameters/cli.py"),
}


def _group(rel: str) -> str:
    short = rel.removeprefix("awiwi_drake/")
    for label, mods in LATER_FEATURES.items():
        if short in mods:
            return label
    parts = short.split("/")
    return f"other modules of `{parts[0] if len(parts) > 1 else short}`: functions no invocation ran"


def unreached(count: dict, top: int = 15) -> str:
    """The complementary count: lines no filing-era invocation reaches, by later feature, then the largest units."""
    groups: dict[str, list] = {}
    units = []
    for rel, f in count["files"].items():
        un = sum(d["lines"] for d in f["defs"] if not d["reached"]) + (0 if f["imported"] else f["rest"])
        unc = sum(d["code"] for d in f["defs"] if not d["reached"]) + (0 if f["imported"] else f["rest_code"])
        g = groups.setdefault(_group(rel), [0, 0, 0])
        g[0] += un
        g[1] += unc
        g[2] += f["lines"]
        units += [(d["lines"], f"{rel.removeprefix('awiwi_drake/')}:{d['start']} `{d['name']}`")
                  for d in f["defs"] if not d["reached"]]
    out = ["| not reached by the filing-era features | lines | code | of the group's lines |", "|---|---:|---:|---:|"]
    for label, (un, unc, n) in sorted(groups.items(), key=lambda kv: (kv[0].startswith("other"), -kv[1][0])):
        if un:
            out.append(f"| {label} | {un:,} | {unc:,} | {n:,} |")
    tot = [sum(g[i] for g in groups.values()) for i in range(3)]
    out.append(f"| total | {tot[0]:,} | {tot[1]:,} | {tot[2]:,} |")
    out += ["", f"Largest units not reached ({count['era']}): " + "; ".join(
        f"{name} ({n})" for n, name in sorted(units, reverse=True)[:top])]
    return "\n".join(out)


def invocation_table() -> str:
    out = ["| id | filing commit | current equivalent (when different) | why it is the same feature |",
           "|---|---|---|---|"]
    for inv in INVOCATIONS:
        f = " ".join(inv.filing) if inv.kind == "cli" else (f"notebook {inv.filing}, every code cell"
                                                              if inv.kind == "notebook" else "README block")
        m = " ".join(inv.main) if inv.kind == "cli" and inv.main else (
            "its current form: " + (f"drops {len(inv.drop)} cell kind(s), {len(inv.replace)} edit(s)"
                                    if inv.drop or inv.replace else "as is") if inv.kind == "notebook"
            else ("current API" if inv.main else ""))
        out.append(f"| {inv.id} | `{f}` | {m if inv.kind != 'cli' else (f'`{m}`' if m else '')} | {inv.why} |")
    return "\n".join(out)


# --------------------------------------------------------------------------------------------------------------

def main(argv=None) -> int:
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == ["_exec"]:
        return _exec(argv[1])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, metavar="DIR", help="work folder (coverage data, outputs, counts)")
    ap.add_argument("--only", choices=("filing", "main"), help="one checkout only")
    ap.add_argument("--reuse", action="store_true", help="count the coverage data already in --out")
    ap.add_argument("--jobs", type=int, default=1, help="invocations run at once (default 1)")
    ap.add_argument("--invocations", help="comma-separated subset of invocation ids (for trying the script)")
    ap.add_argument("--list", action="store_true", help="also print the invocations as a markdown table")
    ap.add_argument("--filing-tree", metavar="DIR", help="an existing checkout of 518f8fe (default: a temporary "
                                                         "git worktree, removed at the end)")
    args = ap.parse_args(argv)
    work = pathlib.Path(args.out).resolve()
    work.mkdir(parents=True, exist_ok=True)
    only = set(args.invocations.split(",")) if args.invocations else None
    if only:
        unknown = only - {i.id for i in INVOCATIONS}
        if unknown:
            ap.error(f"--invocations: unknown id(s) {', '.join(sorted(unknown))}")
    made = filing_tree = None
    if args.filing_tree:
        filing_tree = pathlib.Path(args.filing_tree).resolve()
    elif args.only != "main":
        made = filing_tree = pathlib.Path(tempfile.mkdtemp(prefix="feature_lines_")) / "filing"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(filing_tree), FILING_COMMIT],
                       check=True, capture_output=True)
    try:
        counts = {}
        for era, tree in (("filing", filing_tree), ("main", ROOT)):
            if args.only and args.only != era:
                continue
            if not args.reuse:
                run_era(era, tree, work, args.jobs, only)
            counts[era] = count_era(era, tree, work)
            (work / f"{era}.json").write_text(json.dumps(counts[era], indent=1))
    finally:
        if made is not None:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(made)], check=False)
            shutil.rmtree(made.parent, ignore_errors=True)
    print(report(counts))
    if "main" in counts:
        print()
        print(unreached(counts["main"]))
    if args.list:
        print()
        print(invocation_table())
    return 0


if __name__ == "__main__":
    sys.exit(main())
