"""GIS and mesh exports of a terrain product (docs/architecture.md §1 step 7).

Every writer validates its input first (``terrain.errors.InputError`` naming the field, the
value and the fix) and writes atomically: a file is complete or absent.

- :func:`write_cog` — Cloud-Optimized GeoTIFF, bands ``elevation`` and ``elevation_std``.
- :func:`write_contours` — contour lines (``elev``, ``index``, ``mean_std``) to GeoPackage /
  GeoJSON.
- :func:`write_vector_layers` — named point / line layers (trajectory, landmarks) to
  GeoPackage; :class:`VectorLayer` builds them, :func:`write_geojson` writes one as RFC 7946.
- :func:`write_netcdf` — the product as CF-1.8 netCDF with standard names
  (:func:`cf_standard_name`).
- :func:`write_mesh` — triangle mesh with per-vertex 1-sigma as PLY, VTP and a PNG render.
"""

from __future__ import annotations

from .contours import INDEX_EVERY, contour_layer, contour_levels, write_contours
from .geotiff import write_cog
from .mesh import TerrainMesh, terrain_mesh, write_mesh
from .netcdf import cf_standard_name, write_netcdf
from .vectors import VectorLayer, write_geojson, write_vector_layers

__all__ = [
    "INDEX_EVERY",
    "TerrainMesh",
    "VectorLayer",
    "cf_standard_name",
    "contour_layer",
    "contour_levels",
    "terrain_mesh",
    "write_cog",
    "write_contours",
    "write_geojson",
    "write_mesh",
    "write_netcdf",
    "write_vector_layers",
]
