"""CLI: linearize finger/hand targets, animate, export-hand-diagrams."""

from __future__ import annotations

import json

import numpy as np
import pytest

from awiwi_drake.cli import main


@pytest.mark.parametrize("name", ["finger-index", "finger-middle", "finger-ring", "finger-fifth", "finger-thumb"])
def test_linearize_finger_targets_match_the_builder(name, capsys):
    from awiwi_drake.analysis.linear import linearize
    from awiwi_drake.hand.diagrams import finger_diagram
    assert main(["linearize", name, "--json", "--set", "pretension=30"]) == 0
    data = json.loads(capsys.readouterr().out)
    from awiwi_drake.parameters.hand import FingerRigParams
    finger = name.split("-")[1]
    rig = finger_diagram(finger=finger, params=FingerRigParams.for_finger(finger, pretension=30.0))
    lin = linearize(rig)
    np.testing.assert_allclose(np.array(data["A"]), lin.A, rtol=1e-9, atol=1e-9)
    assert data["state_names"] == list(rig.state_names)


def test_linearize_hand_and_unknown_parameter(capsys):
    assert main(["linearize", "hand", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["state_names"]) == 118 and np.array(data["B"]).shape == (118, 38)
    assert main(["linearize", "finger-index", "--set", "no_such_field=1"]) == 2
    assert "no_such_field" in capsys.readouterr().err


def test_animate_writes_self_contained_html(tmp_path, capsys):
    out = tmp_path / "index.html"
    assert main(["animate", "--out", str(out), "--target", "index", "--duration", "0.15"]) == 0
    text = out.read_text()
    assert "<html" in text.lower() and "meshcat" in text.lower() and len(text) > 10_000
    # self-contained: no script or stylesheet fetched from the network, the meshcat code is inline
    import re
    assert not re.search(r"<script[^>]*\bsrc\s*=\s*[\"']?(https?:)?//", text, re.I)
    assert not re.search(r"<link[^>]*\bhref\s*=\s*[\"']?(https?:)?//", text, re.I)
    inline = re.findall(r"<script[^>]*>(.*?)</script>", text, re.S | re.I)
    assert max(len(js) for js in inline) > 100_000          # the bundled meshcat viewer
    assert text.count("viewer.handle_command_bytearray(") >= 10   # the scene and the recording, embedded as data
    assert main(["animate", "--out", str(tmp_path / "x.txt")]) == 2
    assert "html" in capsys.readouterr().err


def test_export_hand_diagrams(tmp_path):
    assert main(["export-hand-diagrams", "--out", str(tmp_path)]) == 0
    top = (tmp_path / "hand_top.dot").read_text()
    for block in ("tendon_drive", "hand_plant", "wrist_tendon_offsets", "coupling_element"):
        assert block in top
