"""Sensor geometry for image simulation (Shin & Park, issue 12): which ray each
image pixel casts.

* :class:`Pushbroom` — a line camera: one focal point per image line and one
  line of detectors, either the user's geometry as it is (``Pushbroom(s, l)``,
  e.g. from SPICE or Orekit) or a built-in Keplerian orbit
  (:meth:`Pushbroom.from_orbit`).
* :class:`FrameCamera` — all pixels from one focal point (airborne, drone).

Every sensor gives its rays a block of lines at a time (:meth:`rays`), so that
a simulation of an image larger than memory never holds all of them.
Positions are ECR (Earth-centred rotating = body-fixed) Cartesian, in the
units of the DSM's semi-major axis (metres for Earth).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Sensor", "Pushbroom", "FrameCamera"]


def _array(v, name: str, shape_tail: tuple, ndim: int) -> np.ndarray:
    try:
        arr = np.asarray(v)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not an array of numbers ({exc})") from None
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"{name}: must be real numbers, got dtype {arr.dtype}")
    arr = np.array(arr, dtype=np.float64)          # a private copy: later edits by the caller change nothing
    if arr.ndim != ndim or arr.shape[ndim - len(shape_tail):] != shape_tail:
        want = "(" + ", ".join(["n"] * (ndim - len(shape_tail)) + [str(t) for t in shape_tail]) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        k = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name}{list(k[:-1])} has NaN or Inf components")
    arr.flags.writeable = False
    return arr


class Sensor:
    """Common interface: ``shape`` = (nlines, npixels); ``rays(k0, k1)`` gives
    the focal points and directions of lines k0..k1-1 as (n, 3) arrays, pixels of
    a line contiguous (row-major in (line, pixel))."""

    shape: tuple[int, int]

    @property
    def nlines(self) -> int:
        return self.shape[0]

    @property
    def npixels(self) -> int:
        return self.shape[1]

    def _check_block(self, k0: int, k1: int) -> tuple[int, int]:
        k0, k1 = int(k0), int(k1)
        if not 0 <= k0 <= k1 <= self.nlines:
            raise ValueError(f"lines {k0}:{k1} outside 0:{self.nlines}")
        return k0, k1

    def rays(self, k0: int = 0, k1: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError


class Pushbroom(Sensor):
    """A pushbroom (line) camera given by the user's geometry, as it is.

    Parameters
    ----------
    s : array (nlines, 3)
        Focal point of each image line, ECR.
    l : array (nlines, npixels, 3)
        Line of sight of each detector of each line, ECR, any non-zero length.
    """

    def __init__(self, s, l):
        self.s = _array(s, "s", (3,), 2)
        self.l = _array(l, "l", (3,), 3)
        if self.l.shape[0] != self.s.shape[0]:
            raise ValueError(f"s has {self.s.shape[0]} lines but l has {self.l.shape[0]}")
        if self.s.shape[0] == 0 or self.l.shape[1] == 0:
            raise ValueError(f"an image needs at least one line and one pixel, got l of shape {self.l.shape}")
        self.shape = (self.l.shape[0], self.l.shape[1])

    def rays(self, k0: int = 0, k1: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        k0, k1 = self._check_block(k0, self.nlines if k1 is None else k1)
        s = np.repeat(self.s[k0:k1], self.npixels, axis=0)
        return s, self.l[k0:k1].reshape(-1, 3)

    def __repr__(self) -> str:
        return f"Pushbroom({self.nlines} lines x {self.npixels} pixels)"


class FrameCamera(Sensor):
    """A frame camera: every pixel's ray starts at one focal point.

    Parameters
    ----------
    position : array (3,)
        Focal point, ECR.
    l : array (nrows, ncols, 3)
        Line of sight of each pixel, ECR, any non-zero length.
    """

    def __init__(self, position, l):
        self.position = _array(np.reshape(position, (1, -1)) if np.ndim(position) == 1 else position,
                               "position", (3,), 2)[0]
        self.l = _array(l, "l", (3,), 3)
        if self.l.shape[0] == 0 or self.l.shape[1] == 0:
            raise ValueError(f"an image needs at least one row and one column, got l of shape {self.l.shape}")
        self.shape = (self.l.shape[0], self.l.shape[1])

    def rays(self, k0: int = 0, k1: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        k0, k1 = self._check_block(k0, self.nlines if k1 is None else k1)
        l = self.l[k0:k1].reshape(-1, 3)
        return np.broadcast_to(self.position, l.shape), l

    def __repr__(self) -> str:
        return f"FrameCamera({self.nlines} x {self.npixels} pixels)"
