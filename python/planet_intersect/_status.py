"""Status codes of the Fortran core and the exceptions they become.

The table mirrors ``fortran/pi_status.f90``; ``tests/test_status.py`` checks
that the compiled codes agree with it.
"""

from __future__ import annotations

__all__ = ["DEMError", "STAT_MESSAGES", "RAY_STATUS", "RayStatus", "raise_for_stat",
           "DSMError", "DSMStatus", "DSM_RAY_STATUS"]


class DEMError(ValueError):
    """A DEM file pair or array is unusable; the message names it and the problem."""


#: routine-level codes (``stat``) and what they mean
STAT_MESSAGES = {
    0: "success",
    1: "the .hdr file cannot be opened or read",
    2: "a header value (ppd, rmax, f, re) is missing or not a number",
    3: "a header 'key = value' line has an unknown key or value",
    4: "the .dem file cannot be opened",
    5: "the .dem file size disagrees with the header",
    6: "a read from the .dem file failed",
    7: "ppd must be an integer >= 1",
    8: "a radius exceeds rmax, or rmax is not positive",
    9: "flattening f must be in [0, 1)",
    10: "equatorial radius re must be positive and finite",
    11: "a radius is NaN, infinite or not positive",
    12: "step_mode, dem_read_mode or tangent mode out of range",
    13: "the radii array shape disagrees with ppd",
    14: "a latitude or longitude is not finite, or a latitude is outside [-90, 90] degrees",
    15: "the computation could not be resolved in floating point",
}


class RayStatus:
    """Per-ray status codes (``IntersectResult.status``)."""

    HIT = 0  #: the ray hits the surface
    LIMB = 1  #: the ray misses and passes the planet: tangent outputs set
    AWAY = 2  #: the ray misses, pointing away from the planet: no tangent point
    HIT_UNCONVERGED = 3  #: hit; refinement stopped at its iteration limit
    BAD_DIRECTION = 4  #: line of sight zero or non-finite
    BAD_POSITION = 5  #: spacecraft position non-finite or at the centre
    INSIDE = 6  #: spacecraft below the DEM surface
    READ_ERROR = 7  #: a DEM record could not be read or is invalid
    UNRESOLVED = 8  #: the ray could not be resolved in floating point; no result given


#: per-ray code -> short description (documented in docs/status-codes.md)
RAY_STATUS = {
    RayStatus.HIT: "hit",
    RayStatus.LIMB: "limb (no hit, tangent point computed)",
    RayStatus.AWAY: "pointing away (no hit, no tangent point)",
    RayStatus.HIT_UNCONVERGED: "hit, refinement not converged to tolerance",
    RayStatus.BAD_DIRECTION: "invalid line of sight",
    RayStatus.BAD_POSITION: "invalid spacecraft position",
    RayStatus.INSIDE: "spacecraft inside the surface",
    RayStatus.READ_ERROR: "DEM record unreadable or invalid",
    RayStatus.UNRESOLVED: "not resolved in floating point (no result)",
}


def raise_for_stat(stat: int, where: str) -> None:
    """Raise :class:`DEMError` (or ValueError for mode errors) for a non-zero ``stat``."""
    if stat == 0:
        return
    message = STAT_MESSAGES.get(int(stat), f"unknown status {stat}")
    if stat in (12, 14):
        raise ValueError(f"{where}: {message}")
    raise DEMError(f"{where}: {message} (status {stat})")


# ---- geodetic DSM system (Shin & Park): appended, the codes above keep their numbers ----

class DSMError(ValueError):
    """A DSM array, grid or file is unusable; the message names it and the problem."""


class DSMStatus:
    """Per-ray status codes of ``DSMResult`` (``intersect`` on a ``GeodeticDSM``).

    0 and 3-6 mean what they mean for a DEM; 9-14 are the DSM's own (8 is the DEM's UNRESOLVED)
    (``fortran/pi_status.f90``: ray_no_data ... ray_step_limit).
    """

    HIT = 0  #: the ray meets the surface: p, lat, lon, height, distance set
    HIT_UNCONVERGED = 3  #: hit; the refinement stopped at its iteration limit (best estimate)
    BAD_DIRECTION = 4  #: line of sight zero or non-finite (rejected by Python before)
    BAD_POSITION = 5  #: focal point non-finite (rejected by Python before)
    INSIDE = 6  #: the focal point is at or below the surface (Python raises ValueError)
    NO_DATA = 9  #: before any hit the ray passes low (h <= H_max) over no-data; event point set
    LEFT_DSM = 10  #: no hit; the ray is low outside the DSM's area; event point = first such point
    MISS = 11  #: the ray never comes down to H_max
    NOT_CONVERGED = 12  #: iterative: no convergence within 100 iterations (last point in p)
    OSCILLATION = 13  #: iterative: a height repeats, it would iterate forever (last point in p)
    STEP_LIMIT = 14  #: step or segment limit reached before an answer


#: DSM per-ray code -> short description (docs/status-codes.md)
DSM_RAY_STATUS = {
    DSMStatus.HIT: "hit",
    DSMStatus.HIT_UNCONVERGED: "hit, refinement not converged to tolerance",
    DSMStatus.BAD_DIRECTION: "invalid line of sight",
    DSMStatus.BAD_POSITION: "invalid focal point",
    DSMStatus.INSIDE: "focal point at or below the surface",
    DSMStatus.NO_DATA: "no data where the ray could first hit",
    DSMStatus.LEFT_DSM: "left the DSM (or never entered it) without hitting",
    DSMStatus.MISS: "passes above the DSM (never below H_max)",
    DSMStatus.NOT_CONVERGED: "iterative ray tracing did not converge",
    DSMStatus.OSCILLATION: "iterative ray tracing oscillates (endless iteration)",
    DSMStatus.STEP_LIMIT: "step limit reached",
}
