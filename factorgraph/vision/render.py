"""Render the grayscale frames a rover's camera sees of a terrain DataArray.

Engine: Open3D ``RaycastingScene`` (Embree BVH) over a triangle mesh of the DEM, in float32 on
origin-subtracted coordinates (the log's local ENU frame, elevations minus their mean); a
whole frame casts a quarter of its rays plus the pixels between triangles and takes the rest
from the triangles' planes (:mod:`.raycast`). The shading is float32 on ground points
relative to the camera centre. Measured (default site, 179k triangles, 640 x 480, one core
pinned with ``taskset``, steady state): 41-46 ms of CPU per frame (61-63 ms before, same
harness; docs/vision.md "Renderer").

Radiance per pixel (Lambert): ``albedo * (E_sun max(n.s, 0) vis + E_sky (1 + n_z) / 2 ao)``
with ``n`` the DEM normal tilted by the sastrugi slopes (:mod:`.albedo`), ``vis`` a sun
visibility raster marched over the DEM once per scene (crevasse and low-sun shadows), ``ao``
a concavity term. Then a fixed exposure (snow in sun ~ 200 DN), shot and read noise, optional
motion blur along the image's vertical (forward driving), 8-bit quantisation.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from terrain.errors import bad_input
from terrain.grid import Grid

from ..sensors import CameraModel
from .albedo import AlbedoParams, GlacierAlbedo, _bilinear
from .raycast import ImageCaster

__all__ = ["SCENES", "VISION_CAMERA", "Renderer", "Scene", "camera_poses", "render_frames"]

#: Camera preset for image-based tracking: 1.5 m mast, 10 deg down, f = 600 px (56 deg
#: horizontal field of view), features to 20 m. Chosen by measurement (15 keyframes at 2 m,
#: sunny snow, SIFT, no CLAHE, guided matching, docs/vision.md): 0.6 m / f 320 / 15 deg
#: tracks 7-9 inliers per pair (the feasibility probe); 1.5 m / f 320 / 20 deg: 25 views per
#: keyframe in >= 3-view tracks, 25 % of views off by > 4 px; 1.5 m / f 600 / 10 deg with
#: the 18 m detection range: 32 views per keyframe, median 0.55 px, none off by > 4 px.
#: ``CameraModel()`` itself is unchanged (the ideal-track default run).
VISION_CAMERA = CameraModel(
    fx_px=600.0, fy_px=600.0, height_m=1.5, pitch_deg=10.0, range_max_m=20.0
)


@dataclass(frozen=True)
class Scene:
    """Illumination, surface and sensor of a rendered scene (irradiances relative)."""

    name: str = "sunny_snow"
    sun_azimuth_deg: float = 150.0  # clockwise from north
    sun_elevation_deg: float = 35.0
    sun_irradiance: float = 1.0  # 0: overcast
    sky_irradiance: float = 0.25
    albedo: AlbedoParams = field(default_factory=AlbedoParams)
    white_dn: float = 200.0  # sunlit snow (albedo 0.85, normal incidence) maps to this DN
    read_noise_dn: float = 1.0
    shot_noise_dn: float = 0.15  # variance per DN (photon noise)
    motion_blur_px: float = 0.0  # vertical line blur length (px), 0: none
    haze_m: float = 3000.0  # extinction length of the far field

    def __post_init__(self) -> None:
        if not -5.0 <= self.sun_elevation_deg <= 90.0:
            raise bad_input("scene.sun_elevation_deg", self.sun_elevation_deg, "in [-5, 90]", "")
        for name in ("sun_irradiance", "sky_irradiance", "read_noise_dn", "shot_noise_dn"):
            if not getattr(self, name) >= 0:
                raise bad_input(f"scene.{name}", getattr(self, name), "a value >= 0", "")
        if not (self.white_dn > 0 and self.motion_blur_px >= 0 and self.haze_m > 0):
            raise bad_input("scene", self.name, "white_dn > 0, blur >= 0, haze > 0", "")


_DIRTY = AlbedoParams(snow_fraction=0.15, dirt_cones_per_100m2=3.0, rocks_per_m2=0.3)
#: The benchmark's scenes: sunny snow (default), sunny dirty ice, overcast snow, low sun.
SCENES = {
    "sunny_snow": Scene(),
    "sunny_dirty_ice": Scene(name="sunny_dirty_ice", albedo=_DIRTY),
    "overcast_snow": Scene(name="overcast_snow", sun_irradiance=0.0, sky_irradiance=1.0),
    "low_sun": Scene(name="low_sun", sun_elevation_deg=8.0, sun_azimuth_deg=200.0),
}


def camera_poses(xyz: np.ndarray, rpy: np.ndarray, camera: CameraModel):
    """World rotations (K, 3, 3) (columns: camera axes) and centres (K, 3) of the camera for
    body poses ``xyz`` (K, 3) (m, local ENU) and ``rpy`` (K, 3) (rad, ZYX body-to-world)."""
    wRb = Rotation.from_euler("ZYX", np.asarray(rpy)[:, ::-1]).as_matrix()
    bTc = camera.body_T_camera()
    return wRb @ bTc[:3, :3], np.asarray(xyz) + wRb @ bTc[:3, 3]


class Renderer:
    """Ray-cast renderer of ``terrain`` (DataArray, projected CRS) around the local rectangle
    ``area`` (west, south, east, north; m in the frame whose origin is ``origin``).

    ``rng`` (a Generator or a seed) draws the albedo. :func:`render_frames` adds ``poses``:
    the camera rotations (K, 3, 3) and centres (K, 3) of the log's true trajectory."""

    def __init__(
        self,
        terrain,
        origin,
        camera: CameraModel,
        scene: Scene | None = None,
        area=None,
        rng=None,
        margin_m: float = 150.0,
    ):
        import open3d as o3d

        self.camera, self.scene = camera, scene or Scene()
        rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        grid = Grid.from_dataarray(terrain)
        z = np.asarray(terrain.values, float)
        x, y = grid.x - origin[0], grid.y - origin[1]
        if y[0] > y[-1]:  # north-up -> south-up rows, so that row index grows with y
            y, z = y[::-1], z[::-1]
        if area is None:
            area = (x[0], y[0], x[-1], y[-1])
        w, s, e, n = area
        cx = (x >= w - margin_m) & (x <= e + margin_m)
        cy = (y >= s - margin_m) & (y <= n + margin_m)
        x, y, z = x[cx], y[cy], z[np.ix_(cy, cx)]
        if z.size < 4 or min(z.shape) < 2:
            raise bad_input("terrain", z.shape, "a DEM around the traverse", "check the extent")
        self.filled_cells = int((~np.isfinite(z)).sum())  # nodata: nearest valid cell
        if self.filled_cells:
            from scipy.ndimage import distance_transform_edt

            if self.filled_cells == z.size:
                raise bad_input("terrain", "all NaN", "elevations around the traverse", "")
            idx = distance_transform_edt(~np.isfinite(z), return_indices=True)[1]
            z = z[tuple(idx)]
        self.x, self.y, self.dx, self.dy = x, y, float(x[1] - x[0]), float(y[1] - y[0])
        self.z0 = float(z.mean())
        ny, nx = z.shape
        X, Y = np.meshgrid(x, y)
        verts = np.column_stack([X.ravel(), Y.ravel(), z.ravel() - self.z0]).astype(np.float32)
        i = (np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]).ravel()
        tris = np.concatenate(
            [np.column_stack([i, i + 1, i + nx]), np.column_stack([i + 1, i + nx + 1, i + nx])]
        ).astype(np.uint32)
        self.rc = o3d.t.geometry.RaycastingScene()
        self.rc.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(tris))
        # whole frames: a quarter of the rays cast, the rest from the triangles' planes
        self.caster = ImageCaster(self.rc, verts, tris, camera.height_px, camera.width_px)
        self.cast_counts = {"cast": 0, "plane": 0}
        gy, gx = np.gradient(z, self.dy, self.dx)
        nrm = np.stack([-gx, -gy, np.ones_like(z)], -1)
        self._normal = (nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)).astype(np.float32)
        lap = np.gradient(gx, self.dx, axis=1) + np.gradient(gy, self.dy, axis=0)
        self._ao = np.clip(1.0 - 0.5 * np.clip(lap, 0, None) * self.dx, 0.3, 1.0)  # concave
        sc = self.scene
        a, el = math.radians(sc.sun_azimuth_deg), math.radians(sc.sun_elevation_deg)
        self.sun = np.array([math.sin(a) * math.cos(el), math.cos(a) * math.cos(el), math.sin(el)])
        self._vis = self._sun_visibility(z)
        # what the shading looks up per pixel, in one 4-channel raster (one remap per frame)
        self._shade = np.dstack([self._normal[..., :2], self._ao, self._vis]).astype(np.float32)
        self.albedo = GlacierAlbedo(area, sc.albedo, rng)
        cam = camera
        u, v = np.meshgrid(np.arange(cam.width_px) + 0.0, np.arange(cam.height_px) + 0.0)
        self._pix = np.column_stack([u.ravel(), v.ravel()])
        dirs = np.column_stack(
            [
                (u.ravel() - cam.cx_px) / cam.fx_px,
                (v.ravel() - cam.cy_px) / cam.fy_px,
                np.ones(u.size),
            ]
        )
        self._dirs = (dirs / np.linalg.norm(dirs, axis=1, keepdims=True)).astype(np.float32)
        self.gain = sc.white_dn / (sc.albedo.snow_albedo * (sc.sun_irradiance + sc.sky_irradiance))

    def _sun_visibility(self, z: np.ndarray) -> np.ndarray:
        """1 where the sun is seen from the DEM cell, 0 in cast shadow (marched once)."""
        from scipy.ndimage import gaussian_filter, map_coordinates

        el = math.radians(self.scene.sun_elevation_deg)
        if self.scene.sun_irradiance == 0 or el >= math.radians(89):
            return np.ones_like(z, np.float32)
        step = min(self.dx, self.dy)
        tan_e = math.tan(max(el, 1e-3))
        reach = min(np.ptp(z) / tan_e, 300.0)  # shadows longer than 300 m are not cast
        n_steps = int(min(400, math.ceil(reach / step) + 1, max(20, 2e8 // z.size)))
        rows, cols = np.mgrid[0 : z.shape[0], 0 : z.shape[1]].astype(float)
        lit = np.ones(z.shape, bool)
        for i in range(1, n_steps + 1):
            d = i * step
            r = rows + d * self.sun[1] / math.cos(el) / self.dy
            c = cols + d * self.sun[0] / math.cos(el) / self.dx
            zz = map_coordinates(z, [r, c], order=1, mode="nearest")
            lit &= zz <= z + d * tan_e + 0.05
        return gaussian_filter(lit.astype(np.float32), 0.7)

    def _raster(self, a: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
        return _bilinear(a, (px - self.x[0]) / self.dx, (py - self.y[0]) / self.dy, False)

    def _cast(self, R: np.ndarray, c: np.ndarray, uv: np.ndarray):
        import open3d as o3d

        cam = self.camera
        if uv is self._pix:
            d = self._dirs @ R.T.astype(np.float32)
            t, n = self.caster.cast(np.asarray(c, float) - [0.0, 0.0, self.z0], d)
            for key, v in n.items():
                self.cast_counts[key] += v
            return d, t
        else:
            d = np.column_stack(
                [
                    (uv[:, 0] - cam.cx_px) / cam.fx_px,
                    (uv[:, 1] - cam.cy_px) / cam.fy_px,
                    np.ones(len(uv)),
                ]
            )
            d = d / np.linalg.norm(d, axis=1, keepdims=True) @ R.T
        rays = np.empty((len(d), 6), np.float32)
        rays[:, :3] = np.asarray(c, float) - [0.0, 0.0, self.z0]
        rays[:, 3:] = d
        t = self.rc.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        return d, t

    def ground_points(self, R: np.ndarray, c: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """World points (n, 3) (local ENU, m) seen through pixels ``uv`` (n, 2) by a camera
        with rotation ``R`` (3, 3) and centre ``c`` (3,); NaN rows for sky."""
        d, t = self._cast(R, c, np.asarray(uv, float).reshape(-1, 2))
        hit = np.isfinite(t)
        out = np.full((len(t), 3), np.nan)
        out[hit] = np.asarray(c) + d[hit] * t[hit, None]
        return out

    def radiance(self, R: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Noise-free image (H, W) in DN (float32) for camera rotation ``R`` and centre ``c``.

        float32 throughout, ground points relative to the camera centre ``c`` (the lookups
        add ``c`` in float64 per frame, :meth:`GlacierAlbedo.sample_near`)."""
        cam, sc = self.camera, self.scene
        f32 = np.float32
        d, t = self._cast(R, c, self._pix)
        # sky everywhere first: brighter toward the horizon; overcast sky and snow alike
        sky_dn = self.gain * (sc.sky_irradiance + 0.6 * sc.sun_irradiance)
        img = np.clip(d[:, 2], 0.0, 1.0)
        img *= f32(-0.3 * sky_dn)
        img += f32(sky_dn)
        idx = np.flatnonzero(np.isfinite(t))
        th = t[idx]
        dh = d[idx]
        dx, dy = dh[:, 0] * th, dh[:, 1] * th  # ground - camera, east / north (m)
        # one 4-channel lookup: normal (x, y), concavity, sun visibility; n_z = the unit
        # normal's third component (DEM normals point up)
        gx, gy = f32((c[0] - self.x[0]) / self.dx), f32((c[1] - self.y[0]) / self.dy)
        col, row = dx * f32(1 / self.dx) + gx, dy * f32(1 / self.dy) + gy  # DEM cells
        shade = _bilinear(self._shade, col, row, False)
        nx, ny = shade[:, 0], shade[:, 1]
        nz = np.sqrt(np.maximum(1.0 - nx * nx - ny * ny, 0.0))
        cos_inc = np.abs(dh[:, 0] * nx + dh[:, 1] * ny + dh[:, 2] * nz)
        fp = th * f32(1 / cam.fx_px) / np.sqrt(np.maximum(cos_inc, f32(0.05)))
        alb, sx, sy = self.albedo.sample_near(dx, dy, (c[0], c[1]), fp)
        nx = nx - sx  # the DEM normal tilted by the sastrugi slopes, then normalised
        ny = ny - sy
        inv = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
        s = self.sun.astype(np.float32)
        light = f32(0.5 * sc.sky_irradiance) * shade[:, 2] * (1.0 + nz * inv)
        if sc.sun_irradiance:
            sun = np.maximum((nx * s[0] + ny * s[1] + nz * s[2]) * inv, 0.0) * shade[:, 3]
            light += f32(sc.sun_irradiance) * sun
        haze = np.exp(th * f32(-1.0 / sc.haze_m))
        ground = alb * light * haze + f32(sc.sky_irradiance) * (1.0 - haze)
        img[idx] = ground * f32(self.gain)
        return img.reshape(cam.height_px, cam.width_px)

    def render(self, R: np.ndarray, c: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One 8-bit frame (H, W): :meth:`radiance` + motion blur + shot/read noise."""
        import cv2

        sc = self.scene
        img = self.radiance(R, c)
        if sc.motion_blur_px >= 1:
            n = int(round(sc.motion_blur_px))
            img = cv2.filter2D(img, -1, np.full((n, 1), 1.0 / n, np.float32))
        sd = np.sqrt(sc.read_noise_dn**2 + sc.shot_noise_dn * np.clip(img, 0, None))
        img = img + sd * rng.standard_normal(img.shape, dtype=np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def render_frames(
    log, terrain, scene: Scene | None = None, seed: int | None = None, keyframes=None
) -> tuple[Renderer, Iterator[tuple[int, np.ndarray]]]:
    """Frames of a simulated log's true trajectory: ``(renderer, iterator of (k, image))``.

    Parameters
    ----------
    log : MeasurementLog
        With truth poses (``truth["xyz"], truth["rpy"]``); its camera model is used.
    terrain : xarray.DataArray
        The true DEM the log was simulated on.
    scene : Scene, optional
        Default :data:`SCENES` ``["sunny_snow"]``.
    seed : int, optional
        Seed of the one generator (albedo, then per-frame noise in keyframe order); default
        the log's seed.
    keyframes : iterable of int, optional
        Subset to render (default all).
    """
    if not log.has_truth:
        raise bad_input("log", "no truth poses", "a simulated log", "use simulate_traverse")
    seed = log.seed if seed is None else seed
    rng = np.random.default_rng(seed)
    cam = log.sensors.camera
    Rs, cs = camera_poses(log.truth["xyz"], log.truth["rpy"], cam)
    reach = cam.range_max_m * 2
    area = (*(cs[:, :2].min(0) - reach), *(cs[:, :2].max(0) + reach))
    area = (area[0], area[1], area[2], area[3])
    ren = Renderer(terrain, log.origin, cam, scene, area=area, rng=rng)
    ks = range(log.n_keyframes) if keyframes is None else [int(k) for k in keyframes]

    def frames():
        for k in ks:
            yield k, ren.render(Rs[k], cs[k], rng)

    ren.poses = (Rs, cs)
    return ren, frames()


def with_camera(sensors, camera: CameraModel = VISION_CAMERA):
    """``sensors`` (SensorSuite) with ``camera`` swapped in (the vision preset by default)."""
    return replace(sensors, camera=camera)
