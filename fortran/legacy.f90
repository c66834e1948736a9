!> Legacy entry points: external (non-module) procedures with the names of
!> the paper's FORTRAN77 routines (Table 2), so that an old program can call
!> them with implicit interfaces and link `libplanet_intersect_legacy.a`.
!>
!> The original source is not available: these argument lists are
!> reconstructed from the paper and documented in docs/legacy-interface.md.
!> Conventions here: REAL*8 throughout, angles in DEGREES (as the paper's
!> text), vectors as arrays (3, n), status codes as in pi_status.

!> Intersect n lines of sight with the DEM `demfile` (the paper's main routine).
!>   s(3,n), l(3,n): spacecraft positions and lines of sight (planet frame);
!>   dem_read_mode 0|1, step_mode 0|1 (section 3);
!>   p, t, tc, sc (3,n): hit point, spherical tangent point, spheroid tangent
!>   point and the spheroid point below it (NaN where not applicable);
!>   emission(n): emission angle at hits, degrees (NaN otherwise);
!>   istat(n): per-ray status (0 hit, 1 limb, 2 pointing away, ...);
!>   ierr: 0 or a routine status code.
!> The tangent point is the paper's construction (eqs. 55-58).
subroutine zcalc_planet_intersect(n, s, l, demfile, dem_read_mode, step_mode, p, t, tc, sc, &
                                  emission, istat, ierr)
  use pi_kinds, only: dp
  use pi_vector, only: deg
  use pi_dem, only: dem_t, dem_open, dem_close
  use pi_intersect, only: intersect_packed
  use pi_spheroid, only: tangent_mode_paper
  use pi_status, only: stat_ok
  implicit none
  integer, intent(in) :: n, dem_read_mode, step_mode
  real(dp), intent(in) :: s(3, n), l(3, n)
  character(len=*), intent(in) :: demfile
  real(dp), intent(out) :: p(3, n), t(3, n), tc(3, n), sc(3, n), emission(n)
  integer, intent(out) :: istat(n), ierr
  type(dem_t) :: dem
  real(dp), allocatable :: scal(:, :)
  integer, allocatable :: nsteps(:)
  p = 0.0_dp; t = 0.0_dp; tc = 0.0_dp; sc = 0.0_dp; emission = 0.0_dp; istat = -1
  call dem_open(demfile, dem_read_mode, dem, ierr)
  if (ierr /= stat_ok) return
  allocate(scal(9, n), nsteps(n))
  call intersect_packed(dem, n, s, l, step_mode, tangent_mode_paper, p, t, tc, sc, scal, istat, &
                        nsteps, ierr)
  emission = scal(5, :)*deg
  call dem_close(dem)
end subroutine zcalc_planet_intersect

!> Read and check the header of `demfile` and the size of its `.dem`
!> (the paper's zdem_open): ppd, rmax, f, re of Table 1; ierr as pi_status.
subroutine zdem_open(demfile, ppd, rmax, f, re, ierr)
  use pi_kinds, only: dp
  use pi_dem, only: dem_t, dem_open, dem_close
  use pi_status, only: stat_ok
  implicit none
  character(len=*), intent(in) :: demfile
  integer, intent(out) :: ppd, ierr
  real(dp), intent(out) :: rmax, f, re
  type(dem_t) :: dem
  call dem_open(demfile, 1, dem, ierr)
  ppd = dem%ppd; rmax = dem%rmax; f = dem%f; re = dem%re
  if (ierr == stat_ok) call dem_close(dem)
end subroutine zdem_open

!> Read the whole grid of `demfile` into radii(nlon, nlat), nlon = 360 ppd,
!> nlat = 180 ppd (the paper's zdem_read, dem_read_mode 0).
subroutine zdem_read(demfile, nlon, nlat, radii, ierr)
  use pi_kinds, only: dp
  use pi_dem, only: dem_t, dem_open, dem_close
  use pi_status, only: stat_ok, stat_bad_shape
  implicit none
  character(len=*), intent(in) :: demfile
  integer, intent(in) :: nlon, nlat
  real(dp), intent(out) :: radii(nlon, nlat)
  integer, intent(out) :: ierr
  type(dem_t) :: dem
  radii = 0.0_dp
  call dem_open(demfile, 0, dem, ierr)
  if (ierr /= stat_ok) return
  if (dem%nlon /= nlon .or. dem%nlat /= nlat) then
    ierr = stat_bad_shape
  else
    radii = dem%radii
  end if
  call dem_close(dem)
end subroutine zdem_read

!> Interpolated radius at (lat, lon) in degrees from a grid in memory
!> (the paper's zdem_radius, eqs. 2-12). rmax is not needed here.
subroutine zdem_radius(nlon, nlat, radii, ppd, lat, lon, r)
  use pi_kinds, only: dp
  use pi_vector, only: rad
  use pi_dem, only: dem_t, dem_attach, dem_radius
  implicit none
  integer, intent(in) :: nlon, nlat, ppd
  real(dp), intent(in), target :: radii(nlon, nlat)
  real(dp), intent(in) :: lat, lon
  real(dp), intent(out) :: r
  type(dem_t) :: dem
  integer :: stat
  call dem_attach(radii, ppd, huge(1.0_dp), 0.0_dp, 1.0_dp, dem, stat)
  r = 0.0_dp
  if (stat == 0) call dem_radius(dem, lat*rad, lon*rad, r, stat)
end subroutine zdem_radius

!> Interpolated radius at (lat, lon) in degrees read record by record from
!> `demfile` (the paper's zdem_radius_increment, dem_read_mode 1). Opens and
!> closes the file on each call: keeps no state between calls.
subroutine zdem_radius_increment(demfile, lat, lon, r, ierr)
  use pi_kinds, only: dp
  use pi_vector, only: rad
  use pi_dem, only: dem_t, dem_open, dem_close, dem_radius
  use pi_status, only: stat_ok
  implicit none
  character(len=*), intent(in) :: demfile
  real(dp), intent(in) :: lat, lon
  real(dp), intent(out) :: r
  integer, intent(out) :: ierr
  type(dem_t) :: dem
  r = 0.0_dp
  call dem_open(demfile, 1, dem, ierr)
  if (ierr /= stat_ok) return
  call dem_radius(dem, lat*rad, lon*rad, r, ierr)
  call dem_close(dem)
end subroutine zdem_radius_increment

!> Tangent point of the line s + a l on the spheroid (f, re) by the paper's
!> construction, eqs. 54-58 (the paper's ztangent_ellipsoid): tc on the line,
!> sc on the spheroid, d = |tc - sc| (negative when tc is inside).
subroutine ztangent_ellipsoid(s, l, f, re, tc, sc, d)
  use pi_kinds, only: dp
  use pi_vector, only: unit_vector
  use pi_spheroid, only: tangent_paper
  implicit none
  real(dp), intent(in) :: s(3), l(3), f, re
  real(dp), intent(out) :: tc(3), sc(3), d
  call tangent_paper(s, unit_vector(l), f, re, tc, sc, d)
end subroutine ztangent_ellipsoid

!> c = a x b (the paper's zcrossp).
subroutine zcrossp(a, b, c)
  use pi_kinds, only: dp
  use pi_vector, only: cross
  implicit none
  real(dp), intent(in) :: a(3), b(3)
  real(dp), intent(out) :: c(3)
  c = cross(a, b)
end subroutine zcrossp

!> w = v rotated right-handedly by angle (degrees) about axis (the paper's
!> zrotate_about_vector).
subroutine zrotate_about_vector(v, axis, angle, w)
  use pi_kinds, only: dp
  use pi_vector, only: rotate_about_vector, rad
  implicit none
  real(dp), intent(in) :: v(3), axis(3), angle
  real(dp), intent(out) :: w(3)
  w = rotate_about_vector(v, axis, angle*rad)
end subroutine zrotate_about_vector

!> The function Delta of section 2.2: eastward angle of lon2 from lon1,
!> degrees in [0, 360). flondiff(10, 350) = 340, flondiff(350, 10) = 20.
function flondiff(lon1, lon2) result(delta)
  use pi_kinds, only: dp
  implicit none
  real(dp), intent(in) :: lon1, lon2
  real(dp) :: delta
  delta = modulo(lon2 - lon1, 360.0_dp)
  if (delta >= 360.0_dp) delta = 0.0_dp
end function flondiff

!> Angle between vectors a and b, degrees in [0, 180] (the paper's fvsep).
function fvsep(a, b) result(angle)
  use pi_kinds, only: dp
  use pi_vector, only: vsep, deg
  implicit none
  real(dp), intent(in) :: a(3), b(3)
  real(dp) :: angle
  angle = vsep(a, b)*deg
end function fvsep
