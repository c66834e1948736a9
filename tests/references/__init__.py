"""Independent pure-NumPy references for the geodetic DSM surface (issue 11).

Written only from the Shin & Park paper, ``briefs/dsm-contract.md`` and
geometry; nothing here calls planet_intersect's Fortran or its geodetic code.

* ``geodesy``          exact ECEF <-> geodetic conversion (own iteration)
* ``dsm_exhaustive``   fine fixed steps + wall crossings + bisection
* ``box_closed_form``  flat-topped box on the ellipsoid, ellipsoid itself
* ``dsm_scenes``       deterministic building DSMs and labelled rays
"""
