"""Every notebook in notebooks/ is committed without outputs. That each executes
from top to bottom is checked by the documentation build (`mkdocs build --strict`
in CI), which runs them all and fails on a cell that raises."""

import pathlib

import nbformat
import pytest

NOTEBOOKS = sorted(
    (pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb")
)


def test_there_are_notebooks():
    assert any(p.name == "quickstart.ipynb" for p in NOTEBOOKS)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_committed_without_outputs(path):
    notebook = nbformat.read(path, as_version=4)
    for k, cell in enumerate(notebook.cells):
        if cell.cell_type == "code":
            assert not cell.outputs, f"{path.name}: cell {k} has outputs; clear them"
            assert cell.execution_count is None, f"{path.name}: cell {k} was run"
