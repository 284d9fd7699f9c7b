"""The house rules of docs/architecture.md §2, checked on the source tree itself."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Which first-party packages each package may import (imports flow one way).
ALLOWED = {
    "terrain": {"terrain"},
    "survey": {"survey", "terrain"},
    "factorgraph": {"factorgraph", "terrain"},
    "toolkit": {"toolkit", "survey", "factorgraph", "terrain"},
}
HEAVY = {"open3d", "pyvista", "emcee", "dask", "distributed", "cv2", "gtsam", "sklearn"}


def _modules(package):
    return sorted((ROOT / package).rglob("*.py"))


def _imports(tree):
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node, alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node, node.module.split(".")[0]


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_imports_flow_one_way(package):
    for path in _modules(package):
        for _, top in _imports(ast.parse(path.read_text())):
            if top in ALLOWED and top not in ALLOWED[package]:
                pytest.fail(f"{path.relative_to(ROOT)} imports {top}: not allowed from {package}")


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_heavy_libraries_imported_inside_functions(package):
    for path in _modules(package):
        tree = ast.parse(path.read_text())
        for node in tree.body:  # module level only
            if isinstance(node, ast.Import | ast.ImportFrom):
                for _, top in _imports(ast.Module(body=[node], type_ignores=[])):
                    assert top not in HEAVY, f"{path.relative_to(ROOT)}: top-level import {top}"


def test_modules_stay_small():
    for package in ALLOWED:
        for path in _modules(package):
            n = len(path.read_text().splitlines())
            assert n <= 500, f"{path.relative_to(ROOT)} has {n} lines (> 500): split it"
