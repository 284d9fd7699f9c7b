"""The numbered notebooks run top to bottom (nbclient, a fresh kernel each, in a temporary
working folder), carry no stored outputs, and use only the public packages."""

from __future__ import annotations

import ast
import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

FOLDER = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = (
    "01_simulate",
    "02_localize",
    "03_reconstruct",
    "04_plan_monte_carlo",
    "05_export_report",
    "06_change",
    "07_process_field",
    "08_camera_frames",
    "09_real_inputs",
)
# First-party packages plus the libraries their public API returns or that read the products.
ALLOWED_IMPORTS = {
    "terrain",
    "survey",
    "factorgraph",
    "toolkit",
    "numpy",
    "matplotlib",
    "pandas",
    "shapely",
    "rasterio",
    "pyogrio",
    "json",
    "pathlib",
}
BUDGET_S = 60.0  # each notebook on 2 cores (measured 5-20 s)


def _read(name):
    return nbformat.read(FOLDER / f"{name}.ipynb", as_version=4)


def test_the_folder_lists_every_notebook():
    found = sorted(p.stem for p in FOLDER.glob("*.ipynb"))
    assert found == list(NOTEBOOKS)
    readme = (FOLDER / "README.md").read_text()
    assert all(f"{name}.ipynb" in readme for name in NOTEBOOKS)


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_is_clean_and_uses_the_public_packages(name):
    book = _read(name)
    nbformat.validate(book)
    assert book.nbformat == 4
    code = [c for c in book.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)
    for cell in code:
        for node in ast.walk(ast.parse(cell.source)):
            if isinstance(node, ast.Import):
                tops = {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                tops = {(node.module or "").split(".")[0]}
            else:
                continue
            assert tops <= ALLOWED_IMPORTS, f"{name}: imports {tops - ALLOWED_IMPORTS}"
    text = "\n".join(c.source for c in book.cells if c.cell_type == "markdown")
    assert text.lstrip().startswith("# 0"), "a numbered title first"


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_executes(name, tmp_path):
    book = _read(name)
    client = nbclient.NotebookClient(
        book, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    t0 = time.perf_counter()
    client.execute()  # raises CellExecutionError, with the cell and traceback, on any error
    seconds = time.perf_counter() - t0
    errors = [o for c in book.cells for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
    assert seconds < BUDGET_S, f"{name} took {seconds:.0f} s"
