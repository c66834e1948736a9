"""Direct-model image simulation (Shin & Park, issue 12): work in progress on
this commit; the full module follows."""

from __future__ import annotations

__all__ = ["OrthoImage", "SimResult", "simulate_image"]


class OrthoImage:
    """An ortho-image on a geodetic grid (being written)."""


class SimResult:
    """The simulated image and its backplanes (being written)."""


def simulate_image(dsm, ortho, sensor, **kwargs):
    """Simulate an image (being written)."""
    raise NotImplementedError("simulate_image is being written (issue 12)")
