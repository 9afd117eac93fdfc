"""Run-mode switches shared by notebooks, demos and tests."""

import os

__all__ = ["short_mode"]


def short_mode() -> bool:
    """True when ``AWIWI_SHORT=1``: notebooks and demos shorten simulations (CI)."""
    return os.environ.get("AWIWI_SHORT", "0").strip() not in ("", "0", "false", "no")
