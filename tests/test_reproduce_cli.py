"""CLI ``awiwi-drake reproduce``: the figure ids, one cheap figure end to end, one-line errors with exit status 2."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from awiwi_drake.cli import main
from awiwi_drake.config import short_mode
from awiwi_drake.reproductions import FIGURES, reproduce


def test_reproduce_list_names_every_figure_with_its_thesis_reference(capsys):
    assert main(["reproduce", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(FIGURES)
    for line, e in zip(lines, FIGURES.values()):
        assert line.split()[0] == e.id and e.reference in line and e.summary in line
    assert {"fig15.24", "fig15.25", "fig15.26", "cocontraction"} <= set(FIGURES)


def test_reproduce_writes_the_figure_its_series_with_units_and_its_numbers(tmp_path, capsys):
    """Fig 6.9/6.10 (the cheapest id): PNG, CSV whose every column names its unit, JSON whose every number carries a
    unit; the CSV's series are the study's own (the wrist's distance constraints hold to round-off, Fig 6.9)."""
    from awiwi_drake.reproductions.ch06_wrist import wrist_motion_study
    out = tmp_path / "figs"
    assert main(["reproduce", "fig6.10", "--out", str(out), "--short"]) == 0
    assert str(out / "fig6.10.png") in capsys.readouterr().out
    assert (out / "fig6.10.png").stat().st_size > 10_000
    with open(out / "fig6.10.csv") as fh:
        rows = list(csv.reader(fh))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    assert header[:3] == ["t [s]", "q71 [rad]", "q73 [rad]"] and all(h.endswith("]") for h in header)
    w = wrist_motion_study(num_samples=51)
    np.testing.assert_array_equal(data[:, 3:], w.offsets)
    meta = json.loads((out / "fig6.10.json").read_text())
    assert meta["id"] == "fig6.10" and meta["reference"] == FIGURES["fig6.10"].reference and meta["short"] is True
    assert all(set(v) == {"value", "unit"} for v in meta["values"].values())
    assert meta["values"]["max_constraint_error"]["unit"] == "m"
    assert meta["values"]["max_constraint_error"]["value"] < 1e-12


def test_reproduce_bad_id_or_unwritable_folder_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["reproduce", "fig99.1", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'fig99.1'" in err and "fig15.26" in err
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["reproduce", "fig6.10", "--out", str(blocker)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--out" in err and str(blocker) in err
    assert main(["reproduce", "fig6.10"]) == 2
    assert "--out" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.png"))


def _leaves_have_units(values) -> bool:
    if set(values) == {"value", "unit"}:
        return bool(values["unit"])
    return all(isinstance(v, dict) and _leaves_have_units(v) for v in values.values())


@pytest.mark.skipif(short_mode(), reason="runs every figure id (~1 CPU min); the suite runs in short mode")
def test_every_figure_id_writes_its_files_in_short_mode(tmp_path):
    """Every registered id still runs against its chapter module (the registry only calls them) and writes its PNG
    and a JSON whose numbers all carry a unit; its CSV, when written, names a unit in every column."""
    written = reproduce(list(FIGURES), tmp_path, short=True)
    for i, paths in written.items():
        assert {p.suffix for p in paths} >= {".png", ".json"} and all(p.stat().st_size > 0 for p in paths), i
        assert _leaves_have_units(json.loads((tmp_path / f"{i}.json").read_text())["values"]), i
        csv_path = tmp_path / f"{i}.csv"
        if csv_path.exists():
            with open(csv_path) as fh:
                assert all(h.endswith("]") for h in next(csv.reader(fh))), i
