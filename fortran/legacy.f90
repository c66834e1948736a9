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
!>   ierr: 0 or a routine status code (12 for a mode out of range, 13 for
!>   n < 0); when ierr /= 0 every output is NaN and istat is -1.
!> The tangent point is the paper's construction (eqs. 55-58).
!> Departure (docs/legacy-interface.md, note L1): the paper's section 3
!> passes ppd, rmax, f, re in; here they are read from the `.hdr`.
subroutine zcalc_planet_intersect(n, s, l, demfile, dem_read_mode, step_mode, p, t, tc, sc, &
                                  emission, istat, ierr)
  use pi_kinds, only: dp
  use pi_vector, only: deg
  use pi_dem, only: dem_t, dem_open, dem_close
  use pi_intersect, only: intersect_packed
  use pi_spheroid, only: tangent_mode_paper
  use pi_status, only: stat_ok, stat_bad_shape, stat_bad_mode
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
  implicit none
  integer, intent(in) :: n, dem_read_mode, step_mode
  real(dp), intent(in) :: s(3, n), l(3, n)
  character(len=*), intent(in) :: demfile
  real(dp), intent(out) :: p(3, n), t(3, n), tc(3, n), sc(3, n), emission(n)
  integer, intent(out) :: istat(n), ierr
  type(dem_t) :: dem
  real(dp), allocatable :: scal(:, :)
  integer, allocatable :: nsteps(:)
  real(dp) :: nan
  nan = ieee_value(1.0_dp, ieee_quiet_nan)
  if (n < 0) then
    ierr = stat_bad_shape
    return
  end if
  p = nan; t = nan; tc = nan; sc = nan; emission = nan; istat = -1
  ! the modes before the file: with a missing file and step_mode 5 the answer was 1 (no header)
  ! and the bad mode was never named (a review)
  if ((dem_read_mode /= 0 .and. dem_read_mode /= 1) .or. (step_mode /= 0 .and. step_mode /= 1)) then
    ierr = stat_bad_mode
    return
  end if
  call dem_open(demfile, dem_read_mode, dem, ierr)
  if (ierr /= stat_ok) return
  allocate(scal(9, n), nsteps(n))
  call intersect_packed(dem, n, s, l, step_mode, tangent_mode_paper, p, t, tc, sc, scal, istat, &
                        nsteps, ierr)
  call dem_close(dem)
  if (ierr /= stat_ok) then
    p = nan; t = nan; tc = nan; sc = nan; istat = -1
    return
  end if
  emission = scal(5, :)*deg
end subroutine zcalc_planet_intersect

!> Read and check the header of `demfile` and the size of its `.dem`
!> (the paper's zdem_open): ppd, rmax, f, re of Table 1; ierr as pi_status.
subroutine zdem_open(demfile, ppd, rmax, f, re, ierr)
  use pi_kinds, only: dp
  use pi_dem, only: dem_t, dem_open, dem_close
  use pi_status, only: stat_ok
  use pi_ieee, only: nan_dp
  implicit none
  character(len=*), intent(in) :: demfile
  integer, intent(out) :: ppd, ierr
  real(dp), intent(out) :: rmax, f, re
  type(dem_t) :: dem
  call dem_open(demfile, 1, dem, ierr)
  if (ierr == stat_ok) then
    ppd = dem%ppd; rmax = dem%rmax; f = dem%f; re = dem%re
    call dem_close(dem)
  else
    ! (partly parsed values were returned, 0 or defaults, where the project's missing value is
    ! NaN: a review)
    ppd = 0; rmax = nan_dp; f = nan_dp; re = nan_dp
  end if
end subroutine zdem_open

!> Read the whole grid of `demfile` into radii(nlon, nlat), nlon = 360 ppd,
!> nlat = 180 ppd (the paper's zdem_read, dem_read_mode 0).
subroutine zdem_read(demfile, nlon, nlat, radii, ierr)
  use pi_kinds, only: dp
  use pi_dem, only: dem_t, dem_open, dem_close
  use pi_status, only: stat_ok, stat_bad_shape
  use pi_ieee, only: nan_dp
  implicit none
  character(len=*), intent(in) :: demfile
  integer, intent(in) :: nlon, nlat
  real(dp), intent(out) :: radii(nlon, nlat)
  integer, intent(out) :: ierr
  type(dem_t) :: dem
  radii = nan_dp                               ! (0 on an error before: NaN is the missing value)
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
!> (the paper's zdem_radius, eqs. 2-12), with the paper's argument list.
!>
!> The paper's routine has no status argument. Reconstruction (note L2): r is
!> NaN (the project's missing value; every valid radius is > 0 and finite) whenever
!> zdem_radius_status below reports an error: ppd < 1, nlon /= 360 ppd or
!> nlat /= 180 ppd, a latitude or longitude that is not finite, |lat| > 90.
!> Test it with `IF (R .NE. R)`, or call zdem_radius_status for the code.
subroutine zdem_radius(nlon, nlat, radii, ppd, lat, lon, r)
  use pi_kinds, only: dp
  implicit none
  integer, intent(in) :: nlon, nlat, ppd
  real(dp), intent(in) :: radii(nlon, nlat)
  real(dp), intent(in) :: lat, lon
  real(dp), intent(out) :: r
  integer :: ierr
  external :: zdem_radius_status
  call zdem_radius_status(nlon, nlat, radii, ppd, lat, lon, r, ierr)
end subroutine zdem_radius

!> zdem_radius with a status (a reconstruction: not in the paper).
!>   nlon, nlat, radii(nlon, nlat): the grid as zdem_read returns it;
!>   ppd: pixels per degree (Table 1); lat, lon: planetocentric degrees;
!>   r: interpolated radius, the grid's units (NaN when ierr /= 0);
!>   ierr: 0; 7 (ppd < 1 or too large for the grid's size to be counted);
!>   13 (nlon /= 360 ppd or nlat /= 180 ppd); -1 (lat or lon not finite,
!>   or |lat| > 90). The radii themselves are the caller's and are not checked.
subroutine zdem_radius_status(nlon, nlat, radii, ppd, lat, lon, r, ierr)
  use pi_kinds, only: dp, i8
  use pi_vector, only: rad
  use pi_dem, only: dem_t, dem_radius, dem_polar_mean
  use pi_status, only: stat_ok, stat_bad_ppd, stat_bad_shape
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_is_finite
  implicit none
  integer, intent(in) :: nlon, nlat, ppd
  real(dp), intent(in) :: radii(nlon, nlat)
  real(dp), intent(in) :: lat, lon
  real(dp), intent(out) :: r
  integer, intent(out) :: ierr
  !> legacy-only status: latitude or longitude not finite, or |lat| > 90
  integer, parameter :: stat_bad_latlon = -1
  r = ieee_value(1.0_dp, ieee_quiet_nan)
  if (ppd < 1 .or. 360_i8*ppd > huge(1)) then
    ierr = stat_bad_ppd
  else if (nlon /= 360*ppd .or. nlat /= 180*ppd) then
    ierr = stat_bad_shape
  else if (.not. (ieee_is_finite(lat) .and. ieee_is_finite(lon) .and. abs(lat) <= 90.0_dp)) then
    ierr = stat_bad_latlon
  else
    call interpolate(radii)
  end if

contains

  ! the grid as a TARGET dummy (explicit interface), so that the DEM's pointer
  ! to it is valid during this call; the external routine itself has no TARGET
  ! dummy, so FORTRAN77 callers with implicit interfaces stay conforming.
  ! The DEM is set up here rather than by dem_attach, which sums both polar
  ! rows (2 x 360 ppd radii) on every call: 12,000 calls/s at 32 ppd. A pole
  ! mean (section 2.2) is formed only within a pixel of its pole (dem_radius
  ! uses it within half a pixel) and is NaN elsewhere, so that a use outside
  ! would show (docs/legacy-interface.md, note L2).
  subroutine interpolate(grid)
    real(dp), intent(in), target :: grid(nlon, nlat)
    type(dem_t) :: dem
    dem%ppd = ppd
    dem%nlon = nlon
    dem%nlat = nlat
    dem%rmax = huge(1.0_dp)                ! rmax, f, re: not used by eqs. 2-12
    dem%f = 0.0_dp
    dem%re = 1.0_dp
    dem%read_mode = 0
    dem%radii => grid
    dem%owns_radii = .false.
    dem%pole_south = ieee_value(1.0_dp, ieee_quiet_nan)
    dem%pole_north = dem%pole_south
    if (lat <= -90.0_dp + 1.0_dp/ppd) dem%pole_south = dem_polar_mean(grid(:, 1))
    if (lat >= 90.0_dp - 1.0_dp/ppd) dem%pole_north = dem_polar_mean(grid(:, nlat))
    call dem_radius(dem, lat*rad, lon*rad, r, ierr)
    if (ierr /= stat_ok) r = ieee_value(1.0_dp, ieee_quiet_nan)
  end subroutine interpolate

end subroutine zdem_radius_status

!> Interpolated radius at (lat, lon) in degrees read record by record from
!> `demfile` (the paper's zdem_radius_increment, dem_read_mode 1), with the
!> paper's argument list: opens the file, reads the header and both polar rows
!> (for the pole means), reads the four records needed and closes the file on
!> every call. For many calls use zdem_handle_open / zdem_radius_handle /
!> zdem_handle_close, which do the opening once.
!>   r: NaN when ierr /= 0; ierr: as zdem_open, as dem_radius for a record,
!>   -1 for lat or lon not finite or |lat| > 90.
subroutine zdem_radius_increment(demfile, lat, lon, r, ierr)
  use pi_kinds, only: dp
  use pi_vector, only: rad
  use pi_dem, only: dem_t, dem_open, dem_close, dem_radius
  use pi_status, only: stat_ok
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_is_finite
  implicit none
  character(len=*), intent(in) :: demfile
  real(dp), intent(in) :: lat, lon
  real(dp), intent(out) :: r
  integer, intent(out) :: ierr
  !> legacy-only status: latitude or longitude not finite, or |lat| > 90
  integer, parameter :: stat_bad_latlon = -1
  type(dem_t) :: dem
  r = ieee_value(1.0_dp, ieee_quiet_nan)
  if (.not. (ieee_is_finite(lat) .and. ieee_is_finite(lon) .and. abs(lat) <= 90.0_dp)) then
    ierr = stat_bad_latlon
    return
  end if
  call dem_open(demfile, 1, dem, ierr)
  if (ierr /= stat_ok) return
  call dem_radius(dem, lat*rad, lon*rad, r, ierr)
  if (ierr /= stat_ok) r = ieee_value(1.0_dp, ieee_quiet_nan)
  call dem_close(dem)
end subroutine zdem_radius_increment

!> Open `demfile` once for many zdem_radius_handle calls (note L3, a reconstruction:
!> the paper's zdem_radius_increment has no handle). Reads and checks the
!> header and the `.dem` size, reads both polar rows for the pole means, and
!> keeps the `.dem` file open; everything needed later is stored in the
!> caller's integer array handle(nh), nh >= 32 (no SAVE, no module state: the
!> caller owns the state, several handles may be open at once, and one handle
!> may be used by several threads, since reads are positioned, pread).
!>   ierr: as zdem_open (handle is then marked closed); -2 when nh < 32
!>   (handle is not touched). Release with zdem_handle_close. Do not copy an
!>   open handle and close both copies.
!> Layout (integers): 1 magic 1346978888, 2 layout version 1, 3 file
!> descriptor, 4 ppd, 5 bytes per record, 6 byte swap 0|1, 7-8 rmax, 9-10 f,
!> 11-12 re, 13-14 south pole mean, 15-16 north pole mean (REAL*8 bit
!> patterns), 17 checksum of 1-16, 18-32 zero.
subroutine zdem_handle_open(demfile, nh, handle, ierr)
  use pi_dem, only: dem_t, dem_open
  use pi_status, only: stat_ok
  implicit none
  character(len=*), intent(in) :: demfile
  integer, intent(in) :: nh
  integer, intent(inout) :: handle(*)
  integer, intent(out) :: ierr
  integer, parameter :: handle_size = 32, magic = 1346978888, stat_bad_handle = -2
  integer, external :: pi_legacy_handle_sum
  type(dem_t) :: dem
  if (nh < handle_size) then
    ierr = stat_bad_handle
    return
  end if
  handle(1:handle_size) = 0
  call dem_open(demfile, 1, dem, ierr)
  if (ierr /= stat_ok) return                  ! dem_open closed what it opened
  handle(1) = magic
  handle(2) = 1
  handle(3) = dem%fd
  handle(4) = dem%ppd
  handle(5) = dem%itemsize
  handle(6) = merge(1, 0, dem%swap)
  handle(7:8) = transfer(dem%rmax, 0, 2)
  handle(9:10) = transfer(dem%f, 0, 2)
  handle(11:12) = transfer(dem%re, 0, 2)
  handle(13:14) = transfer(dem%pole_south, 0, 2)
  handle(15:16) = transfer(dem%pole_north, 0, 2)
  handle(17) = pi_legacy_handle_sum(handle)
  ! the descriptor now belongs to the handle: dem is not closed here
end subroutine zdem_handle_open

!> Interpolated radius at (lat, lon) in degrees from a DEM opened with
!> zdem_handle_open (eqs. 2-12, dem_read_mode 1: four records read per call,
!> the pole means taken from the handle). Bit-identical to
!> zdem_radius_increment on the same file.
!>   r: NaN when ierr /= 0; ierr: 0; -2 handle not open, corrupted, or
!>   nh < 32; -1 lat or lon not finite or |lat| > 90; 5 the `.dem` no longer
!>   has its size (checked on each call); 6, 8, 11 a record unreadable or
!>   invalid (as dem_radius).
subroutine zdem_radius_handle(nh, handle, lat, lon, r, ierr)
  use pi_kinds, only: dp, i8
  use pi_vector, only: rad
  use pi_dem, only: dem_t, dem_radius
  use pi_io, only: io_size
  use pi_status, only: stat_ok, stat_dem_size
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_is_finite
  implicit none
  integer, intent(in) :: nh
  integer, intent(in) :: handle(*)
  real(dp), intent(in) :: lat, lon
  real(dp), intent(out) :: r
  integer, intent(out) :: ierr
  integer, parameter :: handle_size = 32, magic = 1346978888, stat_bad_handle = -2, stat_bad_latlon = -1
  integer, external :: pi_legacy_handle_sum
  type(dem_t) :: dem
  r = ieee_value(1.0_dp, ieee_quiet_nan)
  ierr = stat_bad_handle
  if (nh < handle_size) return
  if (handle(1) /= magic .or. handle(2) /= 1 .or. handle(17) /= pi_legacy_handle_sum(handle)) return
  if (handle(3) < 0 .or. handle(4) < 1 .or. 360_i8*handle(4) > huge(1)) return
  if (handle(5) /= 4 .and. handle(5) /= 8) return
  if (handle(6) /= 0 .and. handle(6) /= 1) return
  if (.not. (ieee_is_finite(lat) .and. ieee_is_finite(lon) .and. abs(lat) <= 90.0_dp)) then
    ierr = stat_bad_latlon
    return
  end if
  dem%read_mode = 1
  dem%fd = handle(3)
  dem%ppd = handle(4)
  dem%nlon = 360*dem%ppd
  dem%nlat = 180*dem%ppd
  dem%itemsize = handle(5)
  dem%swap = handle(6) == 1
  dem%rmax = transfer(handle(7:8), 0.0_dp)
  dem%f = transfer(handle(9:10), 0.0_dp)
  dem%re = transfer(handle(11:12), 0.0_dp)
  dem%pole_south = transfer(handle(13:14), 0.0_dp)
  dem%pole_north = transfer(handle(15:16), 0.0_dp)
  ! a file truncated (or a descriptor reused for another file) since the open
  if (io_size(dem%fd) /= int(dem%nlon, i8)*int(dem%nlat, i8)*int(dem%itemsize, i8)) then
    ierr = stat_dem_size
    return
  end if
  call dem_radius(dem, lat*rad, lon*rad, r, ierr)
  if (ierr /= stat_ok) r = ieee_value(1.0_dp, ieee_quiet_nan)
end subroutine zdem_radius_handle

!> Close a handle from zdem_handle_open: closes its file and zeroes it.
!>   ierr: 0; -2 when the handle is not open (already closed, never opened,
!>   corrupted) or nh < 32 (nothing is closed then).
subroutine zdem_handle_close(nh, handle, ierr)
  use pi_io, only: io_close
  implicit none
  integer, intent(in) :: nh
  integer, intent(inout) :: handle(*)
  integer, intent(out) :: ierr
  integer, parameter :: handle_size = 32, magic = 1346978888, stat_bad_handle = -2
  integer, external :: pi_legacy_handle_sum
  ierr = stat_bad_handle
  if (nh < handle_size) return
  if (handle(1) /= magic .or. handle(2) /= 1 .or. handle(17) /= pi_legacy_handle_sum(handle)) return
  if (handle(3) >= 0) call io_close(handle(3))
  handle(1:handle_size) = 0
  ierr = 0
end subroutine zdem_handle_close

!> Checksum of handle(1:16) for zdem_handle_open and its users (internal to
!> the legacy library; a corrupted or stale handle is refused, not used).
integer function pi_legacy_handle_sum(handle) result(c)
  implicit none
  integer, intent(in) :: handle(*)
  integer :: k
  c = 305419896                                ! 0x12345678
  do k = 1, 16
    c = ieor(ishftc(c, 7), handle(k))
  end do
end function pi_legacy_handle_sum

!> Tangent point of the line s + a l on the spheroid (f, re) by the paper's
!> construction, eqs. 54-58 (the paper's ztangent_ellipsoid): tc on the line,
!> sc on the spheroid, d = |tc - sc| (negative when tc is inside). A zero or
!> non-finite l has no line: tc, sc and d are NaN (they were tc = s and a finite
!> d for l = 0, a review; zcalc_planet_intersect gives such a ray status 4).
subroutine ztangent_ellipsoid(s, l, f, re, tc, sc, d)
  use pi_kinds, only: dp
  use pi_vector, only: unit_vector
  use pi_spheroid, only: tangent_paper
  use pi_ieee, only: nan_dp, is_finite
  implicit none
  real(dp), intent(in) :: s(3), l(3), f, re
  real(dp), intent(out) :: tc(3), sc(3), d
  if (.not. (all(is_finite(l)) .and. maxval(abs(l)) > 0.0_dp)) then
    tc = nan_dp
    sc = nan_dp
    d = nan_dp
    return
  end if
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
