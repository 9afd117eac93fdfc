"""Display settings of the Meshcat recording (``awiwi-drake animate``).

None of these numbers enters the physics: they place the camera, draw a
forearm stub below the palm and set the frame rate of the recording.  All are
chosen for a readable picture of a hand about 0.2 m long.
"""

from __future__ import annotations

from dataclasses import dataclass

from .base import Parameters, param

__all__ = ["AnimationParams"]


@dataclass(frozen=True)
class AnimationParams(Parameters):
    """Camera, forearm stub and frame rate of a hand/finger recording.

    The recording is shown in a *display frame*: the palm frame (x towards the
    fingers, y towards the thumb, z the palmar normal) turned so that the
    fingers point up (display z) and the palm faces the display x axis.  The
    camera looks at the centre of the box that holds the moving links, from
    ``camera_azimuth`` / ``camera_elevation``, far enough that the box fills
    ``fill_fraction`` of the vertical field of view.
    """

    frame_rate: float = param(30.0, unit="Hz", low=1.0, high=240.0,
                              source="chosen: smooth playback, small HTML file")
    camera_azimuth: float = param(-0.75, unit="rad", low=-3.1416, high=3.1416,
                                  source="chosen: three-quarter view from the palm and thumb side, "
                                         "so that flexion is seen in profile")
    camera_elevation: float = param(0.35, unit="rad", low=-1.5, high=1.5,
                                    source="chosen: slightly from above, fingertips not hidden by the palm")
    field_of_view: float = param(75.0, unit="deg", low=10.0, high=120.0,
                                 source="chosen: Meshcat's default perspective camera (three.js fov 75 deg)")
    fill_fraction: float = param(0.95, unit="-", low=0.2, high=1.5,
                                 source="chosen: the bounding sphere of the moving links fills 95 % of the view height")
    margin: float = param(0.015, unit="m", low=0.0, high=0.1,
                          source="chosen: about two link radii around the link origins")
    forearm_length: float = param(0.08, unit="m", low=0.0, high=0.5,
                                  source="chosen: a short stub that shows where the wrist is")
    forearm_radius: float = param(0.028, unit="m", low=0.005, high=0.1,
                                  source="chosen: about a human wrist (56 mm across)")
    show_grid: bool = param(False, unit="-", source="chosen: the ground grid cuts through the upright hand")
