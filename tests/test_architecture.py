"""The package's layers (docs/ARCHITECTURE.md) hold: `lint-imports` with the contracts in pyproject.toml.

Bottom to top: ``_math, config, parameters`` < ``components, plotting`` < ``rigs, hand`` < ``analysis``
< ``control`` < ``reproductions, discrepancy`` < ``cli, export, diagrams``; imports inside functions
count; no import circles between sibling modules at any depth; ``analysis`` imports no plant. The second
test shows the contracts are not vacuous: a copy of the package with one upward import and one circle
must fail them.
"""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess

ROOT = pathlib.Path(__file__).resolve().parent.parent


def _lint_imports(root: pathlib.Path) -> subprocess.CompletedProcess:
    exe = shutil.which("lint-imports")
    assert exe, "lint-imports not found: install the dev extra (pip install -e '.[dev]')"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    return subprocess.run([exe, "--no-cache"], cwd=root, env=env, capture_output=True, text=True, timeout=300)


def test_import_contracts_hold():
    n_contracts = (ROOT / "pyproject.toml").read_text().count("[[tool.importlinter.contracts]]")
    res = _lint_imports(ROOT)
    assert res.returncode == 0, res.stdout[res.stdout.find("Broken contracts"):] or res.stdout + res.stderr
    assert n_contracts >= 3 and f"{n_contracts} kept, 0 broken" in res.stdout


def test_contracts_catch_an_upward_import_inside_a_function_and_a_circle(tmp_path):
    shutil.copytree(ROOT / "awiwi_drake", tmp_path / "awiwi_drake",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    with open(tmp_path / "awiwi_drake" / "parameters" / "base.py", "a") as f:
        f.write("\n\ndef _upward():\n    from awiwi_drake.control import registry\n    return registry\n")
    with open(tmp_path / "awiwi_drake" / "control" / "friction_observer.py", "a") as f:
        f.write("\nimport awiwi_drake.control.backstepping  # backstepping imports friction_observer\n")
    res = _lint_imports(tmp_path)
    assert res.returncode != 0
    assert "awiwi_drake.parameters.base -> awiwi_drake.control.registry" in res.stdout
    assert ".friction_observer -> .backstepping" in res.stdout


def test_every_reproduction_module_is_on_the_chapter_maps():
    """Each module of reproductions/ is named in the package's chapter table and in docs/ARCHITECTURE.md."""
    import awiwi_drake.reproductions as rep
    modules = sorted(p.stem for p in (ROOT / "awiwi_drake" / "reproductions").glob("*.py")
                     if not p.stem.startswith("_"))
    assert modules, "no reproduction modules found"
    architecture = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    missing_init = [m for m in modules if f":mod:`.{m}`" not in rep.__doc__]
    missing_doc = [m for m in modules if f"{m}.py" not in architecture]
    assert not missing_init, f"not in awiwi_drake/reproductions/__init__.py's table: {', '.join(missing_init)}"
    assert not missing_doc, f"not in docs/ARCHITECTURE.md: {', '.join(missing_doc)}"
