"""Golden outputs of the paper's two Mars examples on the MOLA 4 ppd radius grid.

``python tests/golden.py`` records them (once verified) into data/golden/;
tests/test_mola_examples.py compares every run against them within 1e-9 relative.
"""

from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
GOLDEN = REPO / "data" / "golden"
MOLA_RADIUS = ("mars_mola_megdr_4ppd", "mars_radius_4ppd_megt_plus_areoid.i2be")


def olympus_fields(ex):
    """Every 7th pixel of example 1: enough to pin the geometry, small to commit."""
    r = ex.res
    sel = slice(None, None, 7)
    return {"lat": r.lat[sel], "lon": r.lon[sel], "radius": r.radius[sel], "emission": r.emission[sel],
            "status": r.status[sel].astype(np.int64), "T0_fit": np.array(ex.T0_fit), "lapse_fit": np.array(ex.lapse_fit)}


def limb_fields(ex):
    r = ex.res
    return {"status": r.status.astype(np.int64), "radius": r.radius, "tangent_lat": r.tangent_lat,
            "tangent_height": r.tangent_height, "tangent_altitude": r.tangent_altitude}


def main():
    import os
    from planet_intersect.examples import limb, olympus
    from planet_intersect.mola import mola_dem

    data = Path(os.environ.get("PI_SHARED_DATA", REPO.parent / "shared" / "data"))
    dem = mola_dem(data.joinpath(*MOLA_RADIUS))
    GOLDEN.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(GOLDEN / "olympus_mola4.npz", **olympus_fields(olympus(dem)))
    np.savez_compressed(GOLDEN / "limb_mola4.npz", **limb_fields(limb(dem)))
    print("wrote", *sorted(p.name for p in GOLDEN.glob("*.npz")))


if __name__ == "__main__":
    main()
