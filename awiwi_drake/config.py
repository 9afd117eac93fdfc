"""Run-mode switches shared by notebooks, demos and tests."""

import os

__all__ = ["short_mode", "progress_enabled", "progress_bar", "SimulationProgress"]


def short_mode() -> bool:
    """True when ``AWIWI_SHORT=1``: notebooks and demos shorten simulations (CI)."""
    return os.environ.get("AWIWI_SHORT", "0").strip() not in ("", "0", "false", "no")


# ---------------------------------------------------------------------------------------------- progress
def progress_enabled(quiet: bool | None = None) -> bool:
    """Whether long work shows a progress bar.

    Off with ``quiet=True``, with ``AWIWI_PROGRESS=0`` and in short mode (CI);
    on with ``AWIWI_PROGRESS=1``; otherwise on when stderr is a terminal or the
    code runs in a Jupyter kernel (notebook cells), off when output is piped.
    """
    import sys

    if quiet:
        return False
    env = os.environ.get("AWIWI_PROGRESS", "").strip().lower()
    if env in ("0", "off", "false", "no"):
        return False
    if env in ("1", "on", "true", "yes"):
        return True
    if short_mode():
        return False
    if "ipykernel" in sys.modules:
        return True
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def progress_bar(total: float | None = None, *, desc: str, unit: str = "it", quiet: bool | None = None):
    """A ``tqdm`` progress bar on stderr (``tqdm.auto`` in notebooks), disabled per :func:`progress_enabled`.

    Use as a context manager; ``bar.update(n)`` advances it.
    """
    import sys

    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=not progress_enabled(quiet), leave=False,
                file=sys.stderr, dynamic_ncols=True)


class SimulationProgress:
    """A progress callback for ``simulate(..., progress=...)`` (and anything calling ``progress(t, duration)``).

    Shows simulated seconds out of the run's duration::

        with SimulationProgress("grasp") as progress:
            simulate(loop, ctx, 2.0, progress=progress)
    """

    def __init__(self, desc: str, *, quiet: bool | None = None):
        self.desc, self.quiet, self.bar = desc, quiet, None

    def __call__(self, t: float, duration: float) -> None:
        if self.bar is None:
            self.bar = progress_bar(total=round(float(duration), 6), desc=self.desc, unit="s sim", quiet=self.quiet)
            self.bar.bar_format = "{desc}: {percentage:3.0f}%|{bar}| {n:.3g}/{total:.3g} s simulated [{elapsed}]"
        self.bar.n = round(min(float(t), float(duration)), 6)
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def __enter__(self) -> "SimulationProgress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
