"""The terrain layer: grids and CRS, synthetic glaciers, satellite priors, GP reconstruction.

``terrain`` is the base of glacimap (docs/architecture.md §2): it imports nothing from ``survey``,
``factorgraph`` or ``toolkit``. The names below are the public contract.
"""

from .anisotropy import Anisotropy
from .baselines import delaunay_linear
from .block_samples import BlockReduction, block_reduce
from .breakline import BreaklineMean
from .breakline_search import BreaklineSearch, find_breaklines
from .change import difference
from .coregister import Coregistration, coregister
from .errors import (
    CRSMismatchError,
    DegenerateFitWarning,
    DuplicateLocationError,
    GlacimapError,
    InputError,
    JitterWarning,
    NotFittedError,
    NumericalError,
    TilingWarning,
)
from .gaussian_field import gaussian_field_site, gaussian_field_terrain, se_random_field
from .gp import TerrainGP
from .grid import DEFAULT_CRS, Grid
from .kernels import Matern, SquaredExponential, SumKernel
from .metrics import (
    covered_fraction,
    evaluate,
    interval_coverage,
    mae,
    max_abs_error,
    nlpd,
    rmse,
    standardized_error_stats,
)
from .posterior import HyperPosterior, ShortChainWarning, sample_hyperparameters
from .prior import ConstantMean, TriangulatedMean, as_mean_function, coarse_dem
from .pycnophylactic import PycnophylacticMean
from .raster_mean import RasterMean
from .samples import ElevationSamples
from .sampling import LandmarkNoise, sample_along_path, sample_dem
from .surface_change import default_outline, second_epoch, surface_change
from .synthetic import TerrainFeatures, default_site, random_terrain, terrain_function
from .tiled import TileSpec
from .tuning import PaperTuning, tune_paper_grid
from .validation import CrossValidation, cross_validate
from .volume import VolumeChange, volume_change

__all__ = [
    "DEFAULT_CRS",
    "Anisotropy",
    "BlockReduction",
    "CRSMismatchError",
    "DegenerateFitWarning",
    "ConstantMean",
    "Coregistration",
    "CrossValidation",
    "DuplicateLocationError",
    "ElevationSamples",
    "GlacimapError",
    "Grid",
    "HyperPosterior",
    "InputError",
    "JitterWarning",
    "LandmarkNoise",
    "Matern",
    "NotFittedError",
    "NumericalError",
    "PaperTuning",
    "PycnophylacticMean",
    "RasterMean",
    "BreaklineMean",
    "BreaklineSearch",
    "ShortChainWarning",
    "SquaredExponential",
    "SumKernel",
    "TerrainFeatures",
    "TerrainGP",
    "TileSpec",
    "TilingWarning",
    "TriangulatedMean",
    "VolumeChange",
    "as_mean_function",
    "coarse_dem",
    "coregister",
    "covered_fraction",
    "cross_validate",
    "default_outline",
    "default_site",
    "delaunay_linear",
    "block_reduce",
    "find_breaklines",
    "difference",
    "evaluate",
    "gaussian_field_site",
    "gaussian_field_terrain",
    "interval_coverage",
    "mae",
    "max_abs_error",
    "nlpd",
    "random_terrain",
    "rmse",
    "sample_along_path",
    "sample_dem",
    "sample_hyperparameters",
    "se_random_field",
    "second_epoch",
    "standardized_error_stats",
    "surface_change",
    "terrain_function",
    "tune_paper_grid",
    "volume_change",
]
