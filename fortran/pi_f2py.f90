!> The flat boundary that f2py wraps (described by `_core.pyf`): plain arrays,
!> scalars and a path string, no derived types. Python calls these through
!> `planet_intersect._core`; users call the Python API instead.
!>
!> Angles are radians. Per-ray scalars are packed in `scal(9, n)`:
!>   1 lat, 2 lon, 3 radius, 4 altitude, 5 emission (hits);
!>   6 tangent_lat, 7 tangent_lon, 8 tangent_altitude, 9 tangent_height (limb rays).

!> Intersect n rays with a DEM held in memory (dem_read_mode 0). See
!> pi_intersect::intersect_ray for the algorithm and outputs.
subroutine core_intersect_grid(nlon, nlat, radii, ppd, rmax, f, re, n, s, l, step_mode, &
                               tangent_mode, threads, method, npyr, pyr_data, nlev, pyr_meta, &
                               p, t, tc, sc, scal, status, nsteps, stat)
  use pi_kinds, only: dp, sp
  use pi_dem, only: dem_t, dem_attach
  use pi_status, only: stat_ok
  use pi_intersect, only: intersect_packed
  use pi_exact, only: pyramid_t, pyramid_attach
  implicit none
  integer, intent(in) :: nlon, nlat, ppd, n, step_mode, tangent_mode, threads, method, npyr, nlev
  real(sp), intent(in), target :: pyr_data(npyr)
  integer, intent(in) :: pyr_meta(3, nlev)
  real(dp), intent(in), target :: radii(nlon, nlat)
  real(dp), intent(in) :: rmax, f, re, s(3, n), l(3, n)
  real(dp), intent(out) :: p(3, n), t(3, n), tc(3, n), sc(3, n), scal(9, n)
  integer, intent(out) :: status(n), nsteps(n), stat
  type(dem_t) :: dem
  type(pyramid_t) :: pyr
  call pyramid_attach(pyr_data, pyr_meta, pyr)
  call dem_attach(radii, ppd, rmax, f, re, dem, stat)
  if (stat /= stat_ok) then
    p = 0.0_dp; t = 0.0_dp; tc = 0.0_dp; sc = 0.0_dp; scal = 0.0_dp
    status = -1; nsteps = 0
    return
  end if
  call intersect_packed(dem, n, s, l, step_mode, tangent_mode, p, t, tc, sc, scal, status, nsteps, stat, &
                        threads, method, pyr)
end subroutine core_intersect_grid

!> Intersect n rays with the DEM file pair `path` (NAME, NAME.hdr or NAME.dem)
!> read by Fortran in dem_read_mode 0 (whole grid) or 1 (record by record).
!> The header values (ppd, rmax, f, re, itemsize, swap = 1 when the file's
!> byte order is not the machine's) come from the caller, which parsed and
!> checked the `.hdr` (one parser for both storage modes: issue 10).
subroutine core_intersect_file(path, read_mode, ppd, rmax, f, re, itemsize, swap, n, s, l, step_mode, &
                               tangent_mode, threads, method, use_map, npyr, pyr_data, nlev, pyr_meta, &
                               p, t, tc, sc, scal, status, nsteps, stat)
  use pi_kinds, only: dp, sp
  use pi_dem, only: dem_t, dem_header_t, dem_open, dem_close
  use pi_status, only: stat_ok
  use pi_intersect, only: intersect_packed
  use pi_exact, only: pyramid_t, pyramid_attach
  implicit none
  character(len=*), intent(in) :: path
  integer, intent(in) :: read_mode, ppd, itemsize, swap
  real(dp), intent(in) :: rmax, f, re
  integer, intent(in) :: n, step_mode, tangent_mode, threads, method, use_map, npyr, nlev
  real(sp), intent(in), target :: pyr_data(npyr)
  integer, intent(in) :: pyr_meta(3, nlev)
  real(dp), intent(in) :: s(3, n), l(3, n)
  real(dp), intent(out) :: p(3, n), t(3, n), tc(3, n), sc(3, n), scal(9, n)
  integer, intent(out) :: status(n), nsteps(n), stat
  type(dem_t) :: dem
  type(pyramid_t) :: pyr
  p = 0.0_dp; t = 0.0_dp; tc = 0.0_dp; sc = 0.0_dp; scal = 0.0_dp
  status = -1; nsteps = 0
  call pyramid_attach(pyr_data, pyr_meta, pyr)
  call dem_open(path, read_mode, dem, stat, use_map=use_map /= 0, &
                header=dem_header_t(ppd=ppd, itemsize=itemsize, rmax=rmax, f=f, re=re, swap=swap /= 0))
  if (stat /= stat_ok) return
  call intersect_packed(dem, n, s, l, step_mode, tangent_mode, p, t, tc, sc, scal, status, nsteps, stat, &
                        threads, method, pyr)
  call dem_close(dem)
end subroutine core_intersect_file

!> The polar means (south, north) of a memory-mapped `.dem` file's grid, as
!> dem_attach_map computes them, for core_intersect_mapped's `poles`.
subroutine core_map_poles(nbytes, bytes, itemsize, ppd, rmax, f, re, poles, stat)
  use, intrinsic :: iso_c_binding, only: c_loc, c_int8_t
  use pi_kinds, only: dp, i8
  use pi_dem, only: dem_t, dem_attach_map
  implicit none
  integer(i8), intent(in) :: nbytes
  integer(c_int8_t), intent(in), target :: bytes(nbytes)
  integer, intent(in) :: itemsize, ppd
  real(dp), intent(in) :: rmax, f, re
  real(dp), intent(out) :: poles(2)
  integer, intent(out) :: stat
  type(dem_t) :: dem
  poles = 0.0_dp
  call dem_attach_map(c_loc(bytes), nbytes, itemsize, ppd, rmax, f, re, dem, stat)
  poles = [dem%pole_south, dem%pole_north]
end subroutine core_map_poles

!> As core_intersect_file with use_map, on the caller's own read-only memory map
!> of the `.dem` file (native byte order), passed as its bytes: the map outlives
!> the call, so the pages it has brought in are not faulted in again. poles:
!> the map's polar means from core_map_poles (the polar rows are not re-read).
subroutine core_intersect_mapped(nbytes, bytes, itemsize, ppd, rmax, f, re, poles, n, s, l, step_mode, &
                                 tangent_mode, threads, method, npyr, pyr_data, nlev, pyr_meta, &
                                 p, t, tc, sc, scal, status, nsteps, stat)
  use, intrinsic :: iso_c_binding, only: c_loc, c_int8_t
  use pi_kinds, only: dp, sp, i8
  use pi_dem, only: dem_t, dem_attach_map
  use pi_status, only: stat_ok
  use pi_intersect, only: intersect_packed
  use pi_exact, only: pyramid_t, pyramid_attach
  implicit none
  integer(i8), intent(in) :: nbytes
  integer(c_int8_t), intent(in), target :: bytes(nbytes)
  integer, intent(in) :: itemsize, ppd, n, step_mode, tangent_mode, threads, method, npyr, nlev
  real(sp), intent(in), target :: pyr_data(npyr)
  integer, intent(in) :: pyr_meta(3, nlev)
  real(dp), intent(in) :: rmax, f, re, poles(2), s(3, n), l(3, n)
  real(dp), intent(out) :: p(3, n), t(3, n), tc(3, n), sc(3, n), scal(9, n)
  integer, intent(out) :: status(n), nsteps(n), stat
  type(dem_t) :: dem
  type(pyramid_t) :: pyr
  p = 0.0_dp; t = 0.0_dp; tc = 0.0_dp; sc = 0.0_dp; scal = 0.0_dp
  status = -1; nsteps = 0
  call pyramid_attach(pyr_data, pyr_meta, pyr)
  call dem_attach_map(c_loc(bytes), nbytes, itemsize, ppd, rmax, f, re, dem, stat, poles)
  if (stat /= stat_ok) return
  call intersect_packed(dem, n, s, l, step_mode, tangent_mode, p, t, tc, sc, scal, status, nsteps, stat, &
                        threads, method, pyr)
end subroutine core_intersect_mapped

!> DEM radius (eqs. 2-12) at n points (radians) of a grid held in memory.
subroutine core_radius_grid(nlon, nlat, radii, ppd, rmax, n, lat, lon, r, stat)
  use pi_kinds, only: dp
  use pi_dem, only: dem_t, dem_attach, dem_radius
  use pi_status, only: stat_ok
  implicit none
  integer, intent(in) :: nlon, nlat, ppd, n
  real(dp), intent(in), target :: radii(nlon, nlat)
  real(dp), intent(in) :: rmax, lat(n), lon(n)
  real(dp), intent(out) :: r(n)
  integer, intent(out) :: stat
  type(dem_t) :: dem
  integer :: k
  r = 0.0_dp
  call dem_attach(radii, ppd, rmax, 0.0_dp, 1.0_dp, dem, stat)
  if (stat /= stat_ok) return
  do k = 1, n
    call dem_radius(dem, lat(k), lon(k), r(k), stat)
  end do
end subroutine core_radius_grid

!> DEM radius (eqs. 2-12) at n points (radians) read from the file pair `path`,
!> with the header values from the caller (as core_intersect_file).
subroutine core_radius_file(path, read_mode, ppd, rmax, f, re, itemsize, swap, n, lat, lon, r, stat)
  use pi_kinds, only: dp
  use pi_dem, only: dem_t, dem_header_t, dem_open, dem_close, dem_radius
  use pi_status, only: stat_ok
  implicit none
  character(len=*), intent(in) :: path
  integer, intent(in) :: read_mode, ppd, itemsize, swap, n
  real(dp), intent(in) :: rmax, f, re
  real(dp), intent(in) :: lat(n), lon(n)
  real(dp), intent(out) :: r(n)
  integer, intent(out) :: stat
  type(dem_t) :: dem
  integer :: k
  r = 0.0_dp
  call dem_open(path, read_mode, dem, stat, &
                header=dem_header_t(ppd=ppd, itemsize=itemsize, rmax=rmax, f=f, re=re, swap=swap /= 0))
  if (stat /= stat_ok) return
  do k = 1, n
    call dem_radius(dem, lat(k), lon(k), r(k), stat)
    if (stat /= stat_ok) exit
  end do
  call dem_close(dem)
end subroutine core_radius_file

!> Header values of a `.hdr` file as the Fortran reader sees them.
subroutine core_read_header(path, ppd, rmax, f, re, itemsize, swap, stat)
  use pi_kinds, only: dp
  use pi_dem, only: dem_read_header, dem_paths
  implicit none
  character(len=*), intent(in) :: path
  integer, intent(out) :: ppd, itemsize, swap, stat
  real(dp), intent(out) :: rmax, f, re
  character(len=:), allocatable :: hdr, dem
  logical :: lswap
  call dem_paths(path, hdr, dem)
  call dem_read_header(hdr, ppd, rmax, f, re, itemsize, lswap, stat)
  swap = merge(1, 0, lswap)
end subroutine core_read_header

!> Tangent point of n lines on the spheroid (f, re): mode 0 paper, 1 exact.
subroutine core_tangent(n, s, l, f, re, mode, tc, sc, d)
  use pi_kinds, only: dp
  use pi_vector, only: unit_vector
  use pi_spheroid, only: tangent_spheroid
  implicit none
  integer, intent(in) :: n, mode
  real(dp), intent(in) :: s(3, n), l(3, n), f, re
  real(dp), intent(out) :: tc(3, n), sc(3, n), d(n)
  integer :: k
  do k = 1, n
    call tangent_spheroid(s(:, k), unit_vector(l(:, k)), f, re, mode, tc(:, k), sc(:, k), d(k))
  end do
end subroutine core_tangent

!> The status-code table as compiled, so Python can check that its copy agrees.
subroutine core_codes(codes)
  use pi_status
  implicit none
  integer, intent(out) :: codes(25)
  codes = [stat_ok, stat_hdr_open, stat_hdr_value, stat_hdr_key, stat_dem_open, stat_dem_size, &
           stat_dem_read, stat_bad_ppd, stat_bad_rmax, stat_bad_f, stat_bad_re, stat_bad_radii, &
           stat_bad_mode, stat_bad_shape, stat_bad_coord, stat_unresolved, ray_hit, ray_limb, ray_away, &
           ray_hit_unconverged, ray_bad_direction, ray_bad_position, ray_inside, ray_read_error, &
           ray_unresolved]
end subroutine core_codes

! ============================================================================
! Footprint geometry (Mars Odyssey GRS notes, issue 13): pi_footprint.
! Python: planet_intersect.footprint. Cells and spectra as in pi_footprint.
! ============================================================================

!> Footprint cell count per spectrum (first pass). See pi_footprint::footprint_count.
subroutine core_footprint_count(ns, r, zeta, nrow, ncol, cd, nc, u, rc, rmin, rtop, threads, counts, status, stat)
  use pi_kinds, only: dp, i8
  use pi_footprint, only: footprint_count
  implicit none
  integer, intent(in) :: ns, nrow, ncol, nc, threads
  real(dp), intent(in) :: r(3, ns), zeta(ns), cd, u(3, nc), rc(nc), rmin, rtop
  integer(i8), intent(out) :: counts(ns)
  integer, intent(out) :: status(ns), stat
  call footprint_count(ns, r, zeta, nrow, ncol, cd, nc, u, rc, rmin, rtop, threads, counts, status, stat)
end subroutine core_footprint_count

!> Footprint pairs and their geometry (second pass). See pi_footprint::footprint_fill.
!> idx, d, gsh, scal are the caller's arrays (intent(inout) in _core.pyf), filled
!> in place: f2py would otherwise zero-fill fresh intent(out) arrays, a whole
!> extra pass over 128 bytes per pair.
subroutine core_footprint_fill(ns, r, frames, zeta, nrow, ncol, cd, nc, u, rc, rmin, rtop, ndet, snorm, area, &
                               ascale, offsets, m, threads, idx, d, gsh, scal, status, stat)
  use pi_kinds, only: dp, i8
  use pi_footprint, only: footprint_fill
  implicit none
  integer, intent(in) :: ns, nrow, ncol, nc, threads
  integer(i8), intent(in) :: m, offsets(ns)
  real(dp), intent(in) :: r(3, ns), frames(3, 3, ns), zeta(ns), cd, u(3, nc), rc(nc), rmin, rtop, &
                          ndet(3, nc), snorm(3, nc), area, ascale
  integer, intent(inout) :: idx(m, 2)
  integer, intent(out) :: status(ns), stat
  real(dp), intent(inout) :: d(3, m), gsh(3, m), scal(m, 9)
  call footprint_fill(ns, r, frames, zeta, nrow, ncol, cd, nc, u, rc, rmin, rtop, ndet, snorm, area, &
                      ascale, offsets, m, threads, idx, d, gsh, scal, status, stat)
end subroutine core_footprint_fill

!> The footprint status codes as compiled (fp_ok, fp_bad_position, fp_inside,
!> fp_bad_cells, fp_bad_offsets), so Python can check that its copy agrees.
subroutine core_footprint_codes(codes)
  use pi_footprint, only: fp_ok, fp_bad_position, fp_inside, fp_bad_cells, fp_bad_offsets
  implicit none
  integer, intent(out) :: codes(5)
  codes = [fp_ok, fp_bad_position, fp_inside, fp_bad_cells, fp_bad_offsets]
end subroutine core_footprint_codes

! ============================================================================
! Geodetic DSM system (Shin & Park): conversions, DSM heights, ray tracing.
! Angles radians, lengths in the units of a. Grids are hgt(ncols, nrows), the
! transpose of Python's heights[nrows, ncols] (no copy).
! ============================================================================

!> ECR -> geodetic for n points p(3, n): mode 0 exact, 1 Bowring (eq. 2 as
!> Dana gives it), 2 eq. 2 as printed. lat, lon (radians), h.
subroutine core_ecr_to_geodetic(n, p, a, f, mode, lat, lon, h)
  use pi_kinds, only: dp
  use pi_geodetic, only: ecr_to_geodetic, ecr_to_geodetic_bowring, ecr_to_geodetic_printed
  implicit none
  integer, intent(in) :: n, mode
  real(dp), intent(in) :: p(3, n), a, f
  real(dp), intent(out) :: lat(n), lon(n), h(n)
  if (mode == 1) then
    call ecr_to_geodetic_bowring(p(1, :), p(2, :), p(3, :), a, f, lat, lon, h)
  else if (mode == 2) then
    call ecr_to_geodetic_printed(p(1, :), p(2, :), p(3, :), a, f, lat, lon, h)
  else
    call ecr_to_geodetic(p(1, :), p(2, :), p(3, :), a, f, lat, lon, h)
  end if
end subroutine core_ecr_to_geodetic

!> ECR -> geodetic for n points p(3, n) by pi_geodetic's ecr_to_geodetic_near
!> with the reference (lat_r, lon_r) (radians; its normal computed here) and the
!> height estimate h_est (units of a), as the exact DSM mode's first conversion
!> of a ray uses it (the DSM's centre, the slab's middle): for tests of that use
!> against the exact conversion. lat, lon (radians), h.
subroutine core_ecr_to_geodetic_near(n, p, a, f, lat_r, lon_r, h_est, lat, lon, h)
  use pi_kinds, only: dp
  use pi_geodetic, only: ecr_to_geodetic_near
  implicit none
  integer, intent(in) :: n
  real(dp), intent(in) :: p(3, n), a, f, lat_r, lon_r, h_est
  real(dp), intent(out) :: lat(n), lon(n), h(n)
  real(dp) :: nx(n), ny(n), nz(n)
  call ecr_to_geodetic_near(p(1, :), p(2, :), p(3, :), a, f, lat_r, lon_r, cos(lat_r) * cos(lon_r), &
                            cos(lat_r) * sin(lon_r), sin(lat_r), h_est, lat, lon, h, nx, ny, nz)
end subroutine core_ecr_to_geodetic_near

!> Geodetic (lat, lon radians, h) -> ECR p(3, n).
subroutine core_geodetic_to_ecr(n, lat, lon, h, a, f, p)
  use pi_kinds, only: dp
  use pi_geodetic, only: geodetic_to_ecr
  implicit none
  integer, intent(in) :: n
  real(dp), intent(in) :: lat(n), lon(n), h(n), a, f
  real(dp), intent(out) :: p(3, n)
  call geodetic_to_ecr(lat, lon, h, a, f, p(1, :), p(2, :), p(3, :))
end subroutine core_geodetic_to_ecr

!> DSM surface height at n points (lat, lon radians); code 0 over data,
!> 1 outside the defined area, 2 no data (hs NaN then).
subroutine core_dsm_height(ncols, nrows, hgt, lat0, lon0, dlat, dlon, a, f, interp, n, lat, lon, hs, code)
  use pi_kinds, only: dp
  use pi_dsm, only: dsm_t, dsm_attach, dsm_height
  implicit none
  integer, intent(in) :: ncols, nrows, interp, n
  real(dp), intent(in), target :: hgt(ncols, nrows)
  real(dp), intent(in) :: lat0, lon0, dlat, dlon, a, f, lat(n), lon(n)
  real(dp), intent(out) :: hs(n)
  integer, intent(out) :: code(n)
  real(dp), target :: nopyr(1)
  integer, target :: nometa(3, 1)
  type(dsm_t) :: dsm
  integer :: k
  nopyr = 0.0_dp
  nometa = 1
  call dsm_attach(hgt, lat0, lon0, dlat, dlon, a, f, interp, 0.0_dp, 0.0_dp, nopyr, nometa, dsm)
  do k = 1, n
    call dsm_height(dsm, lat(k), lon(k), hs(k), code(k))
  end do
end subroutine core_dsm_height

!> Trace n rays over the DSM: method 0 following (Shin & Park), 1 exact,
!> 2 iterative. pyr/meta: the max-pyramid (dsm.py). Outputs as
!> pi_dsm_exact::dsm_trace_packed.
subroutine core_dsm_trace(ncols, nrows, hgt, lat0, lon0, dlat, dlon, a, f, interp, hmax, hmin, &
                          npyr, pyr, nlev, meta, n, s, l, method, threads, p, q, scal, status, nsteps, stat, fan)
  use pi_kinds, only: dp
  use pi_dsm, only: dsm_t, dsm_attach
  use pi_dsm_exact, only: dsm_trace_packed
  implicit none
  integer, intent(in) :: ncols, nrows, interp, npyr, nlev, n, method, threads, fan
  real(dp), intent(in), target :: hgt(ncols, nrows), pyr(npyr)
  integer, intent(in), target :: meta(3, nlev)
  real(dp), intent(in) :: lat0, lon0, dlat, dlon, a, f, hmax, hmin, s(3, n), l(3, n)
  real(dp), intent(out) :: p(3, n), q(3, n), scal(10, n)
  integer, intent(out) :: status(n), nsteps(n), stat
  type(dsm_t) :: dsm
  call dsm_attach(hgt, lat0, lon0, dlat, dlon, a, f, interp, hmax, hmin, pyr, meta, dsm)
  call dsm_trace_packed(dsm, n, s, l, method, threads, p, q, scal, status, nsteps, stat, fan)
end subroutine core_dsm_trace

!> The line sweep alone (tests): certified clear distances rclear(n) of rays
!> in consecutive groups of fan sharing one focal point (groups whose focal
!> points differ get 0), pi_dsm_sweep::sweep_fans, as core_dsm_trace runs it.
!> Grid as core_dsm_trace.
subroutine core_dsm_sweep(ncols, nrows, hgt, lat0, lon0, dlat, dlon, a, f, interp, hmax, hmin, &
                          npyr, pyr, nlev, meta, n, s, l, fan, rclear)
  use pi_kinds, only: dp
  use pi_dsm, only: dsm_t, dsm_attach
  use pi_dsm_sweep, only: sweep_fans
  implicit none
  integer, intent(in) :: ncols, nrows, interp, npyr, nlev, n, fan
  real(dp), intent(in), target :: hgt(ncols, nrows), pyr(npyr)
  integer, intent(in), target :: meta(3, nlev)
  real(dp), intent(in) :: lat0, lon0, dlat, dlon, a, f, hmax, hmin, s(3, n), l(3, n)
  real(dp), intent(out) :: rclear(n)
  type(dsm_t) :: dsm
  call dsm_attach(hgt, lat0, lon0, dlat, dlon, a, f, interp, hmax, hmin, pyr, meta, dsm)
  call sweep_fans(dsm, n, s, l, fan, 1, rclear)
end subroutine core_dsm_sweep

!> The order in which core_dsm_trace traces n rays (tests):
!> pi_ray_order::ray_order, order(n) 1-based, sorted 1 when the rays were
!> sorted (0: the given order kept). Grid as core_dsm_trace (only its
!> spacing, ellipsoid and heights are used).
subroutine core_ray_order(ncols, nrows, hgt, lat0, lon0, dlat, dlon, a, f, interp, hmax, hmin, &
                          n, s, l, order, sorted)
  use pi_kinds, only: dp
  use pi_dsm, only: dsm_t, dsm_attach
  use pi_ray_order, only: ray_order
  implicit none
  integer, intent(in) :: ncols, nrows, interp, n
  real(dp), intent(in), target :: hgt(ncols, nrows)
  real(dp), intent(in) :: lat0, lon0, dlat, dlon, a, f, hmax, hmin, s(3, n), l(3, n)
  integer, intent(out) :: order(n), sorted
  real(dp), target :: nopyr(1)
  integer, target :: nometa(3, 1)
  type(dsm_t) :: dsm
  logical :: srt
  nopyr = 0.0_dp
  nometa = 1
  call dsm_attach(hgt, lat0, lon0, dlat, dlon, a, f, interp, hmax, hmin, nopyr, nometa, dsm)
  call ray_order(dsm, n, s, l, order, srt)
  sorted = merge(1, 0, srt)
end subroutine core_ray_order

!> pi_dsm's ulp (spacing read off the exponent bits, in the exact mode's box bounds) for the
!> tests, which compare it with NumPy's spacing.
subroutine core_ulp(n, x, s)
  use pi_kinds, only: dp
  use pi_dsm, only: ulp
  implicit none
  integer, intent(in) :: n
  real(dp), intent(in) :: x(n)
  real(dp), intent(out) :: s(n)
  s = ulp(x)
end subroutine core_ulp

!> The DSM per-ray codes as compiled (no_data, left_dsm, dsm_miss,
!> not_converged, oscillation, step_limit), for Python's table check.
subroutine core_dsm_codes(codes)
  use pi_status
  implicit none
  integer, intent(out) :: codes(6)
  codes = [ray_no_data, ray_left_dsm, ray_dsm_miss, ray_not_converged, ray_oscillation, ray_step_limit]
end subroutine core_dsm_codes

! ======================================================================
! Image simulation (Shin & Park section 4; issue 12)
! ======================================================================

!> Values, surface kinds and local incidence angles of n simulated pixels
!> from their rays' hits, and their backplanes (pi_simulate::sim_shade),
!> written in place into the caller's arrays (a block of the simulation's
!> output arrays, memory-mapped or not). DSM grid as core_dsm_height;
!> gnd(ncols, nrows) bare-earth heights; ortho(nb, ocols, orows) on its grid
!> (olat0, olon0, odlat, odlon, radians); scal(ns, n), ns >= 6, and p(3, n)
!> the rays' hits as core_dsm_trace returns them (passed whole so that rows
!> are not copied), hit (1 = hit), l(3, n) unit directions; walls 0
!> interpolate / 1 ortho; shading 0 none / 1 Lambert; sunmode 0 (azimuth,
!> elevation in radians in sun(1:2)) / 1 ECR unit vector.
!> In/out (every element written): img(nb, n) float32 values, kind(n) int8
!> (-1 none, 0 ground, 1 roof, 2 wall), locinc(n), lat(n), lon(n), inc(n)
!> (degrees; lon not wrapped), hgt(n), dist(n), pts(3, n), NaN where not hit; oval(n) int8
!> (1: a hit with an ortho value there).
subroutine core_sim_shade(ncols, nrows, hgt, lat0, lon0, dlat, dlon, a, f, interp, gnd, nb, ocols, orows, &
                          ortho, olat0, olon0, odlat, odlon, ns, n, scal, p, hit, l, walls, shading, &
                          sunmode, sun, ambient, cos_wall, roof_min, cell_x, cell_y, fill, threads, img, kind, &
                          locinc, lat, lon, height, dist, inc, pts, oval)
  use pi_kinds, only: dp, sp, i1
  use pi_dsm, only: dsm_t, dsm_attach
  use pi_simulate, only: ortho_t, sim_options_t, sim_shade
  use pi_ieee, only: nan_dp
  implicit none
  integer, intent(in) :: ncols, nrows, interp, nb, ocols, orows, ns, n, walls, shading, sunmode, threads
  real(dp), intent(in), target :: hgt(ncols, nrows), ortho(nb, ocols, orows)
  real(dp), intent(in) :: gnd(ncols, nrows)
  real(dp), intent(in) :: lat0, lon0, dlat, dlon, a, f, olat0, olon0, odlat, odlon
  real(dp), intent(in) :: scal(ns, n), p(3, n), l(3, n), sun(3), ambient, cos_wall, roof_min
  real(dp), intent(in) :: cell_x, cell_y, fill
  integer, intent(in) :: hit(n)
  real(sp), intent(inout) :: img(nb, n)
  integer(i1), intent(inout) :: kind(n), oval(n)
  real(dp), intent(inout) :: locinc(n), lat(n), lon(n), height(n), dist(n), inc(n), pts(3, n)
  real(dp), target :: nopyr(1)
  integer, target :: nometa(3, 1)
  type(dsm_t) :: dsm
  type(ortho_t) :: o
  type(sim_options_t) :: opt
  nopyr = 0.0_dp
  nometa = 1
  call dsm_attach(hgt, lat0, lon0, dlat, dlon, a, f, interp, 0.0_dp, 0.0_dp, nopyr, nometa, dsm)
  o%v => ortho
  o%nb = nb
  o%ncols = ocols
  o%nrows = orows
  o%lat0 = olat0
  o%lon0 = olon0
  o%dlat = odlat
  o%dlon = odlon
  o%lonc = olon0 + 0.5_dp * (ocols - 1) * odlon
  opt%walls = walls
  opt%shading = shading
  opt%sun_mode = sunmode
  opt%sun = sun
  opt%ambient = ambient
  opt%cos_wall = cos_wall
  opt%roof_min = roof_min
  opt%cell_x = cell_x
  opt%cell_y = cell_y
  opt%fill = fill
  if (ns < 6) then                                   ! (the wrapper checks it; nothing to read otherwise)
    img = real(fill, sp)
    kind = -1_i1
    oval = 0_i1
    locinc = nan_dp
    lat = nan_dp
    lon = nan_dp
    height = nan_dp
    dist = nan_dp
    inc = nan_dp
    pts = nan_dp
    return
  end if
  call sim_shade(dsm, gnd, o, opt, ns, n, scal, p, hit, l, threads, img, kind, locinc, lat, lon, height, dist, &
                 inc, pts, oval)
end subroutine core_sim_shade
