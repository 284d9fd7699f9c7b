"""The scenario file (TOML) of ``glacimap run``: validated, unknown keys rejected with a
did-you-mean, and an embedded default — the paper's 600 m x 600 m glacier site, a
lawnmower with 4 swaths, default sensors, seed 0.

Every key, its unit and default is in :data:`DEFAULT_SCENARIO` below (also printed by
``glacimap run --print-default``).
"""

from __future__ import annotations

import copy
import difflib
import tomllib
from pathlib import Path
from typing import Any

from terrain.errors import bad_input

__all__ = [
    "DEFAULT_SCENARIO",
    "DEFAULT_TOML",
    "anisotropy_option",
    "load_scenario",
    "print_default",
]

DEFAULT_TOML = """\
# glacimap scenario: the paper's simulated glacier site (Section IV), seed 0.
seed = 0                       # the one seed: terrain noise, sensors, GP subsets, bootstrap

[site]
kind = "default"               # "default": the embedded 600 m site; "random": random_terrain;
                               # "dem": the DEM file `dem` (docs/vision.md, toolkit/site_dem.py)
bounds = [526000.0, 6475000.0, 526600.0, 6475600.0]  # west, south, east, north (m, crs)
crs = "EPSG:32608"             # projected CRS (UTM 8N, Juneau Icefield)
truth_resolution_m = 2.0       # cell of the true DEM the rover drives on
relief_m = 25.0                # relief of a "random" site (m)
dem = ""                       # kind = "dem": any GDAL raster (GeoTIFF...), any CRS, nodata ok;
                               # a relative path is read from this file's folder. Reprojected
                               # (cubic; average when coarsening) to crs at truth_resolution_m.
                               # crs unset: the DEM's own if projected, else the UTM zone of its
                               # centre (stated in the summary). bounds unset: the DEM's
                               # valid-data extent (largest valid rectangle if it is ragged).
max_nodata_fraction = 0.05     # kind = "dem": refuse a site with more nodata cells than this
                               # share; fewer are filled from the nearest valid cell (counted)

[plan]
pattern = "lawnmower"          # "lawnmower" or "piecewise" (Eq 10)
n_swaths = 4
margin_m = 10.0                # swath ends kept this far inside the site

[sensors]                      # factorgraph.sensors: documented defaults
speed_mps = 1.0
keyframe_dt_s = 2.0            # one keyframe (and one GPS fix) every 2 s

[sensors.gps]
rate_hz = 0.5
sigma_white_m = [2.5, 2.5, 2.5]
bias_sigma_m = [2.5, 2.5, 2.5]
bias_tau_s = 60.0

[sensors.camera]
texture_density_per_m2 = 0.05

[sensors.tilt]                 # accelerometer / inclinometer: gravity direction per keyframe
sigma_deg = 0.5

[localize]
gps_model = "bias"             # "white" is the negative control

[select]
max_sigma_m = 0.5              # the paper's 1-sigma limit, on the relative covariance
rule = "elevation"             # what it bounds: "elevation" (slope-aware z) or "ellipse" (3-D)
min_first_seen_distance_m = 5.0
variance = "slope"             # sample variance: "slope" (var(z - grad z.[x,y])) or "eq7"

[reconstruct]
resolution_m = 2.0             # output grid cell (m)
method = "auto"                # TerrainGP method: auto | exact | tiled
max_fit_samples = 2000         # hyperparameters on <= this many samples: TerrainGP's default
n_restarts = 1
anisotropy = "none"            # ground smoother along one azimuth: "none"; "auto" (chosen by
                               # evidence, BIC); [azimuth_deg, ratio]: a known grain, e.g. a
                               # glacier's flow (docs/terrain.md "Anisotropic ground")
breaklines = ""                # lines the ground steps across (an ice cliff, a moraine's
                               # edge): "" none; "auto": found where the selected landmarks
                               # step (terrain.find_breaklines); or a vector file (GeoPackage,
                               # GeoJSON, Shapefile, WKT), a relative path read from this
                               # file's folder. Step heights fitted (docs/terrain.md)
breakline_width = "auto"       # scale of each step's logistic (m), or "auto": fitted
breakline_taper = "auto"       # length a step dies out over before a line's end inside the
                               # survey (m), or "auto": fitted
compare_constant_mean = false  # simulation: also fit a constant-mean GP, scored on the truth

[prior]                        # the satellite DEM (prior.tif): RasterMean, a + b * DEM by GLS
cells = "auto"                 # the paper's triangulated 8 x 8 mean unless the DEM's own cells
                               # are >= 2 x finer (then its own); [8, 8]: always; []: its own
coarse = "mesh"                # those cells through their centres (the paper's), or
                               # "area-means": the smoothest surface keeping each cell's mean
resampling = "bilinear"        # reprojection of a DEM in another CRS
as = "mean"                    # "mean": a + b * DEM (above); "data": its own cells as samples
                               # with their datum offset and 1-sigma measured on the survey,
                               # under a constant mean -- for a DEM noisier than the survey's
                               # interpolation (docs/terrain.md "A satellite DEM as data");
                               # "auto": whichever maps the survey's held-out blocks better
                               # (docs/terrain.md "The DEM's reading chosen by the survey")
resolution_m = 75.0            # simulation: cell of the DEM written (75 m = 8 x 8 on 600 m)
offset_m = 1.5                 # simulation: its vertical datum offset against GPS heights (m)
noise_sd_m = 0.3               # simulation: its independent error per cell (m)

[field]                        # simulation: how the survey is written for glacimap process
gps_format = "nmea"            # nmea | gpx | rtklib
camera = "tracks"              # tracks: ideal simulated feature tracks; images: frames rendered
                               # with the vision camera preset into rover/images, tracked by the
                               # OpenCV front-end in process (docs/vision.md; ~0.45 s a frame)
scene = "sunny_snow"           # camera = "images": sunny_snow | sunny_dirty_ice | overcast_snow
                               # | low_sun

[control]                      # simulation: ground control at the survey's 4 corners
n_targets = 0                  # control points: 0, 4 at the corners, 8 stops at every turn
mode = "stops"                 # "stops" (rover stands on them), "targets" (camera) or "both"
sigma_m = 0.02                 # their survey's 1-sigma (m)

[certify]
n_checkpoints = 400            # independent checkpoints drawn from the truth (seeded)
n_boot = 2000
heldout_folds = 5              # spatial-block CV of the map's sigma (0: skip)

[export]
mesh = true
geojson = true

[change]                       # a second epoch: the site after a known change (docs/change.md)
epoch = 1                      # 1: the site as is; 2: after the change below, surveyed anew
seed_offset = 2                # epoch 2 is surveyed with seed + seed_offset (new GPS bias, ...)
change_seed = 0                # seed of the change's ablation features (terrain.surface_change)
outline_margin = 0.2           # glacier outline: terrain.default_outline(site bounds, margin)
min_thinning_m = 0.5           # thinning at the highest glacier cell (m)
max_thinning_m = 3.0           # thinning at the lowest glacier cell (m)
n_features = 12                # melt pools / crevasses: 0.2-1 m deep, 5-20 m wide
taper_m = 20.0                 # the change ramps up over this distance inside the outline (m)
"""

DEFAULT_SCENARIO: dict[str, Any] = tomllib.loads(DEFAULT_TOML)

# Keys accepted inside [sensors.*] beyond those in the default (checked by the sensor models).
_OPEN_TABLES = {
    ("sensors", "gps"),
    ("sensors", "odometry"),
    ("sensors", "camera"),
    ("sensors", "tilt"),
    ("localize",),
}
_EXTRA_ALLOWED = {("sensors",): {"odometry", "camera", "gps", "tilt"}}
# Keys of either type (metres or "auto"), checked with the rest of their kind at load.
_CHECKED_LATER = {("reconstruct", "breakline_width"), ("reconstruct", "breakline_taper")}


def _open_table_keys(where: tuple[str, ...]) -> set[str]:
    """Field names of the dataclass an open table feeds (its values are checked there)."""
    from dataclasses import fields

    from factorgraph.localize import LocalizeParams
    from factorgraph.sensors import CameraModel, GPSModel, OdometryModel, TiltModel

    kind = {
        ("sensors", "gps"): GPSModel,
        ("sensors", "odometry"): OdometryModel,
        ("sensors", "camera"): CameraModel,
        ("sensors", "tilt"): TiltModel,
        ("localize",): LocalizeParams,
    }[where]
    return {f.name for f in fields(kind)}


def _unknown(path: str, key: str, allowed: set[str]):
    close = difflib.get_close_matches(key, sorted(allowed), n=1)
    hint = f"did you mean '{close[0]}'?" if close else f"known keys: {sorted(allowed)}"
    return bad_input(path, key, "a known scenario key", hint)


def _check(user: dict[str, Any], ref: dict[str, Any], where: tuple[str, ...]) -> None:
    if where in _OPEN_TABLES:
        # keys checked here (with a did-you-mean), values by the dataclass they feed
        allowed = _open_table_keys(where)
        for key in user:
            if key not in allowed:
                raise _unknown(".".join((*where, key)), key, allowed)
        return
    allowed = set(ref) | _EXTRA_ALLOWED.get(where, set())
    for key, value in user.items():
        path = ".".join((*where, key))
        if key not in allowed:
            raise _unknown(path, key, allowed)
        if (*where, key) == ("prior", "cells"):  # "auto" or a list: [8, 8], [] (own cells)
            if not (value == "auto" or isinstance(value, list)):
                raise bad_input(path, value, '"auto" or a list [ny, nx] ([] = own cells)', "")
        elif (*where, key) == ("reconstruct", "anisotropy"):
            anisotropy_option(value, path)
        elif (*where, key) in _CHECKED_LATER:
            pass  # metres or "auto": toolkit.breaklines_io.scenario_breaklines
        elif (*where, key) == ("prior", "coarse") and value not in ("mesh", "area-means"):
            raise bad_input(path, value, '"mesh" or "area-means"', 'coarse = "mesh"')
        elif (*where, key) == ("prior", "as") and value not in ("mean", "data", "auto"):
            raise bad_input(path, value, '"mean", "data" or "auto"', 'as = "auto"')
        elif isinstance(value, dict):
            _check(value, ref.get(key, {}) if isinstance(ref.get(key), dict) else {}, (*where, key))
        elif key in ref and not isinstance(ref[key], dict):
            want = type(ref[key])
            ok = isinstance(value, want) or (want is float and isinstance(value, int))
            if isinstance(value, bool) and want is not bool:
                ok = False
            if not ok:
                raise bad_input(path, value, f"a {want.__name__}", f"default is {ref[key]!r}")


def anisotropy_option(value: Any, field: str = "reconstruct.anisotropy") -> Any:
    """``TerrainGP(anisotropy=...)`` from a setting: ``"none"`` -> None, ``"auto"``, or
    ``[azimuth_deg, ratio]`` (also the text ``"30,2"``) -> :class:`terrain.Anisotropy`."""
    from terrain import Anisotropy

    if isinstance(value, str) and value.strip().lower() in ("none", "auto"):
        return None if value.strip().lower() == "none" else "auto"
    parts = value.split(",") if isinstance(value, str) else value
    try:
        if isinstance(parts, list | tuple) and len(parts) == 2:
            return Anisotropy(float(parts[0]), float(parts[1]))
    except (TypeError, ValueError):
        pass
    raise bad_input(
        field,
        value,
        '"none", "auto" or [azimuth_deg, ratio] with ratio >= 1',
        "e.g. anisotropy = [30.0, 2.0]: lengths twice as long along azimuth 30 deg",
    )


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def print_default(file: Any = None) -> None:
    """Write :data:`DEFAULT_TOML` to ``file`` (default ``sys.stdout``) byte for byte.

    Not through rich: a console that is not a terminal wraps long lines at 80 columns, which
    split comments onto lines TOML cannot parse (``glacimap run --print-default > my.toml``).
    """
    import sys

    out = sys.stdout if file is None else file
    out.write(DEFAULT_TOML)
    out.flush()


def load_scenario(path: str | Path | None = None, overrides: dict | None = None) -> dict:
    """The default scenario, updated by the TOML file at ``path`` and by ``overrides``.

    Raises
    ------
    InputError
        Missing or malformed file, unknown key (with a did-you-mean), wrong value type.
    """
    user: dict[str, Any] = {}
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise bad_input("--config", str(p), "an existing TOML file", "check the path")
        try:
            user = tomllib.loads(p.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise bad_input("--config", str(p), "valid TOML", f"{exc}") from exc
    _check(user, DEFAULT_SCENARIO, ())
    scenario = _merge(DEFAULT_SCENARIO, user)
    if overrides:
        _check(overrides, DEFAULT_SCENARIO, ())
        scenario = _merge(scenario, overrides)
    seed = scenario["seed"]
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise bad_input("seed", seed, "an integer >= 0", "seed = 0")
    if scenario["plan"]["pattern"] not in ("lawnmower", "piecewise"):
        raise bad_input(
            "plan.pattern",
            scenario["plan"]["pattern"],
            "lawnmower|piecewise",
            'pattern = "lawnmower" or "piecewise"',
        )
    if scenario["site"]["kind"] not in ("default", "random", "dem"):
        raise bad_input(
            "site.kind", scenario["site"]["kind"], "'default', 'random' or 'dem'", "pick one"
        )
    base = Path(path).resolve().parent if path is not None else Path.cwd()  # relative paths
    if scenario["site"]["kind"] == "dem":  # path, CRS and bounds resolved once, here
        from .site_dem import resolve_dem_site

        given = set(user.get("site", {})) | set((overrides or {}).get("site", {}))
        scenario["site"] = resolve_dem_site(scenario["site"], given, base)
    from .breaklines_io import scenario_breaklines  # a bad lines file fails here, by key

    scenario["reconstruct"] = scenario_breaklines(scenario["reconstruct"], base)
    if int(scenario["plan"]["n_swaths"]) < 1:
        raise bad_input(
            "plan.n_swaths", scenario["plan"]["n_swaths"], "an integer >= 1", "e.g. n_swaths = 4"
        )
    if scenario["control"]["mode"] not in ("stops", "targets", "both"):
        raise bad_input(
            "control.mode", scenario["control"]["mode"], "stops|targets|both", 'mode = "stops"'
        )
    if int(scenario["control"]["n_targets"]) and int(scenario["plan"]["n_swaths"]) < 2:
        raise bad_input(  # one straight swath has 2 ends, not 4 corners to stand on
            "control.n_targets",
            scenario["control"]["n_targets"],
            "0 with a single swath (control stops stand on the survey's corners or turns)",
            "survey 2 or more swaths ([plan] n_swaths), or n_targets = 0",
        )
    _check_field(scenario)
    _check_models(scenario)
    from .epochs import check_change  # [change]: the second epoch's values

    check_change(scenario)
    return scenario


def _check_field(scenario: dict[str, Any]) -> None:
    """``[field]``: the camera route and its scene; rendered frames carry no marked targets."""
    f = scenario["field"]
    if f["camera"] not in ("tracks", "images"):
        raise bad_input("field.camera", f["camera"], "tracks|images", 'camera = "tracks"')
    if f["camera"] == "images":
        from factorgraph.vision import SCENES

        if f["scene"] not in SCENES:
            raise bad_input("field.scene", f["scene"], "|".join(sorted(SCENES)), "pick one")
        if int(scenario["control"]["n_targets"]) and scenario["control"]["mode"] != "stops":
            raise bad_input(
                "control.mode",
                scenario["control"]["mode"],
                '"stops" with field.camera = "images" (the renderer draws no marked targets)',
                'mode = "stops"',
            )


def _check_models(scenario: dict[str, Any]) -> None:
    """Build the sensor models and the estimator settings once, so that a bad value fails
    at load time (before any work) with the table's name in the message."""
    from factorgraph.localize import LocalizeParams
    from factorgraph.sensors import SensorSuite
    from terrain.errors import InputError

    for table, build in (
        ("sensors", lambda: SensorSuite.from_dict(scenario["sensors"])),
        ("localize", lambda: LocalizeParams(**scenario["localize"])),
    ):
        try:
            build()
        except InputError:
            raise
        except (TypeError, ValueError) as exc:
            raise bad_input(
                table, scenario[table], "values of the documented types", str(exc)
            ) from exc
