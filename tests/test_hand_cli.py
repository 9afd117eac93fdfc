"""CLI: linearize finger/hand targets, animate; the exported hand graph."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from awiwi_drake.cli import main
from awiwi_drake.hand.diagrams import hand_diagram


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
    # 21 joints (q, v) and 38 tendons (motor angle, velocity, hysteresis and guide friction forces: on by default)
    assert len(data["state_names"]) == 2 * 21 + 4 * 38 and np.array(data["B"]).shape == (2 * 21 + 4 * 38, 38)
    assert main(["linearize", "finger-index", "--set", "no_such_field=1"]) == 2
    assert "no_such_field" in capsys.readouterr().err


def test_animate_writes_self_contained_html(tmp_path, capsys):
    out = tmp_path / "index.html"
    assert main(["animate", "--out", str(out), "--target", "finger-index", "--duration", "0.15"]) == 0
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


def _dot_graph(text):
    """(node id by system name, set of edges (src node, output index, dst node, input index)) of a
    Drake Graphviz export, top level only (``max_depth=1``)."""
    nodes = dict((name, node) for node, name in
                 re.findall(r"^(s\d+) \[shape=none, border=0, label=<.*?name=(\S+)\n", text, re.M | re.S))
    edges = {(a, int(i), b, int(j)) for a, i, b, j in re.findall(r"^(s\d+):y(\d+):e -> (s\d+):u(\d+):w", text, re.M)}
    return nodes, edges


def test_exported_hand_graph_shows_every_block_and_connection():
    """The top-level hand graph of ``awiwi-drake export-diagrams`` (committed as diagrams/hand_top.dot, kept
    current by test_simulate_cli_export::test_committed_diagrams_are_current) shows every block of the hand
    diagram under its name and every internal connection between the right ports."""
    import pathlib
    nodes, edges = _dot_graph((pathlib.Path(__file__).parent.parent / "diagrams" / "hand_top.dot").read_text())
    diagram = hand_diagram().diagram
    names = [s.get_name() for s in diagram.GetSystems()]
    assert sorted(nodes) == sorted(names)
    for block in ("hand_dynamics", "wrist_tendon_offsets", "wrist_offset_select"):
        assert block in nodes
    conn = diagram.connection_map()
    assert len(conn) >= len(names) - 1
    for (dst, j), (src, i) in conn.items():
        assert (nodes[src.get_name()], int(i), nodes[dst.get_name()], int(j)) in edges, (src.get_name(), i, dst.get_name(), j)
    assert len(edges) == len(conn)
