"""Hand command: ``animate`` (Meshcat recording to HTML); ``export-diagrams`` writes the hand graphs too.

``awiwi-drake linearize finger-index|finger-middle|finger-ring|finger-fifth|finger-thumb|hand``
comes from the shared ``linearize`` command (targets registered in ``awiwi_drake.diagrams.TARGETS``).
"""

from __future__ import annotations

import argparse

from awiwi_drake.cli import limited_float

__all__ = ["register"]

def register(sub) -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser(
        "animate", formatter_class=fmt,
        help="simulate a grasp of the hand (or one finger) and write a self-contained Meshcat HTML file",
        epilog="The motion: open -> closed -> open joint references tracked by the 3 kHz joint-space\n"
               "controller through the full tendon model (motors, lever springs, routing). Offline.")
    p.add_argument("--out", default="hand.html", metavar="FILE.html", help="HTML file to write (default hand.html)")
    p.add_argument("--target", default="hand", metavar="RIG",
                   help="hand (palm, forearm stub, five fingers) or one finger's rig: finger-thumb, finger-index, "
                        "finger-middle, finger-ring, finger-fifth (default hand)")
    p.add_argument("--duration", type=limited_float("max_animation_duration", "s", positive=True), default=1.5, metavar="S",
                   help="simulated seconds of the open -> closed -> open motion (default 1.5)")
    p.add_argument("--quiet", action="store_true", help="no progress bar (it shows only on a terminal anyway)")
    p.set_defaults(func=_animate)


def _animate(args) -> int:
    from awiwi_drake.cli import output_file
    from awiwi_drake.export.animation import record_animation

    out = output_file(args.out, "--out", suffixes=(".html", ".htm"))
    from awiwi_drake.config import SimulationProgress

    with SimulationProgress("animate", quiet=args.quiet) as progress:
        res = record_animation(out, target=args.target, duration=args.duration, progress=progress)
    print(f"wrote {res.path} ({res.duration:g} s, {res.num_frames} frames; "
          f"max joint tracking error {res.max_tracking_error:.3g} rad)")
    return 0

