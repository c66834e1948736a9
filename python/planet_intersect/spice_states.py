"""Spacecraft state vectors from the user's SPICE kernels (NAIF SPICE via spiceypy).

The GRS notes ask for R and v "for each spectrum, by the appropriate spice
calls": :func:`state_vectors` loads the kernels (SPK, PCK, frames,
leapseconds, ...), converts the times (UTC strings with ``str2et``, or ET
seconds past J2000 TDB as numbers) and calls ``spkezr(target, et, frame,
abcorr, observer)``. The kernels are unloaded afterwards, so nothing is left
in SPICE's (process-global, not thread-safe) kernel pool.

>>> R, v, et = state_vectors(["2002-05-01T00:00:00"], kernels=["odyssey.bsp", "pck.tpc", "naif0012.tls"])
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["state_vectors", "ODYSSEY_ID"]

#: NAIF ID of Mars Odyssey
ODYSSEY_ID = -53

_ABCORR = ("NONE", "LT", "LT+S", "CN", "CN+S", "XLT", "XLT+S", "XCN", "XCN+S")


def _times(times):
    """Times as a list of str (UTC) or float (ET); a single value becomes one."""
    if isinstance(times, (str, bytes, float, int, np.floating, np.integer)) and not isinstance(times, bool):
        times = [times]
    out = []
    for k, t in enumerate(times):
        if isinstance(t, bytes):
            t = t.decode()
        if isinstance(t, str):
            if not t.strip():
                raise ValueError(f"times[{k}]: empty time string")
            out.append(t.strip())
        elif isinstance(t, (bool, np.bool_)):
            raise ValueError(f"times[{k}]: expected a UTC string or ET seconds, got {t!r}")
        else:
            try:
                x = float(t)
            except (TypeError, ValueError):
                raise ValueError(f"times[{k}]: expected a UTC string or ET seconds, got {t!r}") from None
            if not np.isfinite(x):
                raise ValueError(f"times[{k}]: ET must be finite, got {x}")
            out.append(x)
    if not out:
        raise ValueError("times: no times given")
    return out


def state_vectors(times, kernels=(), target: str | int = "-53", observer: str | int = "MARS",
                  frame: str = "IAU_MARS", abcorr: str = "NONE"):
    """State vectors of ``target`` relative to ``observer`` in ``frame`` at each time.

    Parameters
    ----------
    times : str, float or sequence of them
        UTC strings (any form SPICE's ``str2et`` reads; needs a leapseconds
        kernel) or ephemeris times (TDB seconds past J2000) as numbers.
    kernels : sequence of paths
        Kernels to load for this call (SPK, PCK, FK, LSK, meta-kernels); loaded
        in the given order and unloaded before returning. Kernels the caller
        loaded beforehand stay loaded and are used too.
    target, observer : str or int
        NAIF names or IDs (default ``"-53"``, Mars Odyssey, relative to ``"MARS"``).
    frame : str
        Reference frame of the result (default ``"IAU_MARS"``, the planet-fixed
        frame of the footprint geometry; needs Mars' PCK constants).
    abcorr : str
        Aberration correction for ``spkezr`` ("NONE" default: the geometric
        state, which the footprint geometry wants; "LT", "LT+S", "CN", ...).

    Returns
    -------
    R, v, et : arrays (N, 3), (N, 3), (N,)
        Position (km) and velocity (km/s) in ``frame``, and the ET of each time.

    Raises
    ------
    FileNotFoundError
        A kernel path does not exist.
    ValueError
        A bad time, an unknown abcorr, or any SPICE error (missing data for a
        time, unknown body or frame), with SPICE's own message.
    """
    import spiceypy as sp
    from spiceypy.utils.exceptions import SpiceyError

    if isinstance(kernels, (str, os.PathLike)):
        kernels = [kernels]
    paths = []
    for k in kernels:
        p = Path(k)
        if not p.is_file():
            raise FileNotFoundError(f"SPICE kernel {p}: no such file")
        paths.append(str(p))
    if not isinstance(abcorr, str) or abcorr.strip().upper().replace(" ", "") not in _ABCORR:
        raise ValueError(f"abcorr must be one of {', '.join(_ABCORR)}, got {abcorr!r}")
    abcorr = abcorr.strip().upper().replace(" ", "")
    if not isinstance(frame, str) or not frame.strip():
        raise ValueError(f"frame must be a frame name, got {frame!r}")
    tl = _times(times)
    target, observer = str(target), str(observer)
    loaded = []
    try:
        for p in paths:
            try:
                sp.furnsh(p)
            except SpiceyError as exc:
                raise ValueError(f"SPICE kernel {p}: cannot be loaded ({_short(exc)})") from None
            loaded.append(p)
        et = np.empty(len(tl))
        for k, t in enumerate(tl):
            if isinstance(t, str):
                try:
                    et[k] = sp.str2et(t)
                except SpiceyError as exc:
                    raise ValueError(f"times[{k}] = {t!r}: {_short(exc)}") from None
            else:
                et[k] = t
        states = np.empty((len(tl), 6))
        for k in range(len(tl)):
            try:
                states[k], _ = sp.spkezr(target, et[k], frame, abcorr, observer)
            except SpiceyError as exc:
                raise ValueError(f"spkezr({target}, times[{k}] = {tl[k]!r}, {frame}, {abcorr}, {observer}): "
                                 f"{_short(exc)}") from None
    finally:
        for p in reversed(loaded):
            sp.unload(p)
    return states[:, :3].copy(), states[:, 3:].copy(), et


def _short(exc) -> str:
    """SPICE's short and long messages on one line."""
    text = " ".join(str(exc).split())
    return text[:400]
