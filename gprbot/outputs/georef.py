"""Placing the site frame on the earth: WGS84 lon/lat/height and, optionally, a projected (local) CRS.

The site frame is x forward along the survey lines, y left, z up, origin on the surface at the survey's
start. A georeference gives the origin (latitude, longitude, ellipsoidal height, and/or easting,
northing in a named CRS) and the heading: the azimuth of site +x, degrees clockwise from north (grid
north for a projected CRS). Site → east/north is a rotation; east/north/up → WGS84 goes through ECEF
(exact, not a flat-earth approximation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GeoreferenceConfig

_WGS84_A = 6378137.0
_WGS84_F = 1.0 / 298.257223563
_WGS84_E2 = _WGS84_F * (2.0 - _WGS84_F)


@dataclass(frozen=True)
class Georeference:
    """The transform from site coordinates to the earth, built from the config's `georeference` section."""

    config: GeoreferenceConfig

    @property
    def has_wgs84(self) -> bool:
        """Whether the origin's latitude and longitude are known (needed for GeoJSON)."""
        return self.config.origin_lat_deg is not None and self.config.origin_lon_deg is not None

    @property
    def has_projected(self) -> bool:
        """Whether the origin's easting and northing in a named CRS are known."""
        return self.config.crs is not None

    def east_north_up(self, site: NDArray[np.float64]) -> NDArray[np.float64]:
        """Site points (N, 3) as east, north, up offsets (m) from the origin."""
        p = np.atleast_2d(np.asarray(site, dtype=np.float64))
        h = math.radians(self.config.heading_deg)
        x_dir = np.array([math.sin(h), math.cos(h)])  # site +x in (east, north)
        y_dir = np.array([-math.cos(h), math.sin(h)])  # site +y: 90° to the left of +x
        en = p[:, :1] * x_dir + p[:, 1:2] * y_dir
        return np.column_stack([en, p[:, 2]])

    def projected(self, site: NDArray[np.float64]) -> NDArray[np.float64]:
        """Site points (N, 3) as easting, northing, height in the configured CRS (ValueError if none)."""
        if not self.has_projected:
            raise ValueError("georeference: no crs with origin_easting_m / origin_northing_m configured")
        c = self.config
        enu = self.east_north_up(site)
        return np.asarray(enu + np.array([c.origin_easting_m or 0.0, c.origin_northing_m or 0.0, c.origin_height_m]))

    def lon_lat_height(self, site: NDArray[np.float64]) -> NDArray[np.float64]:
        """Site points (N, 3) as WGS84 longitude, latitude (degrees) and ellipsoidal height (m)."""
        if not self.has_wgs84:
            raise ValueError("georeference: origin_lat_deg and origin_lon_deg are not configured")
        c = self.config
        lat0, lon0 = math.radians(float(c.origin_lat_deg or 0.0)), math.radians(float(c.origin_lon_deg or 0.0))
        origin = geodetic_to_ecef(lat0, lon0, c.origin_height_m)
        enu = self.east_north_up(site)
        sl, cl, sp, cp = math.sin(lon0), math.cos(lon0), math.sin(lat0), math.cos(lat0)
        rotation = np.array([[-sl, -sp * cl, cp * cl], [cl, -sp * sl, cp * sl], [0.0, cp, sp]])  # ENU → ECEF
        ecef = origin + enu @ rotation.T
        lat, lon, height = ecef_to_geodetic(ecef)
        return np.column_stack([np.degrees(lon), np.degrees(lat), height])


def geodetic_to_ecef(lat: float, lon: float, height: float) -> NDArray[np.float64]:
    """WGS84 geodetic (radians, m) → ECEF (m)."""
    n = _WGS84_A / math.sqrt(1.0 - _WGS84_E2 * math.sin(lat) ** 2)
    return np.array([(n + height) * math.cos(lat) * math.cos(lon), (n + height) * math.cos(lat) * math.sin(lon),
                     (n * (1.0 - _WGS84_E2) + height) * math.sin(lat)])


def ecef_to_geodetic(ecef: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                          NDArray[np.float64]]:
    """ECEF (N, 3) → WGS84 latitude, longitude (radians), height (m); iterated to well below a millimetre."""
    x, y, z = ecef[:, 0], ecef[:, 1], ecef[:, 2]
    lon = np.arctan2(y, x)
    r = np.hypot(x, y)
    lat = np.arctan2(z, r * (1.0 - _WGS84_E2))
    height = np.zeros_like(lat)
    for _ in range(6):  # converges to < 1e-12 rad in 3–4 iterations near the surface
        n = _WGS84_A / np.sqrt(1.0 - _WGS84_E2 * np.sin(lat) ** 2)
        height = r / np.cos(lat) - n
        lat = np.arctan2(z, r * (1.0 - _WGS84_E2 * n / (n + height)))
    return lat, lon, height
