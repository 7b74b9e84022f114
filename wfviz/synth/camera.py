"""Equidistant fisheye camera model (r = f * theta) with an azimuth/elevation orientation.

World frame: x east, y north, z up (metres or unit directions). Azimuth is measured in
degrees clockwise from north (towards east), elevation in degrees above the horizontal.
Image coordinates: x = column, y = row, origin at the centre of the top-left pixel; the
optical axis images at (cx, cy), image "up" (decreasing y) is the world-up side of the axis
(roll 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np


def az_el_to_dirs(az_deg: np.ndarray | float, el_deg: np.ndarray | float) -> np.ndarray:
    """Unit world directions (..., 3) for azimuth/elevation in degrees."""
    az, el = np.radians(az_deg), np.radians(el_deg)
    return np.stack(np.broadcast_arrays(np.sin(az) * np.cos(el), np.cos(az) * np.cos(el),
                                        np.sin(el)), axis=-1)


def dirs_to_az_el(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(azimuth in [0, 360), elevation) in degrees of world vectors (..., 3) (any length)."""
    d = np.asarray(dirs, dtype=np.float64)
    az = np.degrees(np.arctan2(d[..., 0], d[..., 1])) % 360.0
    el = np.degrees(np.arctan2(d[..., 2], np.hypot(d[..., 0], d[..., 1])))
    return az, el


@dataclass(frozen=True)
class FisheyeCamera:
    """Equidistant fisheye: a direction at angle theta from the axis images at radius f*theta.

    ``fov_deg`` is the full field of view (the imaging circle has radius f * fov/2);
    ``(cx, cy)`` the optical centre in pixels; ``az``/``el`` the optical axis in degrees.
    """

    width: int
    height: int
    fov_deg: float
    cx: float
    cy: float
    f_px: float
    az: float = 0.0
    el: float = 0.0

    @classmethod
    def circular(cls, width: int, height: int, az: float, el: float, fov_deg: float = 180.0,
                 margin: float = 6.0, offset: tuple[float, float] = (0.0, 0.0)) -> FisheyeCamera:
        """A lens whose imaging circle fits inside the frame (dark corners)."""
        radius = min(width, height) / 2.0 - margin
        return cls(width, height, fov_deg, (width - 1) / 2.0 + offset[0],
                   (height - 1) / 2.0 + offset[1], radius / math.radians(fov_deg / 2.0), az, el)

    @classmethod
    def filling(cls, width: int, height: int, fov_deg: float, az: float,
                el: float) -> FisheyeCamera:
        """A lens whose image fills the frame: ``fov_deg`` spans the frame diagonal."""
        radius = math.hypot(width, height) / 2.0
        return cls(width, height, fov_deg, (width - 1) / 2.0, (height - 1) / 2.0,
                   radius / math.radians(fov_deg / 2.0), az, el)

    @property
    def theta_max(self) -> float:
        """Half field of view in radians."""
        return math.radians(self.fov_deg / 2.0)

    @property
    def radius(self) -> float:
        """Imaging-circle radius in pixels (f * theta_max)."""
        return self.f_px * self.theta_max

    @property
    def circle(self) -> tuple[float, float, float] | None:
        """(cx, cy, R) when part of the frame lies outside the imaging circle, else None."""
        corners = [(-0.5, -0.5), (self.width - 0.5, -0.5), (-0.5, self.height - 0.5),
                   (self.width - 0.5, self.height - 0.5)]
        far = max(math.hypot(x - self.cx, y - self.cy) for x, y in corners)
        return None if far <= self.radius else (self.cx, self.cy, self.radius)

    @cached_property
    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World (axis, right, up) unit vectors of the camera (roll 0)."""
        axis = az_el_to_dirs(self.az, self.el)
        a = math.radians(self.az)
        right = np.array([math.cos(a), -math.sin(a), 0.0])
        return axis, right, np.cross(right, axis)

    def project(self, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel (x, y) of world vectors (N, 3) and whether each lies in the field and frame."""
        d = np.atleast_2d(np.asarray(dirs, dtype=np.float64))
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        axis, right, up = self.basis
        theta = np.arccos(np.clip(d @ axis, -1.0, 1.0))
        phi = np.arctan2(d @ up, d @ right)
        x = self.cx + self.f_px * theta * np.cos(phi)
        y = self.cy - self.f_px * theta * np.sin(phi)
        visible = ((theta <= self.theta_max) & (x >= -0.5) & (x <= self.width - 0.5)
                   & (y >= -0.5) & (y <= self.height - 0.5))
        return x, y, visible

    def pixel_to_dir(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Unit world directions (..., 3) imaged at pixel (x, y) (inverse of ``project``)."""
        dx = np.asarray(x, dtype=np.float64) - self.cx
        dy = self.cy - np.asarray(y, dtype=np.float64)
        theta, phi = np.hypot(dx, dy) / self.f_px, np.arctan2(dy, dx)
        axis, right, up = self.basis
        s = np.sin(theta)[..., None]
        return (np.cos(theta)[..., None] * axis + s * np.cos(phi)[..., None] * right
                + s * np.sin(phi)[..., None] * up)

    def off_axis(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(theta in radians, radial image direction in radians) of pixel positions."""
        dx = np.asarray(x, dtype=np.float64) - self.cx
        dy = np.asarray(y, dtype=np.float64) - self.cy
        return np.hypot(dx, dy) / self.f_px, np.arctan2(dy, dx)

    def direction_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """(azimuth, elevation) in degrees of the direction imaged at every pixel centre."""
        ys, xs = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        return dirs_to_az_el(self.pixel_to_dir(xs, ys))

    def coverage(self) -> np.ndarray:
        """Anti-aliased fraction of each pixel inside the imaging circle (float32)."""
        ys, xs = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        r = np.hypot(xs - self.cx, ys - self.cy)
        return np.clip(self.radius + 0.5 - r, 0.0, 1.0).astype(np.float32)

    def horizon(self, n: int = 3601) -> np.ndarray | None:
        """Horizon (elevation 0) polyline (K, 2) of (x, y) inside the field, or None.

        Sampled over azimuth starting opposite the optical axis, so a horizon arc that is
        visible in one piece comes out as one ordered run of points.
        """
        az = self.az + 180.0 + np.linspace(0.0, 360.0, n)
        x, y, vis = self.project(az_el_to_dirs(az, 0.0))
        if vis.sum() < 2:
            return None
        return np.column_stack([x[vis], y[vis]])

    def to_meta(self) -> dict:
        """Camera description for meta.json."""
        return {"projection": "equidistant (r = f*theta)", "fov_deg": self.fov_deg,
                "f_px": self.f_px, "centre": [self.cx, self.cy],
                "orientation": {"azimuth_deg": self.az, "elevation_deg": self.el,
                                "roll_deg": 0.0},
                "width": self.width, "height": self.height}
