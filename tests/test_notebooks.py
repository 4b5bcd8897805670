"""The notebooks in ``notebooks/``: their shape (question first, parameters cell, answer last)
and a full execution at reduced size (``JAXTRACK_NOTEBOOK_SMALL=1``) in a fresh kernel."""

import os
from pathlib import Path

import nbclient
import nbformat
import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def _ids(paths):
    return [p.stem for p in paths]


def test_there_are_notebooks():
    assert NOTEBOOKS, "notebooks/ holds no notebook"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_ids(NOTEBOOKS))
def test_notebook_states_question_first_and_answer_last(path):
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    cells = nb.cells
    assert cells[0].cell_type == "markdown" and "?" in cells[0].source, \
        f"{path.name}: the first cell must state the notebook's question"
    tagged = [c for c in cells if "parameters" in c.get("metadata", {}).get("tags", [])]
    assert len(tagged) == 1 and tagged[0].cell_type == "code", \
        f"{path.name}: exactly one code cell tagged 'parameters'"
    assert "JAXTRACK_NOTEBOOK_SMALL" in tagged[0].source
    first_code = next(c for c in cells if c.cell_type == "code")
    assert first_code is tagged[0], f"{path.name}: the parameters cell comes before any code"
    assert cells[-1].cell_type == "markdown" and "answer" in cells[-1].source.lower(), \
        f"{path.name}: the last cell must give the answer"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_ids(NOTEBOOKS))
def test_notebook_executes_at_reduced_size(path, monkeypatch):
    # The kernel inherits this process's environment (and interpreter: ipykernel's own
    # "python3" kernel spec), so the notebook runs small and against this checkout.
    monkeypatch.setenv("JAXTRACK_NOTEBOOK_SMALL", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("XLA_FLAGS", os.environ.get(
        "XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false"))
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    client.execute()   # raises CellExecutionError, naming the cell, when a cell raises
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert not errors
