"""Real DEMs that glacimap did not make, fetched on demand, and glacier-sized test sites.

Sources (docs/architecture.md §5; docs/terrain.md "Real terrain"): Debian packages that ship real
elevation data, downloaded with ``apt-get download`` and unpacked with ``dpkg -x`` (no R):

``olinda``  r-cran-stars ``tif/olinda_dem_utm25s.tif``: a 111 x 111 DEM at 90 m (SRTM-like),
            Olinda, Brazil, UTM 25S.
``rm``      r-cran-fields ``data/RMelevation.rda``: Rocky Mountain elevations, 289 x 242 at
            2.5 arc-minutes, longitude/latitude.
``prism``   r-cran-fields ``data/PRISMelevation.rda``: conterminous US at 2.5 arc-minutes,
            NaN over the oceans.
``lux``     r-cran-terra ``ex/elev.tif``: Luxembourg, 95 x 90 at 30 arc-seconds (~1 km),
            longitude/latitude, nodata outside the country.
``glacier`` r-cran-fields ``data/glacier.rda``: 8,338 points digitised from the contours of a
            real glacier (locations in km, elevations in m), gridded here by cubic
            interpolation inside their hull.
``jacksboro`` matplotlib's ``sample_data/jacksboro_fault_dem.npz``: 344 x 403 at 3 arc-seconds
            (~90 m), the Jacksboro fault, Tennessee: Appalachian ridge-and-valley terrain,
            strongly anisotropic (long parallel ridges); longitude/latitude.
``topobathy`` matplotlib's ``sample_data/topobathy.npz``: 91 x 120 at 1 arc-minute, the
            Strait of Georgia (topography and bathymetry); longitude/latitude.
``volcano`` r-base-core's ``datasets`` (lazy-load database): R's ``volcano``, Maunga Whau,
            Auckland, digitised from a topographic map on a 10 m grid, 87 x 61 (870 m x 610
            m, relief 101 m); local metres.
``bei``     r-cran-spatstat.data ``bei.extra$elev`` (R lazy-load database ``data/Rdata.rdb``
            with its index ``Rdata.rdx``): a 101 x 201 ground survey at 5 m of the 1000 m x
            500 m Barro Colorado Island forest plot, Panama (relief 40 m); local metres.
``gorillas`` r-cran-spatstat.data ``gorillas.extra$elevation``: a 149 x 181 satellite DEM at
            30.7 m of the Kagwene Gorilla Sanctuary, Cameroon (1,165-2,062 m; 22 % of the
            cells NA outside the sanctuary's window), UTM zone 32N metres (spatstat's
            ``?gorillas``).
``clm``     r-cran-spatstat.data ``clmfires.extra$clmcov200$elevation``: Castilla-La Mancha,
            Spain, 200 x 200 cells of 2 km (8-2,310 m); spatstat's own km plane, read here as
            metres in a local transverse Mercator frame.

The two matplotlib files ship with matplotlib (a glacimap dependency), so they need no
registry: sites made from them were never used to choose glacimap's defaults (added in
session 6 as held-back terrain, docs/terrain.md "Two DEMs held back"). ``bei`` and
``volcano`` were added in session 7 the same way, ``gorillas`` and ``clm`` in session 9:
held back, never used to choose anything.

Files are cached under ``$GLACIMAP_DATA`` (default ``~/.cache/glacimap/real-dems``).
:class:`RealDataUnavailable` says why when the registry cannot be reached; tests and
benchmarks skip with that reason.

A *site* (:func:`glacier_site`) takes a window of a real DEM as the shape donor, maps it onto
a glacier-sized square (default 600 m at 2 m) with a bicubic spline through its nodes and
rescales the elevations to a given relief: the real DEM's roughness spectrum, down to the
node spacing, on the scale a rover surveys. :func:`track_samples` then samples it the way a
rover does: landmarks beside parallel tracks plus scattered points, with Gaussian noise.
Any DEM file GDAL reads can be the shape donor instead of a named one (:func:`load_file`;
``glacier_site("my_dem.tif")``): the same protocol on ground these DEMs never showed.

Usage: ``python scripts/real_dems.py`` fetches the files and prints what it has.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import xarray as xr

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from terrain import ElevationSamples, Grid  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ground_features import FEATURES, add_feature, feature_line  # noqa: E402, F401

PACKAGES = {
    "r-cran-stars": {"olinda": "usr/lib/R/site-library/stars/tif/olinda_dem_utm25s.tif"},
    "r-cran-terra": {"lux": "usr/lib/R/site-library/terra/ex/elev.tif"},
    "r-cran-fields": {
        "rm": "usr/lib/R/site-library/fields/data/RMelevation.rda",
        "prism": "usr/lib/R/site-library/fields/data/PRISMelevation.rda",
        "glacier": "usr/lib/R/site-library/fields/data/glacier.rda",
    },
    # an R lazy-load database: the objects (.rdb) and their index (.rdx), cached side by side
    "r-cran-spatstat.data": {
        name: "usr/lib/R/site-library/spatstat.data/data/Rdata.rdb"
        for name in ("bei", "gorillas", "clm")
    },
    "r-base-core": {"volcano": "usr/lib/R/library/datasets/data/Rdata.rdb"},
}
#: Cached file name of each DEM (a lazy-load database is renamed after its package).
FILES = {
    name: (f"{pkg.removeprefix('r-cran-')}.rdb" if rel.endswith(".rdb") else Path(rel).name)
    for pkg, files in PACKAGES.items()
    for name, rel in files.items()
}
#: R objects read from a lazy-load database: DEM name -> (object, path of list elements to
#: the spatstat "im", metres per coordinate unit, CRS of the coordinates).
LAZYLOAD = {
    "volcano": ("volcano", (), 10.0, None),  # a bare matrix on a 10 m grid
    "bei": ("bei.extra", ("elev",), 1.0, None),
    "gorillas": ("gorillas.extra", ("elevation",), 1.0, "EPSG:32632"),
    "clm": ("clmfires.extra", ("clmcov200", "elevation"), 1000.0, None),
}
#: R's NA for integers (an "im" of integer elevations stores its NA cells as this).
R_NA_INTEGER = -(2**31)
#: Real DEMs that ship with matplotlib (``matplotlib.cbook.get_sample_data``).
MATPLOTLIB = {"jacksboro": "jacksboro_fault_dem.npz", "topobathy": "topobathy.npz"}
NAMES = tuple(FILES) + tuple(MATPLOTLIB)
#: The frame of DEMs whose coordinates are metres in an unnamed local plane.
LOCAL_TM = "+proj=tmerc +lat_0=0 +lon_0=0 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"


class RealDataUnavailable(RuntimeError):
    """The real DEMs are not cached and could not be downloaded; the message says why."""


def cache_dir() -> Path:
    return Path(os.environ.get("GLACIMAP_DATA", Path.home() / ".cache/glacimap/real-dems"))


def fetch(cache: Path | None = None) -> Path:
    """Download and unpack the packages once; return the cache folder with the real DEM files."""
    cache = Path(cache or cache_dir())
    if all((cache / f).exists() for f in FILES.values()):
        return cache
    if shutil.which("apt-get") is None or shutil.which("dpkg") is None:
        raise RealDataUnavailable("apt-get/dpkg not found: the real DEMs come from Debian packages")
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for pkg, files in PACKAGES.items():
            try:
                subprocess.run(
                    ["apt-get", "download", pkg], cwd=tmp, check=True, capture_output=True,
                    timeout=300,
                )  # fmt: skip
            except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as exc:
                err = getattr(exc, "stderr", b"") or b""
                raise RealDataUnavailable(
                    f"apt-get download {pkg} failed ({err.decode(errors='replace').strip()[-200:]}"
                    "); the package registry is needed once to cache the real DEMs"
                ) from exc
            deb = next(Path(tmp).glob(f"{pkg}_*.deb"))
            subprocess.run(["dpkg", "-x", str(deb), str(Path(tmp) / "x")], check=True)
            for name, rel in files.items():
                src = Path(tmp) / "x" / rel
                pairs = [(src, FILES[name])]
                if rel.endswith(".rdb"):  # the index first: a cached .rdb implies its .rdx
                    pairs.insert(0, (src.with_suffix(".rdx"), FILES[name][:-4] + ".rdx"))
                for one, cached in pairs:
                    part = cache / (cached + ".part")  # atomic: never a half-copied file
                    shutil.copyfile(one, part)
                    part.replace(cache / cached)
    return cache


def _read_rda(path: Path, name: str) -> dict:
    import rdata

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "Unknown encoding. Assumed ASCII."
        return rdata.read_rda(str(path))[name]


def _r_xz(data: bytes) -> bytes:
    """R's ``xz`` serialization: a raw LZMA2 stream (no xz container), preset 6
    (``init_filters`` in R's ``src/main/connections.c``)."""
    import lzma

    filters = [{"id": lzma.FILTER_LZMA2, "preset": 6}]
    return lzma.decompress(data, format=lzma.FORMAT_RAW, filters=filters)


def _read_lazyload(rdb: Path, obj: str) -> dict:
    """One object of an R lazy-load database (what ``lazyLoad`` reads): the ``.rdx`` index
    (an RDS file) gives each object's byte offset and length in the ``.rdb``, where it is
    stored as a 4-byte big-endian length and a compressed serialization: zlib, or (R's
    ``compress = 2 / 3``) a type byte, ``"2"`` bzip2, ``"Z"`` xz, ``"0"`` none, then the data."""
    import bz2
    import zlib

    import rdata

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "Wrong extension .rdx for file in RDS format"
        index = rdata.conversion.convert(rdata.parser.parse_file(str(rdb.with_suffix(".rdx"))))
        offset, length = (int(v) for v in index["variables"][obj])
        with open(rdb, "rb") as f:
            f.seek(offset)
            blob = f.read(length)
        if int(np.ravel(index["compressed"])[0]) in (2, 3):
            kind, body = blob[4:5], blob[5:]
            unpack = {b"2": bz2.decompress, b"Z": _r_xz, b"0": bytes}[kind]
        else:
            body, unpack = blob[4:], zlib.decompress
        parsed = rdata.parser.parse_data(unpack(body))
        # factor images (gorillas.extra$vegetation) stay integer codes: rdata's factor
        # constructor fails on a factor matrix, and no DEM is a factor
        classes = {**rdata.conversion.DEFAULT_CLASS_MAP, "factor": lambda obj, attrs: obj}
        return rdata.conversion.convert(parsed, classes, default_encoding="utf8")


def load(name: str) -> xr.DataArray:
    """A real DEM as a north-up ``DataArray`` (dims y, x) in its own CRS, metres of elevation.

    ``olinda`` keeps its UTM 25S CRS; ``rm``, ``prism`` and ``lux`` are in EPSG:4326 (degrees: a
    geographic DEM, as a user's satellite product may be); ``glacier`` is gridded at 100 m
    in a local transverse Mercator frame (its locations are km in an unnamed plane); ``bei``
    and ``volcano`` are in their own metres, labelled with the same local transverse Mercator frame;
    ``gorillas`` is in UTM 32N, ``clm`` in spatstat's km plane read as local metres.
    """
    if name not in NAMES:
        if Path(name).is_file():
            return load_file(name)
        raise ValueError(
            f"name: expected one of {NAMES} or the path of a DEM file, got {name!r} (no such file)"
        )
    if name in MATPLOTLIB:
        return _load_matplotlib(name)
    path = fetch() / FILES[name]
    if name in ("olinda", "lux"):
        return _read_raster(path, f"real DEM {name} ({FILES[name]})")
    if name in ("rm", "prism"):
        d = _read_rda(path, "RMelevation" if name == "rm" else "PRISMelevation")
        z = np.asarray(d["z"], float).T[::-1]  # R stores z[x, y] with y ascending
        x, y = np.asarray(d["x"], float), np.asarray(d["y"], float)[::-1]
        return _array(z, x, y, "EPSG:4326", name)
    if name in LAZYLOAD:
        obj, elements, unit_m, crs = LAZYLOAD[name]
        im = _read_lazyload(path, obj)
        for element in elements:
            im = im[element]
        if name == "volcano":  # volcano[i, j]: i runs south -> north, j east -> west, 10 m
            z = np.asarray(im, float)[::-1, ::-1]
            x = unit_m * np.arange(z.shape[1])
            y = unit_m * np.arange(z.shape[0])[::-1]
        else:  # a spatstat "im": v[row, col], rows = y ascending
            z = np.asarray(im["v"], float)[::-1]
            z[z == R_NA_INTEGER] = np.nan
            x = unit_m * np.asarray(im["xcol"], float)
            y = unit_m * np.asarray(im["yrow"], float)[::-1]
        return _array(z, x, y, crs or LOCAL_TM, name)
    from scipy.interpolate import griddata

    d = _read_rda(path, "glacier")
    loc = np.asarray(d["loc"], float) * 1000.0  # km -> m
    zpts = np.asarray(d["y"], float).ravel()
    res = 100.0
    x = np.arange(loc[:, 0].min() + res, loc[:, 0].max() - res, res)
    y = np.arange(loc[:, 1].max() - res, loc[:, 1].min() + res, -res)
    xx, yy = np.meshgrid(x, y)
    z = griddata(loc, zpts, (xx, yy), method="cubic")
    return _array(z, x, y, LOCAL_TM, name)


def load_file(path: str | Path) -> xr.DataArray:
    """A DEM of the user's own: any single-band raster GDAL reads, as :func:`load` returns.

    Parameters
    ----------
    path : str or Path
        A GeoTIFF, NetCDF, Arc/Info ASCII grid... Rows stored south -> north are flipped
        north-up; nodata cells become NaN (windows avoid them); a file without a CRS is
        labelled with the local transverse Mercator frame (a site takes only the DEM's shape).

    Returns
    -------
    xarray.DataArray, dims (y, x)
        Elevations at cell centres, in the file's own units and CRS.
    """
    return _read_raster(Path(path), f"DEM file {Path(path).name}")


def _read_raster(path: Path, source: str) -> xr.DataArray:
    import rasterio

    with rasterio.open(path) as ds:
        t = ds.transform
        if t.b != 0.0 or t.d != 0.0:
            raise ValueError(
                f"{path}: the raster is rotated (geotransform {tuple(t)[:6]}); warp it "
                "north-up first, e.g. gdalwarp SRC DST"
            )
        z = ds.read(1, masked=True).astype(float).filled(np.nan)
        crs = ds.crs.to_wkt() if ds.crs else LOCAL_TM
    x = t.c + t.a * (np.arange(z.shape[1]) + 0.5)
    y = t.f + t.e * (np.arange(z.shape[0]) + 0.5)
    if t.e > 0:  # rows stored south -> north
        z, y = z[::-1], y[::-1]
    return xr.DataArray(
        z,
        coords={"y": y, "x": x},
        dims=("y", "x"),
        name="elevation",
        attrs={"units": "m", "crs_wkt": crs, "source": source},
    )


def _load_matplotlib(name: str) -> xr.DataArray:
    from matplotlib import cbook

    with np.load(cbook.get_sample_data(MATPLOTLIB[name], asfileobj=False)) as d:
        if name == "jacksboro":
            z = np.asarray(d["elevation"], float)
            ny, nx = z.shape
            # cell centres; the file's "ymin" is the northern edge (rows run north -> south)
            x = float(d["xmin"]) + float(d["dx"]) * (np.arange(nx) + 0.5)
            y = float(d["ymin"]) - float(d["dy"]) * (np.arange(ny) + 0.5)
        else:
            z = np.asarray(d["topo"], float)
            x = np.asarray(d["longitude"], float) - 360.0  # 0..360 -> -180..180
            y = np.asarray(d["latitude"], float)
            if y[0] < y[-1]:
                z, y = z[::-1], y[::-1]
    return xr.DataArray(
        z,
        coords={"y": y, "x": x},
        dims=("y", "x"),
        name="elevation",
        attrs={
            "units": "m",
            "crs_wkt": "EPSG:4326",
            "source": f"real DEM {name} (matplotlib {MATPLOTLIB[name]})",
        },
    )


def _array(z, x, y, crs, name) -> xr.DataArray:
    return xr.DataArray(
        z,
        coords={"y": y, "x": x},
        dims=("y", "x"),
        name="elevation",
        attrs={"units": "m", "crs_wkt": crs, "source": f"real DEM {name} ({FILES[name]})"},
    )


def _windows(z: np.ndarray, k: int) -> list[tuple[int, int]]:
    """Top-left corners of k x k windows without NaN, most relief first."""
    ny, nx = z.shape
    step = max(k // 2, 1)
    out = []
    for i in range(0, ny - k + 1, step):
        for j in range(0, nx - k + 1, step):
            w = z[i : i + k, j : j + k]
            if np.all(np.isfinite(w)):
                out.append((float(np.std(w)), i, j))
    out.sort(reverse=True)
    return [(i, j) for _, i, j in out]


#: Spline degree of each ``glacier_site`` resampling.
SPLINE_DEGREE = {"cubic": 3, "linear": 1}


def glacier_site(
    name: str,
    size_m: float = 600.0,
    relief_m: float = 25.0,
    resolution: float = 2.0,
    nodes: int = 40,
    window: int = 0,
    crs: str = "EPSG:32608",
    resampling: str = "cubic",
) -> xr.DataArray:
    """A glacier-sized truth DEM whose shape comes from a real DEM.

    Parameters
    ----------
    name : str
        One of :data:`NAMES`, or the path of a DEM file of one's own (:func:`load_file`).
    size_m, resolution : float
        Side of the square site and its cell size, m.
    relief_m : float
        Elevation range of the site after rescaling, m (25 m: the paper's site).
    nodes : int
        Real DEM nodes along a side of the window: the node spacing on the site is
        ``size_m / (nodes - 1)`` (40 -> 15.4 m, the rover-scale length scale).
    window : int
        Which window: 0 is the one with the most relief, 1 the next...
    crs : str
        CRS the site is labelled with (the paper's UTM 8N).
    resampling : {"cubic", "linear"}
        How the window's nodes are carried onto the site's cells: a bicubic spline through
        them (smooth between nodes) or bilinear facets (creased along node lines, as a DEM
        upsampled by ``gdalwarp -r bilinear``).
    """
    from scipy.interpolate import RectBivariateSpline

    dem = load(name)
    z = np.asarray(dem.values, float)
    corners = _windows(z, nodes)
    if window >= len(corners):
        raise ValueError(
            f"window: {name} has {len(corners)} windows of {nodes} nodes without nodata, "
            f"window {window} asked for; ask for a lower window or fewer nodes"
        )
    i, j = corners[window]
    w = z[i : i + nodes, j : j + nodes]
    t = np.linspace(0.0, size_m, nodes)
    if resampling not in SPLINE_DEGREE:
        raise ValueError(f"resampling: expected one of {list(SPLINE_DEGREE)}, got {resampling!r}")
    k = SPLINE_DEGREE[resampling]
    spline = RectBivariateSpline(t, t, w[::-1], kx=k, ky=k)  # rows south -> north
    n = int(round(size_m / resolution))
    grid = Grid(500_000.0, 6_800_000.0 + size_m, (resolution, resolution), (n, n), crs)
    u = (np.arange(n) + 0.5) * resolution
    fine = spline(u, u)[::-1]  # back to north-up
    fine = (fine - fine.min()) / np.ptp(fine) * relief_m + 1000.0
    return grid.data_array(
        fine,
        "elevation",
        source=f"real DEM {name} window {window} ({nodes} nodes, corner row {i} col {j}), "
        f"rescaled to {size_m:g} m and {relief_m:g} m relief, {resampling} between nodes",
    )


def track_samples(
    truth: xr.DataArray,
    n: int,
    n_tracks: int = 8,
    scattered: float = 0.1,
    noise_sd: float = 0.2,
    lateral_sd: float = 8.0,
    stated_var: bool = True,
    seed: int = 0,
) -> ElevationSamples:
    """Noisy samples along ``n_tracks`` north-south rover tracks plus scattered points.

    Track samples lie beside wavy north-south lines (half-normal lateral offset of
    ``lateral_sd`` m on either side), ``scattered`` of them uniformly over the site. Each
    sample is the bilinear truth plus N(0, noise_sd^2); ``stated_var`` writes that variance
    into ``z_var`` (else 0: noise the samples do not state).
    """
    from terrain import sample_dem

    rng = np.random.default_rng(seed)
    grid = Grid.from_dataarray(truth)
    w, s, e, nb = grid.bounds
    lo = np.array([grid.x[0], grid.y[-1]])
    hi = np.array([grid.x[-1], grid.y[0]])
    n_scat = int(round(scattered * n))
    n_trk = n - n_scat
    track = rng.integers(0, n_tracks, n_trk)
    spacing = (e - w) / n_tracks
    yy = rng.uniform(s, nb, n_trk)
    phase = rng.uniform(0, 2 * np.pi, n_tracks)
    x0 = w + spacing * (track + 0.5) + 6.0 * np.sin(yy / 45.0 + phase[track])
    xx = x0 + rng.normal(0.0, lateral_sd, n_trk)
    pts = np.column_stack([xx, yy])
    pts = np.vstack([pts, rng.uniform(lo, hi, (n_scat, 2))])
    pts = np.clip(pts, lo, hi)
    true_z = sample_dem(truth, pts)
    z = true_z + rng.normal(0.0, noise_sd, n)
    z_var = np.full(n, noise_sd**2 if stated_var else 0.0)
    return ElevationSamples(
        pts, z, z_var, crs=grid.crs, extra={"true_z": true_z}, duplicates="average"
    )


if __name__ == "__main__":
    where = fetch()
    print(f"real DEMs cached in {where}")
    for nm in NAMES:
        da = load(nm)
        print(f"  {nm:8s} {da.shape} {np.nanmin(da.values):8.1f}..{np.nanmax(da.values):8.1f} m")
