"""Independent pure-NumPy references for the geodetic DSM surface (issue 11).

Written only from the Shin & Park paper, ``briefs/dsm-contract.md`` and
geometry; nothing here calls planet_intersect's Fortran or its geodetic code.

* ``geodesy``          exact ECEF <-> geodetic conversion (own iteration)
* ``dsm_exhaustive``   fine fixed steps + wall crossings + bisection
* ``box_closed_form``  flat-topped box on the ellipsoid, ellipsoid itself
* ``dsm_scenes``       deterministic building DSMs and labelled rays
* ``sim_closed_form``  image simulation (issue 12): a box building on flat
                       ground, its closed forms (h tan theta) and a two-stage
                       ray caster (tangent plane, then the exact surfaces),
                       written from briefs/sim-contract.md only

Not independent (it guards a translation, not the geometry):

* ``sim_numpy``        the simulation's per-pixel rules in plain NumPy, as
                       they were before the Fortran kernel took them over
"""
