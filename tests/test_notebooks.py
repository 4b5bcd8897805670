"""The notebooks in ``notebooks/``: their shape (question first, parameters cell, answer last)
and a full execution at reduced size (``JAXTRACK_NOTEBOOK_SMALL=1``) in a fresh kernel, section
by section."""

import contextlib
import os
import re
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


def _sections(path):
    """The notebook's sections with code: ``[(title, [cell indices])]``, split at its ``## ``
    and ``### `` headings (the cells before the first go with the first section)."""
    nb = nbformat.read(path, as_version=4)
    sections = []
    for i, cell in enumerate(nb.cells):
        if cell.cell_type == "markdown" and cell.source.startswith(("## ", "### ")):
            sections.append((cell.source.splitlines()[0].lstrip("#").strip(), []))
        elif cell.cell_type == "code":
            if not sections:
                sections.append(("", []))
            sections[-1][1].append(i)
    merged = []
    for title, cells in sections:
        if merged and (not merged[-1][0] or not merged[-1][1]):
            merged[-1] = (merged[-1][0] or title, merged[-1][1] + cells)
        else:
            merged.append((title, cells))
    return [(t, c) for t, c in merged if c]


SECTIONS = [(path, k) for path in NOTEBOOKS for k in range(len(_sections(path)))]


def _slug(title):
    return re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")[:30]


class _Kernel:
    """One notebook's kernel, kept across its section tests; the next notebook's first
    section shuts it down. A section's test runs any earlier section not yet run (when run
    alone), then its own cells."""

    def __init__(self):
        self.path = None

    def run(self, path, section):
        if path != self.path:
            self.close()
            # The kernel inherits this environment (and interpreter: ipykernel's own
            # "python3" kernel spec), so the notebook runs small and against this checkout.
            env = dict(os.environ, JAXTRACK_NOTEBOOK_SMALL="1", MPLBACKEND="Agg",
                       XLA_FLAGS=os.environ.get("XLA_FLAGS",
                                                "--xla_cpu_multi_thread_eigen=false"))
            self.nb = nbformat.read(path, as_version=4)
            self.client = nbclient.NotebookClient(
                self.nb, timeout=600, kernel_name="python3",
                resources={"metadata": {"path": str(path.parent)}})
            self.stack = contextlib.ExitStack()
            self.stack.enter_context(self.client.setup_kernel(env=env))
            self.path, self.done = path, 0
        sections = _sections(path)
        for _, cells in sections[self.done:section + 1]:
            for i in cells:
                # raises CellExecutionError, naming the cell, when a cell raises
                self.client.execute_cell(self.nb.cells[i], i)
        self.done = max(self.done, section + 1)
        return [o for i in sections[section][1] for o in self.nb.cells[i].get("outputs", [])
                if o.get("output_type") == "error"]

    def close(self):
        if self.path is not None:
            self.stack.close()
            self.path = None


@pytest.fixture(scope="module")
def kernel():
    k = _Kernel()
    yield k
    k.close()


@pytest.mark.parametrize(
    "path, section", SECTIONS,
    ids=[f"{p.stem}-{k}-{_slug(_sections(p)[k][0])}" for p, k in SECTIONS])
def test_notebook_section_executes_at_reduced_size(kernel, path, section):
    """Each notebook runs in a fresh kernel at reduced size (``JAXTRACK_NOTEBOOK_SMALL=1``),
    one test per section, in order."""
    assert not kernel.run(path, section)
