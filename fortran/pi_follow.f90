!> Ray following over a geodetic DSM (Shin & Park, section 3, steps 1-5 and
!> eqs. 1-5) and the conventional iterative ray tracing they criticise
!> (section 2, O'Neil & Dowman), one ray at a time; plus the ray helpers the
!> exact mode (pi_dsm_exact) shares.
!>
!> The ray is P(r) = s + r l (eq. 1), s in ECR, l a unit vector, r >= 0 the
!> distance from s. Every choice where the paper is silent or ambiguous is a
!> numbered note in docs/shin-park-notes.md, marked "[note N]" below.
!>
!> Per-ray status codes (pi_status): ray_hit, ray_hit_unconverged (the
!> refinement hit its iteration limit), ray_no_data, ray_left_dsm, ray_dsm_miss,
!> ray_not_converged and ray_oscillation (iterative), ray_step_limit.
module pi_follow
  use pi_kinds, only: dp
  use pi_status
  use pi_dsm, only: dsm_t, dsm_height, dsm_cell_metres, pt_ok, pt_outside, pt_nodata
  use pi_geodetic, only: ecr_to_geodetic, ecr_to_geodetic_bowring, geodetic_to_ecr
  implicit none
  private

  public :: dsm_ray_t, follow_ray, iterate_ray, ray_geo, level_crossing, level_crossing_back, &
            ellipsoid_entry, set_hit, set_event, settle_start, refine_tol, follow_maxsteps, iter_maxit, &
            iter_tol, nadir_tol, newton_tol, bowring_error, bowring_tol

  !> Refinement and exact-mode tolerance on r (units of a; 1e-6 m for Earth in metres).
  real(dp), parameter :: refine_tol = 1.0e-6_dp
  !> Step limit of the ray following (then ray_step_limit).
  integer, parameter :: follow_maxsteps = 20000000
  !> Iteration limit and height tolerance of the iterative ray tracing.
  integer, parameter :: iter_maxit = 100
  real(dp), parameter :: iter_tol = 1.0e-6_dp
  !> cos(theta_i) at or below this is the paper's nadir case (theta_i = 90 deg) [note 6].
  real(dp), parameter :: nadir_tol = 1.0e-12_dp
  !> Largest error of eq. 2 (Bowring's one step), relative to a, for which the following
  !> steps with it; above it (strongly flattened bodies) the steps use the exact
  !> conversion: see bowring_error [note 10].
  real(dp), parameter :: bowring_tol = 1.0e-10_dp

  !> Everything computed for one ray (lengths in units of a, angles radians).
  type :: dsm_ray_t
    integer :: status = ray_bad_direction
    !> ray points converted (steps, refinement and search evaluations)
    integer :: nsteps = 0
    !> hit: point p, geodetic lat, lon, height of p, surface height there, distance r, incidence
    real(dp) :: p(3), lat, lon, h, hs, r, incidence
    !> no-data / left-the-DSM event: first low point over no-data or outside
    real(dp) :: q(3), qlat, qlon, qh, qr
    !> set by the exact mode's fast path when it declines with the slab searched to
    !> its end and found clear of hits and no-data points (pi_dsm_fast's
    !> search_slab): exact_ray then looks only for the first low point outside
    logical :: slab_clear = .false.
  end type dsm_ray_t

contains

  !> Largest Newton step along a ray (units of a) after which a level or cell
  !> crossing counts as found: 1e-9, or 1e-15 |r| (>= 4.5 ulp(r)) where r is
  !> so large that a smaller step no longer moves r (r >= ~1.7e7 m, a focal
  !> point at GEO distance: the loops stalled and reported the crossing
  !> missing). The one stopping rule of pi_follow's, exact_ray's and the fast
  !> path's Newton loops.
  elemental function newton_tol(r) result(tol)
    real(dp), intent(in) :: r
    real(dp) :: tol
    tol = max(1.0e-9_dp, 1.0e-15_dp * abs(r))
  end function newton_tol

  !> Exact geodetic coordinates of P(r) = s + r l and dh/dr = l . n (n the unit
  !> normal at the foot point: the gradient of the geodetic height).
  pure subroutine ray_geo(dsm, s, l, r, lat, lon, h, dh)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r
    real(dp), intent(out) :: lat, lon, h, dh
    real(dp) :: p(3), nx, ny, nz
    p = s + r * l                                           ! Shin & Park eq. 1
    call ecr_to_geodetic(p(1), p(2), p(3), dsm%a, dsm%f, lat, lon, h, nx, ny, nz)
    dh = l(1) * nx + l(2) * ny + l(3) * nz
  end subroutine ray_geo

  !> First r >= r0 with h(r) <= level, by Newton from the left on the convex
  !> h(r) - level (the geodetic height is the signed distance to a convex
  !> body, so convex along a line: Newton from a point above never overshoots).
  !> found = .false. when h(r) stays above level. On return r is within 1e-9 of
  !> the crossing, not after it. neval counts conversions.
  pure subroutine level_crossing(dsm, s, l, r0, level, r, found, neval)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r0, level
    real(dp), intent(out) :: r
    logical, intent(out) :: found
    integer, intent(inout) :: neval
    real(dp) :: lat, lon, h, dh, dr, rg
    logical :: hit
    integer :: it
    r = r0
    found = .false.
    ! start near the crossing: the first intersection with the ellipsoid raised
    ! by `level` (a + level, b + level), used only when h is still above the
    ! level and falling there (then it lies before the crossing)
    ! (raised by a margin: the level surface bulges past that ellipsoid by up
    ! to ~e2^2 |level| / 32, measured)
    if (level > -0.5_dp * dsm%b) then
      rg = level + 1.0e-9_dp * dsm%a + dsm%e2**2 * abs(level) / 8.0_dp
      call ellipsoid_entry(dsm%a + rg, dsm%b + rg, s, l, rg, hit)
      if (hit .and. rg > r0) then
        call ray_geo(dsm, s, l, rg, lat, lon, h, dh)
        neval = neval + 1
        if (h - level > 0.0_dp .and. dh < 0.0_dp) r = rg
      end if
    end if
    do it = 1, 300
      call ray_geo(dsm, s, l, r, lat, lon, h, dh)
      neval = neval + 1
      if (h - level <= 0.0_dp) then
        found = .true.
        return
      end if
      if (.not. (dh < 0.0_dp)) return                  ! rising or NaN: never reaches the level
      dr = -(h - level) / dh
      r = r + dr
      if (dr <= newton_tol(r)) then
        found = .true.
        return
      end if
    end do
    found = .false.                                   ! unreachable in practice (monotone convergence)
  end subroutine level_crossing

  !> Last r <= r1 with h(r) <= level (Newton from the right, h(r1) > level).
  pure subroutine level_crossing_back(dsm, s, l, r1, level, r, found, neval)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r1, level
    real(dp), intent(out) :: r
    logical, intent(out) :: found
    integer, intent(inout) :: neval
    real(dp) :: lat, lon, h, dh, dr
    integer :: it
    r = r1
    found = .false.
    do it = 1, 300
      call ray_geo(dsm, s, l, r, lat, lon, h, dh)
      neval = neval + 1
      if (h - level <= 0.0_dp) then
        found = .true.
        return
      end if
      if (.not. (dh > 0.0_dp)) return
      dr = (h - level) / dh
      r = r - dr
      if (dr <= newton_tol(r)) then
        found = .true.
        return
      end if
    end do
  end subroutine level_crossing_back

  !> First intersection r >= 0 of the ray with the ellipsoid (a, b) (h = 0).
  pure subroutine ellipsoid_entry(a, b, s, l, r, hit)
    real(dp), intent(in) :: a, b, s(3), l(3)
    real(dp), intent(out) :: r
    logical, intent(out) :: hit
    real(dp) :: qa, qb, qc, disc, sq, r1, r2
    qa = (l(1)**2 + l(2)**2) / (a * a) + l(3)**2 / (b * b)
    qb = (s(1) * l(1) + s(2) * l(2)) / (a * a) + s(3) * l(3) / (b * b)
    qc = (s(1)**2 + s(2)**2) / (a * a) + s(3)**2 / (b * b) - 1.0_dp
    disc = qb * qb - qa * qc
    hit = .false.
    r = 0.0_dp
    if (.not. (disc >= 0.0_dp)) return
    sq = sqrt(disc)
    ! the two roots without cancellation
    if (qb <= 0.0_dp) then
      r1 = qc / (-qb + sq)
      r2 = (-qb + sq) / qa
    else
      r1 = (-qb - sq) / qa
      r2 = qc / (-qb - sq)
    end if
    if (r1 > r2) then
      r = r1; r1 = r2; r2 = r
    end if
    if (r1 >= 0.0_dp) then
      r = r1
      hit = .true.
    else if (r2 >= 0.0_dp) then
      r = 0.0_dp                                        ! s inside the ellipsoid
      hit = .true.
    end if
  end subroutine ellipsoid_entry

  !> Fill res as a hit at distance r (exact coordinates of p; hs the surface there).
  pure subroutine set_hit(dsm, s, l, r, status, res)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r
    integer, intent(in) :: status
    type(dsm_ray_t), intent(inout) :: res
    real(dp) :: dh
    integer :: code
    res%status = status
    res%r = r
    res%p = s + r * l
    call ray_geo(dsm, s, l, r, res%lat, res%lon, res%h, dh)
    call dsm_height(dsm, res%lat, res%lon, res%hs, code)
    res%incidence = acos(max(-1.0_dp, min(1.0_dp, -dh)))   ! from the normal: 0 = looking straight down
  end subroutine set_hit

  !> The exact modes' start point r (the first point searched, h its height,
  !> hs and code the DSM there, as dsm_height gives them): over no-data it is
  !> the no-data event, at or below the surface the hit; done = .false. if
  !> neither (the search goes on).
  pure subroutine settle_start(dsm, s, l, r, h, hs, code, res, done)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r, h, hs
    integer, intent(in) :: code
    type(dsm_ray_t), intent(inout) :: res
    logical, intent(out) :: done
    done = .true.
    if (code == pt_nodata) then
      call set_event(dsm, s, l, r, ray_no_data, res)
    else if (code == pt_ok .and. h <= hs) then
      call set_hit(dsm, s, l, r, ray_hit, res)
    else
      done = .false.
    end if
  end subroutine settle_start

  !> Fill res's event point (no-data / left the DSM) at distance r.
  pure subroutine set_event(dsm, s, l, r, status, res)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r
    integer, intent(in) :: status
    type(dsm_ray_t), intent(inout) :: res
    real(dp) :: dh
    res%status = status
    res%qr = r
    res%q = s + r * l
    call ray_geo(dsm, s, l, r, res%qlat, res%qlon, res%qh, dh)
  end subroutine set_event

  !> g(r) = h(r) - H(r) for the refinement; a point that is not over data counts
  !> as above the surface (g > 0) [note 9]. low_nodata: the point is over
  !> no-data at h <= H_max.
  pure subroutine gap(dsm, s, l, r, g, low_nodata)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r
    real(dp), intent(out) :: g
    logical, intent(out) :: low_nodata
    real(dp) :: lat, lon, h, dh, hs
    integer :: code
    call ray_geo(dsm, s, l, r, lat, lon, h, dh)
    call dsm_height(dsm, lat, lon, hs, code)
    if (code == pt_ok) then
      g = h - hs
    else
      g = max(h - dsm%hmax, 0.0_dp) + 1.0e-3_dp
    end if
    low_nodata = code == pt_nodata .and. h <= dsm%hmax
  end subroutine gap

  !> Error of eq. 2 (Bowring's one step) over the DSM's heights: the largest
  !> |h error| + a |latitude error| of ecr_to_geodetic_bowring against the exact
  !> conversion at latitudes 0, 5, ..., 90 degrees (the error is symmetric about
  !> the equator and does not depend on longitude) and heights H_min, H_max and
  !> their mean (units of a).
  !>
  !> Particulars: on the Earth it is 2e-6 m at 10 km and on Mars 2e-5 m, far
  !> below bowring_tol * a; on a 13 km body with f = 0.3 it is ~100 m at 4 km
  !> (a fuzz case: the steps put the ray over a cell five rows from where the
  !> exact conversion puts it, and the following reported a hit outside the
  !> grid) [note 10]. 57 conversions each way: call it once per batch.
  pure function bowring_error(dsm) result(err)
    type(dsm_t), intent(in) :: dsm
    real(dp) :: err, hl(3), lat, x, y, z, la, lo, h, lb, lob, hb
    integer :: i, j
    hl = [dsm%hmin, 0.5_dp * (dsm%hmin + dsm%hmax), dsm%hmax]
    err = 0.0_dp
    do j = 1, 3
      do i = 0, 18
        lat = real(i, dp) * (5.0_dp * acos(-1.0_dp) / 180.0_dp)
        call geodetic_to_ecr(lat, 0.0_dp, hl(j), dsm%a, dsm%f, x, y, z)
        call ecr_to_geodetic(x, y, z, dsm%a, dsm%f, la, lo, h)
        call ecr_to_geodetic_bowring(x, y, z, dsm%a, dsm%f, lb, lob, hb)
        err = max(err, abs(hb - h) + dsm%a * abs(lb - la))
      end do
    end do
    if (.not. (err <= huge(1.0_dp))) err = huge(1.0_dp)       ! NaN: never trust eq. 2
  end function bowring_error

  !> Shin & Park ray following (section 3, steps 1-5) for one ray; l unit,
  !> s above the surface (checked by the caller). See the module header.
  !> exact_steps (default .false.): convert the steps exactly instead of by
  !> eq. 2, for bodies where eq. 2 is off (bowring_error > bowring_tol a) [note 10].
  pure subroutine follow_ray(dsm, s, l, res, exact_steps)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3)
    type(dsm_ray_t), intent(inout) :: res
    logical, intent(in), optional :: exact_steps
    real(dp) :: re, pe(3), late, lone, he, nx, ny, nz, sin_ti, cos_ti, r, dr, dy, dx, dd
    real(dp) :: p(3), lat, lon, h, hs, hprev, rprev, ra, rb, ga, gb, rc, gc, wold, rout, rfirst
    logical :: hit_e, found, exact, nda, ndc
    integer :: code, k, it, side
    res%nsteps = 0
    exact = .false.
    if (present(exact_steps)) exact = exact_steps
    ! ---- step 1: r_min (eq. 3), theta_i, nadir case, Delta r (eq. 4)
    call ellipsoid_entry(dsm%a, dsm%b, s, l, re, hit_e)
    if (hit_e .and. re > 0.0_dp) then
      pe = s + re * l
      call ecr_to_geodetic(pe(1), pe(2), pe(3), dsm%a, dsm%f, late, lone, he, nx, ny, nz)
      sin_ti = -(l(1) * nx + l(2) * ny + l(3) * nz)          ! theta_i from the horizontal [note 3]
      cos_ti = sqrt(max(0.0_dp, 1.0_dp - sin_ti * sin_ti))
      if (cos_ti <= nadir_tol) then                         ! the paper's nadir case [note 6]
        call dsm_height(dsm, late, lone, hs, code)
        res%nsteps = 1
        if (code == pt_outside) then
          call set_event(dsm, s, l, max(re - dsm%hmax, 0.0_dp), ray_left_dsm, res)
          return
        else if (code == pt_nodata) then
          call set_event(dsm, s, l, max(re - dsm%hmax, 0.0_dp), ray_no_data, res)
          return
        end if
        call set_hit(dsm, s, l, re - hs, ray_hit, res)        ! the projected point at height H
        return
      end if
      r = re - dsm%hmax / sin_ti                             ! eq. 3, r_min back from the ellipsoid [note 4]
    else
      ! the ray does not reach the bare ellipsoid (or s is inside it): start
      ! where it enters the H_max level, theta_i = 0 [note 5]
      call level_crossing(dsm, s, l, 0.0_dp, dsm%hmax, r, found, res%nsteps)
      if (.not. found) then
        res%status = ray_dsm_miss
        return
      end if
      p = s + r * l
      call ecr_to_geodetic(p(1), p(2), p(3), dsm%a, dsm%f, late, lone, he)
      cos_ti = 1.0_dp
      sin_ti = 0.0_dp
    end if
    r = max(r, 0.0_dp)
    call dsm_cell_metres(dsm, late, dy, dx)
    dd = min(dy, dx)                                         ! D_DSM in metres at the projected point [note 7]
    dr = dd / cos_ti                                         ! eq. 4 [note 8]
    ! ... at most the slab (H_max to H_min, plus one D) along the ray: below H_min every point over
    ! the DSM is a hit, so a longer step samples nothing more; near nadir eq. 4's step was thousands
    ! of km (a MISS for rays 1e-7 rad off nadir, a hit 62 km underground: a review) [note 8]
    if (sin_ti > 0.0_dp) dr = min(dr, (dsm%hmax - dsm%hmin + dd) / sin_ti)
    ! ---- steps 2-5
    rfirst = r
    rprev = r
    hprev = huge(1.0_dp)
    rout = -1.0_dp
    do k = 1, follow_maxsteps
      p = s + r * l                                          ! step 2: eq. 1
      if (exact) then
        call ecr_to_geodetic(p(1), p(2), p(3), dsm%a, dsm%f, lat, lon, h)        ! eq. 2 is off here [note 10]
      else
        call ecr_to_geodetic_bowring(p(1), p(2), p(3), dsm%a, dsm%f, lat, lon, h) ! eq. 2 [note 10]
      end if
      call dsm_height(dsm, lat, lon, hs, code)               ! step 3
      res%nsteps = res%nsteps + 1
      if (code == pt_ok .and. h <= hs) then                  ! step 4: the ray is at or below the surface [note 11]
        if (exact) exit
        ! confirmed by the exact conversion that the refinement and the result use: eq. 2's
        ! h = p / cos(phi) - N amplifies rounding near a pole (1.7e-3 m at 0.77 m from Mars's
        ! pole, a fuzz case: the hit came back 1.2e-4 m above the surface); unconfirmed, the
        ! point is above the surface and the steps go on [note 10]
        call gap(dsm, s, l, r, gb, ndc)
        res%nsteps = res%nsteps + 1
        if (gb <= 0.0_dp) exit
      else if (code == pt_nodata .and. h <= dsm%hmax) then
        call set_event(dsm, s, l, r, ray_no_data, res)       ! [note 12]
        return
      else if (code == pt_outside .and. h <= dsm%hmax) then  ! outside: go on, it may come back [note 12]
        if (.not. (rout >= 0.0_dp)) rout = r
      end if
      if ((h > dsm%hmax .and. h > hprev) .or. (code == pt_outside .and. h < dsm%hmin)) then
        if (rout >= 0.0_dp) then                             ! rising above everything, or below all outside
          call set_event(dsm, s, l, rout, ray_left_dsm, res)
        else
          res%status = ray_dsm_miss
        end if
        return
      end if
      hprev = h
      rprev = r
      r = r + dr                                             ! step 5: eq. 5
    end do
    if (k > follow_maxsteps) then
      res%status = ray_step_limit
      return
    end if
    ! ---- refinement between the last two points [note 9]: Illinois false
    ! position on g = h - H, bracket [ra, rb] with g(ra) > 0 >= g(rb), bisection
    ! when two iterations did not halve the bracket; stops at rb - ra <= refine_tol.
    ra = rprev
    rb = r
    if (exact) call gap(dsm, s, l, rb, gb, ndc)             ! (else known from the step's confirmation)
    call gap(dsm, s, l, ra, ga, nda)
    res%nsteps = res%nsteps + merge(2, 1, exact)
    ! eq. 2 may have put the step before at or above the surface where the exact conversion puts
    ! it below (its h = p / cos(phi) - N amplifies rounding near a pole: a fuzz case 8.6 m from
    ! Mars's pole was a hit 3.5e-6 m below flat ground, the crossing a step, 2.5e-6 m, back): the
    ! crossing then lies before ra, so step back, exactly, until above (at most the steps taken;
    ! rfirst, where h = H_max, is never below) [note 10]
    do while (.not. (ga > 0.0_dp) .and. ra > rfirst)
      rb = ra
      gb = ga
      ra = max(ra - dr, rfirst)
      call gap(dsm, s, l, ra, ga, nda)
      res%nsteps = res%nsteps + 1
    end do
    if (rb - ra <= refine_tol) then
      call set_hit(dsm, s, l, rb, ray_hit, res)
      return
    end if
    side = 0
    wold = 2.0_dp * (rb - ra)
    do it = 1, 200
      if (rb - ra <= refine_tol) exit
      if (mod(it, 2) == 1) then
        if (rb - ra > 0.5_dp * wold) then
          rc = 0.5_dp * (ra + rb)
        else
          rc = rb - gb * (rb - ra) / (gb - ga)
        end if
        wold = rb - ra
      else
        rc = rb - gb * (rb - ra) / (gb - ga)
      end if
      if (.not. (rc > ra .and. rc < rb)) rc = 0.5_dp * (ra + rb)
      call gap(dsm, s, l, rc, gc, ndc)
      res%nsteps = res%nsteps + 1
      if (gc > 0.0_dp) then
        ra = rc
        ga = gc
        nda = ndc
        if (side == -1) gb = 0.5_dp * gb
        side = -1
      else
        rb = rc
        gb = gc
        if (side == 1) ga = 0.5_dp * ga
        side = 1
      end if
    end do
    if (nda) then
      ! the crossing is the side of a cell that the ray reaches low over no-data,
      ! which the steps passed over: not a hit the DSM can vouch for (the exact
      ! mode's NO_DATA there; a fuzz case was a hit 12.6 m below a roof) [note 12]
      call set_event(dsm, s, l, ra, ray_no_data, res)
    else if (rb - ra <= refine_tol) then
      call set_hit(dsm, s, l, rb, ray_hit, res)
    else
      call set_hit(dsm, s, l, rb, ray_hit_unconverged, res)
    end if
  end subroutine follow_ray

  !> Conventional iterative ray tracing (Shin & Park section 2, Fig. 1): start
  !> on the bare ellipsoid (h_0 = 0) [note 13], intersect the ray with the
  !> level surface of geodetic height h_k, read H there, set h_{k+1} = H,
  !> until |H - h_k| <= iter_tol (hit), a level repeats (ray_oscillation: the
  !> endless iteration of Fig. 1b), or iter_maxit levels (ray_not_converged).
  pure subroutine iterate_ray(dsm, s, l, res)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3)
    type(dsm_ray_t), intent(inout) :: res
    real(dp) :: levels(0:iter_maxit), r, lat, lon, h, dh, hs
    logical :: found
    integer :: k, j, code
    res%nsteps = 0
    levels(0) = 0.0_dp
    do k = 0, iter_maxit - 1
      call level_crossing(dsm, s, l, 0.0_dp, levels(k), r, found, res%nsteps)
      if (.not. found) then
        res%status = ray_dsm_miss
        return
      end if
      call ray_geo(dsm, s, l, r, lat, lon, h, dh)
      call dsm_height(dsm, lat, lon, hs, code)
      if (code /= pt_ok) then
        call set_event(dsm, s, l, r, merge(ray_left_dsm, ray_no_data, code == pt_outside), res)
        return
      end if
      if (abs(hs - levels(k)) <= iter_tol) then
        call set_hit(dsm, s, l, r, ray_hit, res)
        return
      end if
      do j = 0, k - 1
        if (abs(hs - levels(j)) <= iter_tol) then          ! a cycle: it would repeat forever
          call set_hit(dsm, s, l, r, ray_oscillation, res)
          return
        end if
      end do
      levels(k + 1) = hs
    end do
    call set_hit(dsm, s, l, r, ray_not_converged, res)
  end subroutine iterate_ray

end module pi_follow
