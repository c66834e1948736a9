!> Status codes shared by every routine of planet-intersect.
!>
!> Library routines never STOP or print. A routine that can fail returns an
!> integer `stat` (0 = success, one of the `stat_*` codes below otherwise) and
!> the ray loop returns one `ray_*` code per ray. The Python layer
!> (`planet_intersect._status`) holds the same table with messages; keep the
!> two in step (a test compares them).
module pi_status
  implicit none
  private

  ! routine-level codes
  public :: stat_ok, stat_hdr_open, stat_hdr_value, stat_hdr_key, stat_dem_open, &
            stat_dem_size, stat_dem_read, stat_bad_ppd, stat_bad_rmax, stat_bad_f, &
            stat_bad_re, stat_bad_radii, stat_bad_mode, stat_bad_shape, stat_bad_coord, &
            stat_unresolved
  ! per-ray codes
  public :: ray_hit, ray_limb, ray_away, ray_hit_unconverged, ray_bad_direction, &
            ray_bad_position, ray_inside, ray_read_error, ray_unresolved
  ! per-ray codes of the geodetic DSM tracing (Shin & Park), appended
  public :: ray_no_data, ray_left_dsm, ray_dsm_miss, ray_not_converged, ray_oscillation, &
            ray_step_limit

  !> Success.
  integer, parameter :: stat_ok = 0
  !> The `.hdr` file cannot be opened or read.
  integer, parameter :: stat_hdr_open = 1
  !> One of the four header values is missing or not a number.
  integer, parameter :: stat_hdr_value = 2
  !> An optional `key = value` line has an unknown key or value.
  integer, parameter :: stat_hdr_key = 3
  !> The `.dem` file cannot be opened.
  integer, parameter :: stat_dem_open = 4
  !> The `.dem` size is not `nlat*nlon*itemsize` bytes.
  integer, parameter :: stat_dem_size = 5
  !> A read from the `.dem` file failed.
  integer, parameter :: stat_dem_read = 6
  !> `ppd < 1`.
  integer, parameter :: stat_bad_ppd = 7
  !> A radius exceeds `rmax` (or `rmax <= 0`).
  integer, parameter :: stat_bad_rmax = 8
  !> Flattening outside [0, 1).
  integer, parameter :: stat_bad_f = 9
  !> Equatorial radius not positive and finite.
  integer, parameter :: stat_bad_re = 10
  !> A radius is NaN, infinite or not positive.
  integer, parameter :: stat_bad_radii = 11
  !> `step_mode`, `dem_read_mode` or `tangent_mode` out of range.
  integer, parameter :: stat_bad_mode = 12
  !> Array dimensions disagree with `ppd`.
  integer, parameter :: stat_bad_shape = 13
  !> A latitude or longitude handed to the DEM interpolation is not finite, or
  !> the latitude lies outside [-pi/2, pi/2] (never used as an array index).
  integer, parameter :: stat_bad_coord = 14
  !> A search could not be resolved in floating point: a non-finite
  !> intermediate value, no progress along the ray, or its step/segment budget
  !> exhausted (pi_intersect::max_steps, pi_exact::max_nodes).
  integer, parameter :: stat_unresolved = 15

  !> The ray hits the DEM surface; `p` and its properties are set.
  integer, parameter :: ray_hit = 0
  !> The ray misses the surface and passes the planet: tangent outputs are set.
  integer, parameter :: ray_limb = 1
  !> The ray misses and points away from the planet (cos psi0 < 0): no tangent point.
  integer, parameter :: ray_away = 2
  !> Hit, but the refinement (eqs. 34-41) did not reach the tolerance in the
  !> iteration limit; `p` is the last estimate and still lies within the final bracket.
  integer, parameter :: ray_hit_unconverged = 3
  !> The line of sight has zero length or a non-finite component.
  integer, parameter :: ray_bad_direction = 4
  !> The spacecraft position is non-finite or at the planet centre.
  integer, parameter :: ray_bad_position = 5
  !> The spacecraft is below the DEM surface.
  integer, parameter :: ray_inside = 6
  !> A DEM record could not be read (dem_read_mode = 1) or is invalid.
  integer, parameter :: ray_read_error = 7
  !> The ray could not be resolved in floating point (stat_unresolved or
  !> stat_bad_coord on its path): no result is given, never a guessed one.
  integer, parameter :: ray_unresolved = 8

  ! ---- geodetic DSM tracing (Shin & Park: pi_follow, pi_dsm_exact) ----
  !> DSM: before any hit the ray passes low (h <= H_max) over a no-data point;
  !> the event point is set, no hit is guessed.
  integer, parameter :: ray_no_data = 9
  !> DSM: no hit, but the ray is low (h <= H_max) at a point outside the DSM's
  !> defined area (it left the DSM or never entered it); the event point is set.
  integer, parameter :: ray_left_dsm = 10
  !> DSM: the ray never comes down to H_max (passes above everything or points away).
  integer, parameter :: ray_dsm_miss = 11
  !> DSM, iterative ray tracing: no convergence within the iteration limit.
  integer, parameter :: ray_not_converged = 12
  !> DSM, iterative ray tracing: the iteration revisits a height (endless oscillation).
  integer, parameter :: ray_oscillation = 13
  !> DSM: the step or segment limit was reached before an answer.
  integer, parameter :: ray_step_limit = 14
end module pi_status
