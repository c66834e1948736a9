"""planet-intersect: where each pixel of a planetary instrument looks on a rough planet.

A faithful port of N.A. Teanby (2008), "Intersection between spacecraft
viewing vectors and digital elevation models", Computers & Geosciences 34:
ray stepping over a global DEM of radii, hit points and emission angles, and
for limb views the tangent point on the reference spheroid and its altitude
above the local terrain. The core is modern Fortran wrapped with f2py.

>>> import planet_intersect as pi
>>> dem = pi.DEM.read("mars.hdr")
>>> res = pi.intersect(dem, s, l)
"""

from ._status import DEMError, RayStatus, RAY_STATUS
from .dem import DEM, read_header
from .geometry import detector_los, spheroid_radius, ray_spheroid_intersection
from .intersect import IntersectResult, intersect
from . import legacy_config  # link flags of the legacy FORTRAN77 library
from ._ext import core_info  # which compiled core (portable or x86-64-v3) is in use
from .footprint import (CellTable, FootprintResult, airmass, footprint, scale_height,  # GRS footprint
                        spacecraft_frame, spacecraft_quaternion)
from .geodetic import ecef_to_geodetic, geodetic_to_ecef
from .dsm import DSMError, DSMResult, DSMStatus, DSM_RAY_STATUS, GeodeticDSM
from .sensors import FrameCamera, Pushbroom, off_nadir_angle, view_zenith_angle
from .simulate import OrthoImage, SimResult, simulate_image

__version__ = "0.1.0"

__all__ = [
    "DEM", "DEMError", "IntersectResult", "RAY_STATUS", "RayStatus", "detector_los", "intersect",
    "ray_spheroid_intersection", "read_header", "spheroid_radius", "legacy_paths", "core_info",
    "CellTable", "FootprintResult", "airmass", "footprint", "scale_height", "spacecraft_frame",
    "spacecraft_quaternion",
    "GeodeticDSM", "DSMResult", "DSMStatus", "DSMError", "DSM_RAY_STATUS", "ecef_to_geodetic", "geodetic_to_ecef",
    "FrameCamera", "Pushbroom", "off_nadir_angle", "view_zenith_angle", "OrthoImage", "SimResult", "simulate_image",
]


def legacy_paths() -> dict:
    """Installed paths of the legacy library and the ``test_planet_intersect`` driver."""
    from pathlib import Path

    here = Path(__file__).parent
    return {"library": here / "lib" / "libplanet_intersect_legacy.a",
            "driver": here / "bin" / "test_planet_intersect"}
