"""Every package states its contract in ``__all__``, and every name there imports."""

from __future__ import annotations

import importlib
import inspect
import subprocess
import sys
import types

import pytest

PACKAGES = ("terrain", "survey", "factorgraph", "factorgraph.field", "toolkit")


@pytest.mark.parametrize("name", PACKAGES)
def test_every_name_in_all_imports(name):
    mod = importlib.import_module(name)
    assert mod.__doc__ and len(mod.__doc__.split()) > 10, f"{name} states no contract"
    names = list(mod.__all__)
    assert len(names) == len(set(names)), f"{name}.__all__ repeats a name"
    for n in names:
        obj = getattr(mod, n)  # lazy names (toolkit) resolve here
        assert obj is not None, f"{name}.{n}"
        assert not isinstance(obj, types.ModuleType) or n == "standards", (
            f"{name}.{n} is a module, not the function or class of that name"
        )
        if callable(obj) and not isinstance(obj, type):
            assert inspect.getdoc(obj), f"{name}.{n} has no docstring"


def _fresh(code: str) -> str:
    """Run ``code`` in a fresh interpreter; its stdout, stripped."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip()


def test_issue_17_names():
    """The names issue 17 asks for, in a fresh interpreter (nothing imported before)."""
    code = (
        "from factorgraph import simulate_traverse, localize, select_landmarks, read_log, "
        "write_log, LocalizeParams, SensorSuite, read_field_log, write_field_log, IngestReport\n"
        "from toolkit import run_scenario, certify\n"
        "from survey import standards\n"
        "import inspect\n"
        "assert inspect.isfunction(localize), localize\n"
        "assert inspect.isclass(LocalizeParams)\n"
        "assert hasattr(standards, 'CHECKPOINT_COUNTS')\n"
        "print('ok')\n"
    )
    assert _fresh(code) == "ok"


def test_toolkit_imports_lazily():
    """``import toolkit`` loads none of its heavy modules until a name is used."""
    code = (
        "import sys, toolkit\n"
        "assert 'toolkit.pipeline' not in sys.modules, 'eager'\n"
        "toolkit.run_scenario\n"
        "assert 'toolkit.pipeline' in sys.modules\n"
        "print(sorted(set(toolkit.__all__) - set(dir(toolkit))))\n"
    )
    assert _fresh(code) == "[]"
    toolkit = importlib.import_module("toolkit")
    assert set(toolkit._WHERE) <= set(toolkit.__all__)  # every lazy name is public
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        importlib.import_module("toolkit").nothing  # noqa: B018
