"""The quickstart notebook runs top to bottom."""

from __future__ import annotations

import os

import nbclient
import nbformat

NOTEBOOK = os.path.join(os.path.dirname(__file__), "..", "experiments", "quickstart.ipynb")


def test_quickstart_notebook_executes(tmp_path, monkeypatch):
    # the kernel inherits the session's compilation cache ($JAXMAC_CACHE, conftest.py)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=900, kernel_name="python3",
                                      resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    outputs = "".join(o.get("text", "") + str(o.get("data", {}).get("text/plain", ""))
                      for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", []))
    assert "final_greedy_return" in outputs and "goal" in outputs
