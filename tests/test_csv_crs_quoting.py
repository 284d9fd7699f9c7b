"""CSV products whose ``crs`` cell has commas: a CRS without an EPSG code (the Olinda DEM
shipped by r-cran-stars is a BOUNDCRS whose text is WKT / a PROJ string with
``+towgs84=0,0,0,...``) must be quoted, or the files glacimap writes cannot be read back
(found running ``glacimap run`` with ``[site] kind = "dem"`` on that DEM: checkpoints.csv
line 2 had 5 + 6 cells)."""

from __future__ import annotations

import numpy as np
import xarray as xr
from pyproj import CRS

from factorgraph.select import LandmarkSelection
from terrain import ElevationSamples
from toolkit.certify_io import read_checkpoints
from toolkit.field_survey import _write_checkpoints
from toolkit.products import samples_table, write_csv
from toolkit.samples_io import read_samples

#: The Olinda DEM's CRS in kind: UTM 25 S on GRS80 with a null datum shift (a BOUNDCRS).
BOUND = CRS("+proj=utm +zone=25 +south +ellps=GRS80 +towgs84=0,0,0,0,0,0,0 +units=m +type=crs")


def test_the_crs_text_has_commas():
    assert BOUND.is_bound and "," in BOUND.to_string()


def test_samples_csv_round_trip_with_a_bound_crs(tmp_path):
    rng = np.random.default_rng(0)
    n = 30
    xy = rng.uniform([290_000, 9_115_000], [290_600, 9_115_600], (n, 2))
    s = ElevationSamples(xy, rng.normal(40, 5, n), 0.04, crs=BOUND, extra={"t_s": np.arange(n)})
    sel = LandmarkSelection(
        s, {"kept": np.ones(n, bool), "z_std_m": np.full(n, 0.2)}, {}, [1, 1, 1]
    )
    path = write_csv(tmp_path / "samples.csv", samples_table(sel))
    back = read_samples(path).samples
    assert back.n == n and CRS(back.crs) == BOUND
    np.testing.assert_allclose(back.xy, xy, rtol=0, atol=1e-6)


def test_checkpoints_csv_round_trip_with_a_bound_crs(tmp_path):
    x = 290_000 + 2.0 * np.arange(50) + 1.0
    y = 9_115_100 - 2.0 * np.arange(50) - 1.0
    truth = xr.DataArray(
        np.add.outer(0.1 * np.arange(50), 0.05 * np.arange(50)),
        coords={"y": y, "x": x},
        dims=("y", "x"),
        attrs={"crs_wkt": BOUND.to_wkt()},
    )
    bounds = (290_000.0, 9_115_000.0, 290_100.0, 9_115_100.0)
    path = _write_checkpoints(truth, bounds, 20, np.random.default_rng(1), tmp_path / "cp.csv")
    cps = read_checkpoints(path)
    assert len(cps.z) == 20 and CRS(cps.crs) == BOUND
