"""The quickstart notebook runs top to bottom and learns: its plot cell shows an image and its final greedy return is
above Box Pushing 6x6's do-nothing plateau (-4).

It trains the quickstart preset for real (one seed instead of two: JAXMAC_NOTEBOOK_QUICK=1; 2,048 episodes), which
ends at a final greedy return of 166.4 (the same in two runs from a fresh compilation cache). The test took 2 min 36 s
on a 2-core CPU whose cores were both busy with other training runs."""

from __future__ import annotations

import os
import re

import nbclient
import nbformat

NOTEBOOK = os.path.join(os.path.dirname(__file__), "..", "experiments", "quickstart.ipynb")
PLATEAU = -4.0  # Box Pushing 6x6: what a policy that never pushes a box scores


def _tagged(nb, tag: str):
    cells = [c for c in nb.cells if c.cell_type == "code" and tag in c.get("metadata", {}).get("tags", [])]
    assert len(cells) == 1, f"one code cell tagged {tag!r}"
    return cells[0]


def _text(cell) -> str:
    return "".join(o.get("text", "") + str(o.get("data", {}).get("text/plain", "")) for o in cell.get("outputs", []))


def test_quickstart_notebook_learns(tmp_path, monkeypatch):
    # the kernel inherits the session's compilation cache ($JAXMAC_CACHE, conftest.py); the notebook chooses its
    # matplotlib backend itself (%matplotlib inline)
    monkeypatch.setenv("JAXMAC_NOTEBOOK_QUICK", "1")
    monkeypatch.delenv("MPLBACKEND", raising=False)
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=1800, kernel_name="python3",
                                      resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    plot = _tagged(nb, "plot")
    assert any("image/png" in o.get("data", {}) for o in plot.outputs), "the plot cell shows the learning curve"
    found = re.search(r"final greedy return: (-?\d+(?:\.\d+)?)", _text(_tagged(nb, "final-return")))
    assert found, _text(_tagged(nb, "final-return"))
    assert float(found.group(1)) > PLATEAU
