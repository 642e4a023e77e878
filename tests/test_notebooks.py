"""Execute the notebooks in notebooks/ (shortened runs: DRAKE_ATT_NOTEBOOK_TEST=1)."""

import glob
import os
import re

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK_DIR = os.path.join(os.path.dirname(__file__), os.pardir, "notebooks")
NOTEBOOKS = sorted(glob.glob(os.path.join(NOTEBOOK_DIR, "*.ipynb")))


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[os.path.basename(p) for p in NOTEBOOKS])
def test_notebook_executes(path, monkeypatch):
    monkeypatch.setenv("DRAKE_ATT_NOTEBOOK_TEST", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert not cell.get("outputs"), f"{path}: commit notebooks with outputs cleared"
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": NOTEBOOK_DIR}}).execute()
    if os.path.basename(path) == "tour.ipynb":
        _check_tour_sweep(nb)


def _check_tour_sweep(nb) -> None:
    """The tour's sweep of tracker 1's boresight noise prints every axis: roll and pitch
    grow with the noise while yaw (cross-boresight for both trackers) stays within 5%; its
    structural override is refused as structural, naming the field (not another error)."""
    cell = next(c for c in nb.cells if c.cell_type == "code" and "for sigma in" in c.source)
    text = "".join(o.get("text", "") for o in cell.outputs if o.get("output_type") == "stream")
    rows = [
        tuple(float(x) for x in m)
        for m in re.findall(r"RMSE roll ([0-9.]+)\s+pitch ([0-9.]+)\s+yaw ([0-9.]+) deg", text)
    ]
    assert len(rows) == 3, text
    roll, pitch, yaw = zip(*rows, strict=True)
    assert roll[0] < roll[1] < roll[2] and pitch[0] < pitch[1] < pitch[2], text
    assert max(yaw) <= 1.05 * min(yaw), text
    refused = next(line for line in text.splitlines() if line.startswith("refused:"))
    assert "sensors.st1.period_s (structural;" in refused, refused
