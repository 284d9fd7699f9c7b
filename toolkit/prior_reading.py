"""How a prior DEM is read: as the mean, as data, or chosen by the survey (``--prior-as``).

``mean`` (the default): ``a + b * DEM`` (:class:`terrain.RasterMean`). ``data``: its cells
as samples with their own 1-sigma (:func:`terrain.dem_as_data.dem_as_data`) under a
constant mean. ``auto``: whichever of the two maps the survey's held-out samples better
(:func:`terrain.dem_choice.choose_dem_reading`), with the map's own GP settings; the choice
and both scores go into the product (``prior_reading``) and the certificate.
"""

from __future__ import annotations

import json
from typing import Any

from terrain import ElevationSamples, Grid
from terrain.errors import bad_input

__all__ = ["PRIOR_READINGS", "choose_reading", "prior_reading", "reading_record"]

#: ``--prior-as`` / ``[prior] as``: the default first.
PRIOR_READINGS = ("mean", "data", "auto")


def prior_reading(prior: Any, settings: dict[str, Any], given: str | None = None) -> str:
    """How the prior DEM is read: ``given`` (``--prior-as``) or the ``[prior] as`` setting.

    Returns
    -------
    {"mean", "data", "auto"}

    Raises
    ------
    InputError
        Another value, or ``data`` / ``auto`` without a DEM (nothing to read).
    """
    field = "--prior-as" if given is not None else "[prior] as"
    value = given if given is not None else settings.get("prior", {}).get("as", "mean")
    if value not in PRIOR_READINGS:
        raise bad_input(field, value, '"mean", "data" or "auto"', "e.g. --prior-as auto")
    if value != "mean" and prior is None:
        raise bad_input(
            field, value, "a prior DEM to read", "pass --prior DEM.tif, or read it as mean"
        )
    return value


def choose_reading(
    prior: Any,
    dem_mean: Any,
    survey: ElevationSamples,
    grid: Grid,
    settings: dict[str, Any],
    seed: int,
) -> Any:
    """``--prior-as auto``: the DEM read as the mean or as data, chosen by held-out samples.

    Parameters
    ----------
    prior : path, rasterio dataset, xarray.DataArray or RasterMean
        The DEM.
    dem_mean : RasterMean
        The mean reading's mean (``prior_mean``'s), bound to ``grid`` here.
    survey : ElevationSamples
        The survey's samples (the map's CRS, m), without the DEM's cells.
    grid : Grid
        The map.
    settings : dict
        The scenario: ``[reconstruct]`` builds both GPs as the map's
        (:func:`toolkit.stages.map_estimator`); ``[certify] heldout_folds`` the folds
        (at least 2).
    seed : int
        The one seed: the GPs' and the blocks' deal.

    Returns
    -------
    terrain.dem_choice.DemReading or str
        The choice; or, where the survey cannot be held out in enough blocks to choose (a
        handful of samples), why, in words: the DEM is then read as the mean (the default).
    """
    from terrain import RasterMean
    from terrain.dem_choice import choose_dem_reading

    from .stages import map_estimator

    dem = prior.source if isinstance(prior, RasterMean) else prior  # its own file or array
    folds = max(2, int(settings["certify"]["heldout_folds"]) or 5)
    if survey.n < folds:  # too few samples to hold out one block per fold
        return (
            f"--prior-as auto could not choose ({survey.n} samples for {folds} held-out "
            "folds); the prior DEM is read as the mean"
        )
    return choose_dem_reading(
        map_estimator(dem_mean, grid, settings, seed),
        map_estimator("constant", grid, settings, seed),
        dem,
        survey,
        grid,
        n_folds=folds,
        seed=seed,
    )


def reading_record(choice: Any) -> str:
    """The product's ``prior_reading`` attribute: the choice's record as JSON."""
    return json.dumps(choice.to_dict(), sort_keys=True)
