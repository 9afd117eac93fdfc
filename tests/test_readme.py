"""The README's quickstart runs as written (so it cannot silently go stale)."""

import pathlib
import re

import pytest


def test_readme_quickstart_runs_and_shows_physics(capsys):
    text = (pathlib.Path(__file__).parent.parent / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "README.md has no python code block"
    namespace: dict = {}
    for i, block in enumerate(blocks):       # blocks build on each other, as a reader runs them
        exec(compile(block, f"README python block {i + 1}", "exec"), namespace)
    assert namespace["lin"].A.shape[0] == namespace["rig"].num_states
    lin_A = namespace["linearize"](namespace["flexible_joint_rig"]()).A
    assert lin_A[1, 0] == pytest.approx(-0.605 / 4e-7, rel=1e-12)   # (12.10) with Table 12.1
    from awiwi_drake.rigs import joint_rig
    op = namespace["op"]
    assert op.joint_stiffness > joint_rig().operating_point(pretension=10.0).joint_stiffness
    assert "Nm/rad" in capsys.readouterr().out


def test_readme_sections_cited_elsewhere_exist():
    """Code, tests, benchmarks and docs cite README passages by their title (``README "How the plants are built,
    and speed"``); each cited title is a heading or a bold lead of the README, so a renamed section cannot leave
    the citations pointing nowhere (the "Backends, and speed" section was renamed when the backends were removed
    and five citations kept the old title)."""
    root = pathlib.Path(__file__).parent.parent
    readme = (root / "README.md").read_text()
    titles = set(re.findall(r"^#+ +(.+?) *$", readme, flags=re.M)) | set(re.findall(r"\*\*(.+?)\*\*", readme))
    files = [p for d in ("awiwi_drake", "tests", "benchmarks", "docs") for p in (root / d).rglob("*")
             if p.suffix in (".py", ".md")]
    cited = {(p.relative_to(root).as_posix(), t) for p in files
             for t in re.findall(r'README,? "([^"\n]+)"', p.read_text())}
    assert len(cited) >= 5, cited             # the scan finds the citations (it has teeth)
    missing = sorted((f, t) for f, t in cited if t not in titles)
    assert not missing, f"README titles cited but not in README.md: {missing}"
