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
