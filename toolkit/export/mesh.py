"""A triangle mesh of the terrain with per-vertex uncertainty: PLY, VTP and a rendered PNG.

Vertices are the cell centres of the product's Grid, stored relative to a recorded local
origin (default: the grid's south-west corner and elevation 0) so that float32 keeps
sub-millimetre precision even though UTM northings are ~10^6-10^7 m. Each quad between four
neighbouring cell centres becomes two triangles, counter-clockwise seen from above (normals
point up); a quad with a NaN corner is dropped and counted.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS

from terrain.errors import bad_input

from ._files import atomic_file, check_target
from ._product import Product, read_product

__all__ = ["TerrainMesh", "terrain_mesh", "write_mesh"]


@dataclass(frozen=True)
class TerrainMesh:
    """A terrain triangulation.

    Attributes
    ----------
    vertices : ndarray of shape (n, 3), float32
        Easting, northing, elevation minus ``origin``, metres.
    faces : ndarray of shape (m, 3), int32
        Vertex indices, counter-clockwise seen from above.
    elevation, elevation_std : ndarray of shape (n,), float64
        Absolute elevation and its 1-sigma at each vertex, metres.
    origin : ndarray of shape (3,), float64
        Add to ``vertices`` to get coordinates in ``crs`` (m).
    crs : pyproj.CRS
        Horizontal CRS of the grid.
    dropped_cells : int
        Quads (of the ``(ny - 1) * (nx - 1)``) left out because a corner was NaN.
    elevation_std_relative : ndarray of shape (n,) or None
        The map's own 1-sigma (the survey's shared offset left out, m), when the product has
        it: where the data gaps are, which the total 1-sigma hides under the shared term.
    """

    vertices: np.ndarray
    faces: np.ndarray
    elevation: np.ndarray
    elevation_std: np.ndarray
    origin: np.ndarray
    crs: CRS
    dropped_cells: int
    elevation_std_relative: np.ndarray | None = None


def terrain_mesh(ds: Any, origin: Any = None) -> TerrainMesh:
    """Triangulate a terrain product: two triangles per quad of cell centres.

    Parameters
    ----------
    ds : xarray.Dataset
        Terrain product (``elevation``, ``elevation_std`` on ``(y, x)``, CRS in attrs).
    origin : array-like of shape (3,), optional
        Local origin (easting, northing, elevation) in metres; default the grid's west and
        south edges and elevation 0.
    """
    return _mesh(read_product(ds), origin)


def _mesh(product: Product, origin: Any) -> TerrainMesh:
    grid = product.grid
    if origin is None:
        west, south, _, _ = grid.bounds
        origin = (west, south, 0.0)
    o = np.asarray(origin, dtype=float)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise bad_input("origin", origin, "three finite numbers (x, y, z) in metres", "")
    ny, nx = grid.shape
    if ny < 2 or nx < 2:
        raise bad_input("product shape", grid.shape, "at least 2 x 2 cells to mesh", "")
    z = product.elevation
    finite = np.isfinite(z)
    idx = np.arange(ny * nx).reshape(ny, nx)
    nw, ne, sw, se = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    ok = finite[:-1, :-1] & finite[:-1, 1:] & finite[1:, :-1] & finite[1:, 1:]
    nw, ne, sw, se = nw[ok], ne[ok], sw[ok], se[ok]
    faces = np.concatenate([np.column_stack([sw, se, ne]), np.column_stack([sw, ne, nw])])
    # Keep only vertices used by a triangle, renumbered in row-major order.
    used = np.zeros(ny * nx, bool)
    used[faces.ravel()] = True
    new_index = np.cumsum(used) - 1
    xy = grid.xy()[used]
    vertices = np.column_stack([xy - o[:2], z.ravel()[used] - o[2]]).astype(np.float32)
    return TerrainMesh(
        vertices=vertices,
        faces=new_index[faces].astype(np.int32),
        elevation=z.ravel()[used],
        elevation_std=product.elevation_std.ravel()[used],
        origin=o,
        crs=grid.crs,
        dropped_cells=int((~ok).sum()),
        elevation_std_relative=(
            None
            if product.elevation_std_relative is None
            else product.elevation_std_relative.ravel()[used]
        ),
    )


def _ascii(text: str) -> str:
    return " ".join(text.encode("ascii", "replace").decode().split())


def _write_ply(path: Path, mesh: TerrainMesh, provenance: dict[str, str]) -> None:
    """Binary little-endian PLY with a float ``quality`` vertex property (= elevation_std).

    Written directly: open3d's PLY writer cannot store extra per-vertex properties. Readers
    that do not know ``quality`` (open3d, MeshLab's import) skip it; MeshLab maps it to
    vertex quality.
    """
    x0, y0, z0 = mesh.origin
    epsg = mesh.crs.to_epsg()
    comments = [
        "glacimap terrain mesh",
        f"origin {float(x0)!r} {float(y0)!r} {float(z0)!r}",
        "vertex x y z are relative to the origin: add it to get coordinates in the crs, m",
        f"crs {f'EPSG:{epsg}' if epsg else _ascii(mesh.crs.to_wkt())}",
        "quality = elevation_std, posterior 1-sigma of elevation, metres",
        *(f"{k} {_ascii(v)}" for k, v in provenance.items() if k in ("seed", "method")),
        f"vertical_datum of z {_ascii(provenance.get('vertical_datum', 'not stated'))}",
    ]
    n, m = len(mesh.vertices), len(mesh.faces)
    header = "\n".join(
        [
            "ply",
            "format binary_little_endian 1.0",
            *(f"comment {_ascii(c)}" for c in comments),
            f"element vertex {n}",
            *(f"property float {p}" for p in ("x", "y", "z", "quality")),
            f"element face {m}",
            "property list uchar int vertex_indices",
            "end_header",
        ]
    )
    vert = np.empty(n, [("xyz", "<f4", 3), ("quality", "<f4")])
    vert["xyz"] = mesh.vertices
    vert["quality"] = mesh.elevation_std
    face = np.empty(m, [("count", "u1"), ("idx", "<i4", 3)])
    face["count"] = 3
    face["idx"] = mesh.faces
    with open(path, "wb") as f:
        f.write((header + "\n").encode("ascii"))
        f.write(vert.tobytes())
        f.write(face.tobytes())


def _polydata(mesh: TerrainMesh, provenance: dict[str, str]):
    import pyvista as pv

    faces = np.column_stack([np.full(len(mesh.faces), 3), mesh.faces]).ravel()
    poly = pv.PolyData(mesh.vertices, faces=faces)
    poly.point_data["elevation"] = mesh.elevation
    poly.point_data["elevation_std"] = mesh.elevation_std
    if mesh.elevation_std_relative is not None:
        poly.point_data["elevation_std_relative"] = mesh.elevation_std_relative
    poly.field_data["origin"] = mesh.origin
    # VTK string arrays are ASCII only (the WKT's area of use has a degree sign).
    strings = {"crs": mesh.crs.to_string(), "crs_wkt": mesh.crs.to_wkt(), **provenance}
    for key, value in strings.items():
        poly.field_data[key] = [value.encode("ascii", "ignore").decode()]
    return poly


def _write_vtp(path: Path, poly: Any) -> None:
    from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter

    writer = vtkXMLPolyDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(poly)
    writer.SetDataModeToBinary()
    writer.SetCompressorTypeToZLib()
    if writer.Write() != 1:
        raise OSError(f"VTK could not write {path}")


def _render_png(
    path: Path, poly: Any, exaggeration: float, window_size: tuple[int, int], title: str
) -> None:
    import matplotlib.image
    import pyvista as pv
    from vtkmodules.vtkCommonCore import vtkLogger

    # Without a display VTK falls back to off-screen rendering after printing "bad X server
    # connection" as a warning on stderr on every glacimap run / process / export: the PNG is
    # still made, so only VTK's errors are shown (a real failure raises below).
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    shown = poly.copy()
    shown.points[:, 2] *= exaggeration
    plotter = pv.Plotter(off_screen=True, window_size=list(window_size))
    try:
        plotter.set_background("white")
        plotter.add_mesh(
            shown,
            scalars="elevation_std",
            cmap="viridis",
            nan_color="lightgrey",
            scalar_bar_args={"title": "1-sigma (m)", "color": "black", "vertical": True},
        )
        plotter.add_text(title, font_size=10, color="black")
        plotter.view_isometric()
        image = plotter.screenshot(return_img=True)
    finally:
        plotter.close()
    matplotlib.image.imsave(path, image, format="png")


def write_mesh(
    ds: Any,
    ply_path: str | os.PathLike | None = None,
    vtp_path: str | os.PathLike | None = None,
    png_path: str | os.PathLike | None = None,
    origin: Any = None,
    *,
    exaggeration: float = 3.0,
    window_size: tuple[int, int] = (1200, 900),
) -> dict[str, Any]:
    """Write the terrain mesh with per-vertex 1-sigma as PLY, VTP and/or a rendered PNG.

    Parameters
    ----------
    ds : xarray.Dataset
        Terrain product (``elevation``, ``elevation_std`` on ``(y, x)``, CRS in attrs).
    ply_path : path-like, optional
        Binary PLY: float32 vertex ``x y z`` (relative to the origin) and ``quality`` (=
        ``elevation_std``, m), triangle faces; comment lines give the origin, CRS, seed and
        the vertical datum of z.
    vtp_path : path-like, optional
        VTK XML PolyData: the same points, point arrays ``elevation`` (absolute, m) and
        ``elevation_std`` (m; and ``elevation_std_relative`` when the product has it), field
        data ``origin`` (3,), ``crs_wkt`` and provenance.
    png_path : path-like, optional
        Off-screen pyvista render coloured by ``elevation_std`` with a "1-sigma (m)" bar.
    origin : array-like of shape (3,), optional
        Local origin, metres; default (west, south, 0) of the grid.
    exaggeration : float
        Vertical exaggeration of the PNG render only (> 0).
    window_size : (int, int)
        PNG width and height in pixels.

    Returns
    -------
    dict
        ``vertices``, ``triangles``, ``dropped_cells``, ``origin`` (list of 3 floats),
        ``crs``, ``vertical_datum`` and ``paths`` (files written).
    """
    targets = {
        "ply": ply_path and check_target(ply_path, (".ply",), "ply_path"),
        "vtp": vtp_path and check_target(vtp_path, (".vtp",), "vtp_path"),
        "png": png_path and check_target(png_path, (".png",), "png_path"),
    }
    if not (np.isscalar(exaggeration) and np.isfinite(exaggeration) and exaggeration > 0):
        raise bad_input("exaggeration", exaggeration, "a positive factor", "e.g. 3.0")
    if len(window_size) != 2 or min(int(v) for v in window_size) < 16:
        raise bad_input("window_size", window_size, "(width, height) >= 16 pixels", "")
    product = read_product(ds)
    mesh = _mesh(product, origin)
    provenance = product.provenance
    paths = []
    if targets["ply"]:
        with atomic_file(targets["ply"]) as tmp:
            _write_ply(tmp, mesh, provenance)
        paths.append(str(targets["ply"]))
    if targets["vtp"] or targets["png"]:
        poly = _polydata(mesh, provenance)
        if targets["vtp"]:
            with atomic_file(targets["vtp"]) as tmp:
                _write_vtp(tmp, poly)
            paths.append(str(targets["vtp"]))
        if targets["png"]:
            title = f"elevation 1-sigma, vertical exaggeration x{exaggeration:g}"
            with atomic_file(targets["png"]) as tmp:
                _render_png(tmp, poly, float(exaggeration), tuple(window_size), title)
            paths.append(str(targets["png"]))
    return {
        "vertices": len(mesh.vertices),
        "triangles": len(mesh.faces),
        "dropped_cells": mesh.dropped_cells,
        "origin": mesh.origin.tolist(),
        "crs": mesh.crs.to_string(),
        "vertical_datum": product.vertical_datum,
        "paths": paths,
    }
