"""Suite order: the modules holding the longest tests are collected first.

``scripts/test.sh`` runs the suite on two pytest-xdist workers (``--dist load``), which hand out the tests in
collection order; a long test started last leaves the other worker idle until it ends.  Started first, the long
ones (the notebooks, 10-25 s each in short mode, and the finger / workflow diagnoses, 5-15 s) overlap with the
many short tests instead.  Measured with ``--durations``: these modules hold 15 of the 20 slowest tests.  The
order within a module is unchanged (module-scoped fixtures stay shared).
"""

from __future__ import annotations

LONGEST_FIRST = ("test_notebooks.py", "test_discrepancy_finger.py", "test_discrepancy_workflow.py",
                 "test_backstepping.py", "test_joint_design.py")


def pytest_collection_modifyitems(session, config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))       # stable: the rest keep their order
