import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from terrain import heap

ROOT = Path(__file__).resolve().parents[1]

# A small fit and map in a fresh process: the hash of the mean and 1-sigma bytes, and
# whether the heap tuning took effect.
_CHILD = """
import hashlib, json, numpy as np
from terrain import ElevationSamples, Grid, TerrainGP, heap
rng = np.random.default_rng(0)
xy = rng.uniform(0, 200, (1500, 2))
z = np.sin(xy[:, 0] / 30) * 5 + np.cos(xy[:, 1] / 45) * 3 + rng.normal(0, 0.1, 1500)
gp = TerrainGP(seed=0).fit(ElevationSamples(xy, z, np.full(1500, 0.01), crs="EPSG:32633"))
ds = gp.predict_grid(Grid.from_bounds((0, 0, 200, 200), 4.0, "EPSG:32633"))
h = hashlib.sha256(ds.elevation.values.tobytes() + ds.elevation_std.values.tobytes())
print(json.dumps({"hash": h.hexdigest(), "tuned": heap.keep_freed_memory()}))
"""


def _child(env_value: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != heap.ENV}
    if env_value is not None:
        env[heap.ENV] = env_value
    out = subprocess.run(
        [sys.executable, "-c", _CHILD], env=env, cwd=ROOT, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_same_bits_with_and_without_the_heap_tuning():
    # Only where numpy's memory comes from changes, never a value.
    tuned, default = _child(None), _child("default")
    assert tuned["tuned"] is True  # glibc (the CI machine's libc)
    assert default["tuned"] is False  # GLACIMAP_MALLOC=default turns it off
    assert tuned["hash"] == default["hash"]


def test_keep_freed_memory_runs_once():
    first = heap.keep_freed_memory()
    assert heap.keep_freed_memory() is first  # cached: mallopt is called once per process
    assert heap.MMAP_THRESHOLD == 32 * 1024 * 1024  # glibc's largest on 64-bit
