"""The Meshcat recording holds the hand's geometry and a camera that frames the moving links.

The HTML written by ``awiwi-drake animate`` embeds every Meshcat command as a
base64 msgpack blob.  The test decodes them (independently of the code that
chose the camera) and checks: link geometry per finger, palm and forearm stub,
one colour per finger, and that every link position of the recorded motion lies
inside the camera's field of view while filling a readable part of it.
"""

from __future__ import annotations

import base64
import math
import re

import numpy as np
import pytest

msgpack = pytest.importorskip("msgpack", reason="the dev extra installs msgpack to decode Meshcat recordings")

from awiwi_drake.cli import main  # noqa: E402
from awiwi_drake.parameters.cli import AnimationParams  # noqa: E402
from awiwi_drake.parameters.hand import FINGERS  # noqa: E402


def _commands(html: str) -> list[dict]:
    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return [msgpack.unpackb(base64.b64decode(b)) for b in blobs]


def _three_to_drake(v) -> np.ndarray:
    """Meshcat's three.js frame is y-up: (x, y, z)_three = (x, z, -y)_drake."""
    x, y, z = v
    return np.array([x, -z, y])


def _camera(cmds):
    pos = [c for c in cmds if c["type"] == "set_property" and c["path"] == "/Cameras/default/rotated/<object>"
           and c["property"] == "position"]
    tgt = [c for c in cmds if c["type"] == "set_target"]
    assert len(pos) == 1 and len(tgt) == 1, "the recording must hold exactly one camera pose and target"
    return _three_to_drake(pos[0]["value"]), _three_to_drake(tgt[0]["value"])


def _recorded_link_positions(cmds) -> np.ndarray:
    """Every body origin of every recorded frame [m], in the viewer's world (display) frame."""
    root = next(c for c in cmds if c["type"] == "set_transform" and c["path"] == "/drake")
    X = np.array(root["matrix"], float).reshape(4, 4).T          # column-major in the message
    anim = next(c for c in cmds if c["type"] == "set_animation")
    pts = [k["value"] for a in anim["animations"] for tr in a["clip"]["tracks"] if tr["name"] == ".position"
           for k in tr["keys"]]
    pts = np.array(pts, float)
    assert len(pts) > 10
    return pts @ X[:3, :3].T + X[:3, 3]


def _check_framed(cmds, fov_deg: float):
    cam, target = _camera(cmds)
    pts = _recorded_link_positions(cmds)
    axis = (target - cam) / np.linalg.norm(target - cam)
    rel = pts - cam
    angles = np.arccos(np.clip(rel @ axis / np.linalg.norm(rel, axis=1), -1.0, 1.0))
    half = math.radians(fov_deg) / 2
    # every recorded link position is in view (vertical fov; the viewer is wider than tall) ...
    assert angles.max() < 0.9 * half, f"a link leaves the view: {math.degrees(angles.max()):.1f} deg off axis"
    # ... and the links are not a speck at the centre (the issue saw ~25 px): they span > 1/3 of the half-fov
    assert angles.max() > half / 3, f"the hand is too small in view ({math.degrees(angles.max()):.1f} deg)"
    # the camera is a readable distance away: 0.05 m .. 1 m for a 0.2 m hand
    assert 0.05 < np.linalg.norm(target - cam) < 1.0


def test_hand_recording_has_geometry_and_a_framed_camera(tmp_path, capsys):
    out = tmp_path / "hand.html"
    assert main(["animate", "--out", str(out), "--duration", "0.05"]) == 0
    captured = capsys.readouterr()
    assert "Meshcat listening" not in captured.err and captured.err == ""   # no server log noise
    cmds = _commands(out.read_text())
    objects = {c["path"]: c["object"] for c in cmds if c["type"] == "set_object"}
    assert any(p.endswith("palm_visual") for p in objects), "palm missing"
    assert "/drake/forearm_stub" in objects, "forearm stub missing"
    colours = {}
    for f in FINGERS:
        links = [p for p in objects if p.endswith("_visual") and f"/{f}_" in p]
        assert len(links) >= 3, f"{f}: only {len(links)} link shapes"
        kinds = {objects[p]["geometries"][0]["type"] for p in links}
        assert kinds <= {"CylinderGeometry", "BoxGeometry", "CapsuleGeometry", "SphereGeometry"}
        # link length from the kinematic tables, radius visible (not a degenerate 1 mm stick)
        heights = [objects[p]["geometries"][0].get("height", 0.0) for p in links]
        assert max(heights) > 0.02
        colours[f] = {objects[p]["materials"][0]["color"] for p in links}
        assert len(colours[f]) == 1, f"{f}: links have different colours"
    assert len({next(iter(c)) for c in colours.values()}) == len(FINGERS), "fingers share a colour"
    _check_framed(cmds, AnimationParams().field_of_view)


def test_finger_recording_is_framed_on_the_finger(tmp_path):
    out = tmp_path / "index.html"
    assert main(["animate", "--out", str(out), "--target", "finger-index", "--duration", "0.15"]) == 0
    cmds = _commands(out.read_text())
    objects = [c["path"] for c in cmds if c["type"] == "set_object"]
    assert any("index_proximal_visual" in p for p in objects)
    assert not any("palm_visual" in p or "forearm" in p for p in objects)
    _check_framed(cmds, AnimationParams().field_of_view)


def test_frame_camera_closed_form():
    """Points on a sphere of radius r: the camera sits r / (fill tan(fov/2)) from the centre."""
    from awiwi_drake.export.animation import frame_camera

    p = AnimationParams(margin=0.0, fill_fraction=1.0, camera_azimuth=0.0, camera_elevation=0.0)
    pts = np.array([[1, 2, 3], [1, 2, 3]]) + 0.1 * np.array([[1, 1, 1], [-1, -1, -1]]) / math.sqrt(3)
    cam, target = frame_camera(pts, p)
    np.testing.assert_allclose(target, [1, 2, 3], atol=1e-12)
    d = 0.1 / math.tan(math.radians(p.field_of_view) / 2)
    np.testing.assert_allclose(cam, [1 + d, 2, 3], atol=1e-12)
