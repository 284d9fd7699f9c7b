"""The face of glacimap: pipeline, certification, export, report and the command line.

Only ``toolkit`` sees every other package (the layout ``toolkit -> {survey, factorgraph}
-> terrain``). The names below are the public contract; most are imported on first use
(PEP 562), so ``import toolkit`` stays light and a name's own module loads only when asked.

* Pipeline: :func:`process` (a survey's files: ingest -> localize -> select -> reconstruct ->
  certify -> export -> report) -> :class:`ProcessResult`; :func:`run_scenario` (simulate a
  survey, write it as field files, :func:`process` them) -> :class:`RunResult`;
  :func:`load_scenario` reads a scenario / settings TOML.
* Certification: :func:`certify` a DEM against independent checkpoints
  (:func:`read_checkpoints`, :class:`Checkpoints`), :func:`write_certificate`.
* Products: :func:`write_cog`, :func:`write_contours`, :func:`write_mesh`,
  :func:`write_geojson`; :func:`write_report` (the HTML certificate).
* Command line: ``glacimap`` (:func:`main`); ``__version__`` is the installed version
  (``glacimap --version``), the one certificates record.
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import Any

try:  # the installed distribution's version: what ``glacimap --version`` prints and every
    # certificate and product records (toolkit.certify.software_versions)
    __version__ = version("glacimap")
except PackageNotFoundError:  # a source tree on sys.path without ``pip install -e .``
    __version__ = "0+unknown"

# A public name equal to its submodule's name is imported eagerly: importing the submodule
# binds ``toolkit.<name>`` to the module, which a lazy ``__getattr__`` would never override.
from .certify import Checkpoints, certify, read_checkpoints, write_certificate

#: public name -> the module that defines it (imported on first use)
_WHERE = {
    "RunResult": "toolkit.pipeline",
    "run_scenario": "toolkit.pipeline",
    "process": "toolkit.processing",
    "ProcessResult": "toolkit.processing",
    "load_scenario": "toolkit.config",
    "write_cog": "toolkit.export",
    "write_contours": "toolkit.export",
    "write_geojson": "toolkit.export",
    "write_mesh": "toolkit.export",
    "write_report": "toolkit.report",
    "main": "toolkit.cli",
}

__all__ = [
    "Checkpoints",
    "ProcessResult",
    "RunResult",
    "certify",
    "load_scenario",
    "main",
    "process",
    "read_checkpoints",
    "run_scenario",
    "write_certificate",
    "write_cog",
    "write_contours",
    "write_geojson",
    "write_mesh",
    "write_report",
]


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'toolkit' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
