!> Ray stepping to the DEM surface: the paper's zcalc_planet_intersect
!> (section 2.3.2, eqs. 19-44), hit properties (section 2.4, eqs. 42-50) and
!> limb tangent points (section 2.4.1, eqs. 51-63).
!>
!> The path of one ray, in order:
!>   1. eq. 19-20  limb viewing angle psi0 and spherical tangent point t;
!>   2. eq. 21-22  search interval [d0, dm] where the ray is inside r_max;
!>   3. eq. 23-28  steps that each subtend delta-alpha at the planet centre;
!>   4. eq. 29-30  latitude/longitude of each test point, DEM radius (eqs. 2-12);
!>   5. eq. 31-41  refinement of the bracketed crossing;
!>   6. eq. 42-50  latitude, longitude, radius and emission angle of the hit;
!>   7. eq. 51-63  for a ray that misses: tc, sc and the tangent altitude.
!>
!> Every choice where the paper is silent or degenerate is listed in
!> docs/paper-notes.md and marked "[note N]" below.
module pi_intersect
  use pi_kinds, only: dp, i8
  use pi_status
  use pi_vector, only: pi, rad, deg, vsep, latlon_of, unit_vector
  use pi_dem, only: dem_t, dem_radius
  use pi_spheroid, only: spheroid_normal, spheroid_radius, tangent_spheroid
  use pi_exact, only: pyramid_t, exact_search
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_is_finite
  !$ use omp_lib, only: omp_get_max_threads
  implicit none
  private

  public :: ray_result_t, intersect_ray, intersect_rays, intersect_packed, step_angle, refine_tol_rel, refine_maxit
  public :: pyramid_t, method_stepping, method_exact, exact_tol_rel, max_steps, far_limit, far_anchor

  !> method values: the paper's ray stepping, or the exact first hit (pi_exact).
  integer, parameter :: method_stepping = 0, method_exact = 1
  !> Exact mode: leaves of the subdivision are shorter than exact_tol_rel * rmax.
  real(dp), parameter :: exact_tol_rel = 1.0e-9_dp

  !> Refinement stops when |r(p') - p'| <= refine_tol_rel * rmax [note 5].
  real(dp), parameter :: refine_tol_rel = 1.0e-12_dp
  !> Iteration limit of the refinement [note 5].
  integer, parameter :: refine_maxit = 100
  !> Most test points one ray may take (the stepping loop's bound on any input:
  !> the paper's steps need ~600 per ray at 128 ppd); past it the ray is
  !> ray_unresolved [note 19].
  integer, parameter :: max_steps = 10000000
  !> Spacecraft farther than far_limit * rmax from the centre are rejected
  !> (ray_bad_position): the direction of a unit vector is resolved to ~1e-16,
  !> so past this the line's position at the planet is uncertain by more than
  !> 0.1 rmax [note 19].
  real(dp), parameter :: far_limit = 1.0e15_dp
  !> Spacecraft farther than far_anchor * rmax: the line is re-anchored where it
  !> enters the r_max sphere (or at its closest approach to the centre) before
  !> the search and the tangent point, so that distances along it stay of the
  !> order of rmax and no step is lost to rounding [note 19].
  real(dp), parameter :: far_anchor = 16.0_dp

  !> Everything computed for one ray. Lengths in the DEM's units, angles in
  !> radians, NaN where a quantity does not apply.
  type :: ray_result_t
    !> One of the ray_* codes of pi_status.
    integer :: status = ray_bad_direction
    !> Number of test points evaluated (steps) and refinement iterations.
    integer :: nsteps = 0, niter = 0
    !> Hit point p (eq. 35 at convergence), its latitude, longitude, radius
    !> (eqs. 42-44), height above the spheroid (NaN without one), emission angle (eq. 45).
    real(dp) :: p(3), lat, lon, radius, altitude, emission
    !> Spherical tangent point t (eq. 20), spheroid tangent point tc (eq. 57),
    !> spheroid point sc below it; latitude/longitude of sc (eqs. 59-60);
    !> tangent altitude above the DEM (eq. 63) and above the spheroid (eq. 58, signed).
    real(dp) :: t(3), tc(3), sc(3), tangent_lat, tangent_lon, tangent_altitude, tangent_height
  end type ray_result_t

contains

  !> Angular step delta-alpha of eq. 23, radians, at latitude lat (radians).
  !>
  !> step_mode 1: cos(theta)/(2 ppd) degrees with theta clamped to the
  !> first/last row centre, theta1 = -90 + 1/(2 ppd) and theta_n = -theta1,
  !> so the step cannot collapse at the poles; step_mode 0: 1/(2 ppd) degrees.
  pure function step_angle(lat, ppd, step_mode) result(dalpha)
    real(dp), intent(in) :: lat
    integer, intent(in) :: ppd, step_mode
    real(dp) :: dalpha, lat_max
    if (step_mode == 1) then
      lat_max = (90.0_dp - 0.5_dp/ppd)*rad
      dalpha = cos(min(abs(lat), lat_max)) / (2.0_dp*ppd) * rad
    else
      dalpha = 1.0_dp / (2.0_dp*ppd) * rad
    end if
  end function step_angle

  !> Intersect one line of sight with the DEM (the paper's zcalc_planet_intersect
  !> for one pixel).
  !>
  !> Inputs: dem (open, either read mode); s, the spacecraft position in the
  !> planet-fixed frame (DEM units); l, the line of sight (any non-zero length,
  !> normalised here); step_mode 0 or 1 (eq. 23); tangent_mode 0 (paper's
  !> eqs. 55-58) or 1 (exact nearest point).
  !> Output: res, with res%status one of ray_hit, ray_hit_unconverged,
  !> ray_limb, ray_away, ray_bad_direction, ray_bad_position, ray_inside,
  !> ray_read_error.
  !>
  !> Particulars. Test points g_i = s + d_i l start at d0 (eq. 24; at the
  !> spacecraft when it is inside r_max, [note 3]) and advance by the sine rule
  !> (eqs. 25-28) with psi_i the angle at the current test point between l and
  !> the direction to the centre [note 1]. The first g_{i+1} with |g_{i+1}| < r_{i+1}
  !> brackets the hit, which is refined with eqs. 34-41. No test point beyond dm.
  subroutine intersect_ray(dem, s, l_in, step_mode, tangent_mode, res, method, pyr)
    type(dem_t), intent(in) :: dem
    real(dp), intent(in) :: s(3), l_in(3)
    integer, intent(in) :: step_mode, tangent_mode
    type(ray_result_t), intent(out) :: res
    !> method_stepping (default) or method_exact, which needs pyr.
    integer, intent(in), optional :: method
    type(pyramid_t), intent(in), optional :: pyr
    real(dp) :: l(3), nl, sn, cos_psi0, tn, half, d0, dm, nan, lat, lon, r_s
    real(dp) :: g(3), gn, rg, psi, dalpha, psi_next, denom, dg, d, d_next
    real(dp) :: g_next(3), gn_next, r_next, lat_next, lon_next, n(3), r_tc
    integer :: st, nodes
    logical :: hit, exact
    real(dp) :: d_hit
    !> the point the line is anchored at for the search and the tangent point:
    !> s itself, or for a far spacecraft a point on the line near the planet
    real(dp) :: s0(3), shift, margin

    nan = ieee_value(0.0_dp, ieee_quiet_nan)
    res%p = nan; res%lat = nan; res%lon = nan; res%radius = nan
    res%altitude = nan; res%emission = nan
    res%t = nan; res%tc = nan; res%sc = nan
    res%tangent_lat = nan; res%tangent_lon = nan
    res%tangent_altitude = nan; res%tangent_height = nan
    res%nsteps = 0
    res%niter = 0

    nl = norm2(l_in)
    if (.not. all(ieee_is_finite(l_in)) .or. nl <= 0.0_dp) then
      res%status = ray_bad_direction
      return
    end if
    sn = norm2(s)
    if (.not. all(ieee_is_finite(s)) .or. sn <= 0.0_dp .or. .not. (sn <= far_limit*dem%rmax)) then
      res%status = ray_bad_position
      return
    end if
    l = l_in/nl

    ! a spacecraft inside r_max must be above the surface
    if (sn <= dem%rmax) then
      call latlon_of(s, lat, lon)
      call dem_radius(dem, lat, lon, r_s, st)
      if (st /= stat_ok) then
        res%status = ray_failure(st)
        return
      end if
      if (sn < r_s) then
        res%status = ray_inside
        return
      end if
    end if

    cos_psi0 = -dot_product(s, l)/sn              ! eq. 19
    res%t = s + sn*cos_psi0*l                     ! eq. 20
    tn = norm2(res%t)
    s0 = s
    if (sn > far_anchor*dem%rmax .and. cos_psi0 > 0.0_dp) s0 = res%t     ! [note 19]

    hit = .false.
    if (tn < dem%rmax) then
      half = sqrt(dem%rmax**2 - tn**2)
      d0 = sn*cos_psi0 - half                     ! eq. 21
      dm = sn*cos_psi0 + half                     ! eq. 22
      if (sn > far_anchor*dem%rmax .and. d0 > 0.0_dp) then
        ! [note 19] a far spacecraft: anchor the line just before it enters r_max,
        ! farther out than the anchor's own rounding (~eps |s|), so that the anchor
        ! is outside the surface whatever the rounding (the fuzz harness found hits
        ! placed at an anchor that had rounded to inside a DEM whose rmax is its top)
        ! The margin is radial: along a grazing line a point m before the entry is only ~m^2/(2 rmax)
        ! higher, and the anchor's rounding (~eps |s| in each coordinate) can put it inside the
        ! surface (the bulk fuzzer: a line 1.03 km deep in a sphere seen from 6.9e11 rmax, anchored
        ! 14.6 km before its entry, i.e. 0.27 km above the surface, rounded 11 m inside and was a
        ! hit there). So the anchor goes back until it is `margin` above the r_max sphere.
        margin = max(1.0e-9_dp*dem%rmax, 16.0_dp*epsilon(1.0_dp)*sn)
        shift = max(d0 - (sqrt(max((dem%rmax + margin)**2 - tn**2, 0.0_dp)) - half) - margin, 0.0_dp)
        s0 = s + shift*l
        dm = dm - shift
        d0 = 0.0_dp              ! search from the anchor itself: d0's own rounding (~eps |s|)
      end if                     ! could otherwise put the start past the entry, inside the surface
      exact = .false.
      if (present(method) .and. present(pyr)) exact = method == method_exact
      if (dm > 0.0_dp .and. exact .and. s0(1) == 0.0_dp .and. s0(2) == 0.0_dp .and. &
          l(1) == 0.0_dp .and. l(2) == 0.0_dp) then
        ! [note 21] a line along the polar axis: the surface on it is the pole's
        ! radius (section 2.2); every point of it has the pole's latitude and no
        ! longitude, which the pyramid's boxes cannot bound
        call dem_radius(dem, sign(0.5_dp*pi, s0(3)), 0.0_dp, r_s, st)   ! the pole on s0's side
        if (st /= stat_ok) then
          res%status = ray_failure(st)
          return
        end if
        res%nsteps = 1
        if (s0(3)*l(3) < 0.0_dp .and. abs(s0(3)) >= r_s) then         ! towards that pole, above it
          hit = .true.
          res%p = [0.0_dp, 0.0_dp, sign(r_s, s0(3))]
          res%status = ray_hit
        end if
      else if (dm > 0.0_dp .and. exact) then
        call exact_search(dem, pyr, s0, l, max(d0, 0.0_dp), dm, exact_tol_rel*dem%rmax, hit, d_hit, nodes, st)
        res%nsteps = nodes
        if (st /= stat_ok) then
          res%status = ray_failure(st)
          return
        end if
        if (hit) then
          res%p = s0 + d_hit*l
          res%status = ray_hit
        end if
      else if (dm > 0.0_dp) then
        d = max(d0, 0.0_dp)                       ! [note 3]
        g = s0 + d*l                              ! eq. 24
        gn = norm2(g)
        psi = vsep(l, -g)                         ! angle at g0 [note 1]
        call latlon_of(g, lat, lon)
        do
          dalpha = step_angle(lat, dem%ppd, step_mode)          ! eq. 23
          psi_next = psi + dalpha                               ! eq. 25
          denom = max(sin(pi - psi_next), sin(dalpha))          ! [note 2]
          dg = sin(dalpha)*gn/denom                             ! eq. 26
          d_next = d + dg                                       ! eq. 27
          if (.not. (d_next > d) .or. res%nsteps >= max_steps) then
            res%status = ray_unresolved                         ! no progress (NaN, rounding) [note 19]
            return
          end if
          if (d_next > dm) exit                                 ! past the search interval: no hit
          g_next = s0 + d_next*l                                ! eq. 28
          gn_next = norm2(g_next)
          call latlon_of(g_next, lat_next, lon_next)            ! eqs. 29-30
          call dem_radius(dem, lat_next, lon_next, r_next, st)  ! eqs. 2-12
          res%nsteps = res%nsteps + 1
          if (st /= stat_ok) then
            res%status = ray_failure(st)
            return
          end if
          if (gn_next < r_next) then
            if (res%nsteps == 1) then
              ! the bracket's upper end needs r at g0 (eq. 34)
              call dem_radius(dem, lat, lon, rg, st)
              if (st /= stat_ok) then
                res%status = ray_failure(st)
                return
              end if
            end if
            call refine(dem, l, g, gn, rg, g_next, gn_next, r_next, dg, res, st)
            if (st /= stat_ok) then
              res%status = ray_failure(st)
              return
            end if
            hit = .true.
            exit
          end if
          d = d_next
          g = g_next
          gn = gn_next
          rg = r_next
          psi = psi_next
          lat = lat_next
          lon = lon_next
        end do
      end if
    end if

    if (hit) then
      call latlon_of(res%p, res%lat, res%lon)                   ! eqs. 42-43
      res%radius = norm2(res%p)                                 ! eq. 44
      n = spheroid_normal(res%p, dem%f)                         ! eq. 50
      res%emission = vsep(n, -l)                                ! eq. 45
      if (has_spheroid(dem)) res%altitude = res%radius - spheroid_radius(res%lat, dem%f, dem%re)
      res%t = nan                                               ! [note 7]
      return
    end if

    if (cos_psi0 < 0.0_dp) then
      res%status = ray_away                                     ! no tangent point ahead
      res%t = nan
      return
    end if

    ! limb view: tangent point on the spheroid and its altitude above the DEM
    res%status = ray_limb
    call tangent_spheroid(s0, l, dem%f, dem%re, tangent_mode, res%tc, res%sc, res%tangent_height)
    call latlon_of(res%sc, res%tangent_lat, res%tangent_lon)    ! eqs. 59-60
    r_tc = spheroid_radius(res%tangent_lat, dem%f, dem%re)      ! eq. 61
    call dem_radius(dem, res%tangent_lat, res%tangent_lon, rg, st)
    if (st /= stat_ok) then
      res%status = ray_failure(st)
      res%tc = nan; res%sc = nan; res%t = nan
      res%tangent_lat = nan; res%tangent_lon = nan; res%tangent_height = nan
      return
    end if
    n = spheroid_normal(res%sc, dem%f)
    ! eq. 63, with n_c taken as the outward spheroid normal at sc [note 6]
    res%tangent_altitude = (r_tc - rg)*dot_product(res%sc, n)/(norm2(res%sc)*norm2(n)) &
                           + res%tangent_height
    if (.not. has_spheroid(dem)) then
      ! [note 20] no spheroid (f = 0, re = 1): sc and the height above it would be
      ! measured from a unit sphere; the altitude above the DEM (|tc| - r) stands
      res%sc = nan
      res%tangent_height = nan
    end if
  end subroutine intersect_ray

  !> The per-ray code for a routine status met on a ray's path: a coordinate or
  !> search that could not be resolved is ray_unresolved, a record that could
  !> not be read or is invalid ray_read_error.
  pure integer function ray_failure(st) result(code)
    integer, intent(in) :: st
    if (st == stat_bad_coord .or. st == stat_unresolved) then
      code = ray_unresolved
    else
      code = ray_read_error
    end if
  end function ray_failure

  !> Refine a bracketed crossing by eqs. 31-41.
  !>
  !> ga (radius gna, DEM radius ra) is above the surface, gb (gnb, rb) below,
  !> dg = |gb - ga|. Each iteration places p' where the chord ga-gb crosses
  !> the chord between the surface points below ga and gb (eq. 34, v in [0, 1))
  !> and keeps the half that still brackets the crossing (eqs. 36-41), until
  !> |r(p') - p'| <= refine_tol_rel*rmax or refine_maxit iterations [note 5].
  !> Safeguard: when the same end has been kept twice running (false position
  !> stalling at a crease of the bilinear surface), the next p' is the bracket
  !> midpoint (v = 1/2) [note 5].
  subroutine refine(dem, l, ga_in, gna_in, ra_in, gb_in, gnb_in, rb_in, dg_in, res, stat)
    type(dem_t), intent(in) :: dem
    real(dp), intent(in) :: l(3), ga_in(3), gna_in, ra_in, gb_in(3), gnb_in, rb_in, dg_in
    type(ray_result_t), intent(inout) :: res
    integer, intent(out) :: stat
    real(dp) :: ga(3), gna, ra, gnb, rb, dg, v, pp(3), pn, rp, lat, lon, tol
    integer :: it, side, last_side
    logical :: stalled

    ga = ga_in; gna = gna_in; ra = ra_in
    gnb = gnb_in; rb = rb_in; dg = dg_in
    tol = refine_tol_rel*dem%rmax
    res%status = ray_hit_unconverged
    pp = gb_in
    last_side = 0
    stalled = .false.
    do it = 1, refine_maxit
      if (stalled) then
        v = 0.5_dp
      else
        v = rb*(ra - gna)/(gnb*ra - gna*rb)        ! eq. 34
      end if
      pp = ga + v*dg*l                             ! eq. 35
      pn = norm2(pp)
      call latlon_of(pp, lat, lon)
      call dem_radius(dem, lat, lon, rp, stat)
      res%niter = it
      if (stat /= stat_ok) return
      if (abs(rp - pn) <= tol) then
        res%status = ray_hit
        exit
      end if
      if (rp > pn) then                            ! p' below the surface
        gnb = pn; rb = rp                          ! eqs. 36-37
        dg = v*dg                                  ! eq. 38
        side = 1
      else                                         ! p' above the surface
        ga = pp; gna = pn; ra = rp                 ! eqs. 39-40
        dg = (1.0_dp - v)*dg                       ! eq. 41
        side = 2
      end if
      stalled = side == last_side
      last_side = side
    end do
    res%p = pp
  end subroutine refine

  !> Intersect n rays: res(k) for spacecraft s(:, k) and line of sight l(:, k).
  !>
  !> threads: OpenMP threads for the ray loop (0 = all available; ignored in a
  !> build without OpenMP). Rays are independent and each is computed by the
  !> same code whichever thread runs it, so results are bit-identical for any
  !> thread count. The count is a num_threads clause: no global state is set.
  !>
  !> stat: stat_bad_mode when step_mode or tangent_mode is not 0 or 1 (then
  !> nothing is computed); otherwise stat_ok, with per-ray codes in res%status.
  subroutine intersect_rays(dem, s, l, step_mode, tangent_mode, res, stat, threads, method, pyr)
    type(dem_t), intent(in) :: dem
    real(dp), intent(in) :: s(:, :), l(:, :)
    integer, intent(in) :: step_mode, tangent_mode
    type(ray_result_t), intent(out) :: res(:)
    integer, intent(out) :: stat
    integer, intent(in), optional :: threads, method
    type(pyramid_t), intent(in), optional :: pyr
    integer :: meth
    integer(i8) :: k
    integer :: nt
    stat = stat_ok
    if ((step_mode /= 0 .and. step_mode /= 1) .or. (tangent_mode /= 0 .and. tangent_mode /= 1)) then
      stat = stat_bad_mode
      return
    end if
    meth = method_stepping
    if (present(method)) meth = method
    if (meth /= method_stepping .and. meth /= method_exact) then
      stat = stat_bad_mode
      return
    end if
    if (meth == method_exact .and. .not. present(pyr)) then
      stat = stat_bad_mode
      return
    end if
    nt = 1
    !$ nt = omp_get_max_threads()
    if (present(threads)) then
      if (threads > 0) nt = threads
    end if
    if (meth == method_exact) then
      !$omp parallel do schedule(dynamic, 64) num_threads(nt) default(shared) private(k)
      do k = 1, size(res, kind=i8)
        call intersect_ray(dem, s(:, k), l(:, k), step_mode, tangent_mode, res(k), meth, pyr)
      end do
      !$omp end parallel do
    else
      !$omp parallel do schedule(dynamic, 64) num_threads(nt) default(shared) private(k)
      do k = 1, size(res, kind=i8)
        call intersect_ray(dem, s(:, k), l(:, k), step_mode, tangent_mode, res(k))
      end do
      !$omp end parallel do
    end if
  end subroutine intersect_rays

  !> intersect_rays with the results unpacked into plain arrays (the form the
  !> f2py boundary and the legacy zcalc_planet_intersect hand out).
  !>
  !> scal(:, k) = lat, lon, radius, altitude, emission, tangent_lat,
  !> tangent_lon, tangent_altitude, tangent_height (radians, DEM units).
  subroutine intersect_packed(dem, n, s, l, step_mode, tangent_mode, p, t, tc, sc, scal, status, nsteps, stat, &
                              threads, method, pyr)
    type(dem_t), intent(in) :: dem
    integer, intent(in) :: n, step_mode, tangent_mode
    integer, intent(in), optional :: threads, method
    type(pyramid_t), intent(in), optional :: pyr
    real(dp), intent(in) :: s(3, n), l(3, n)
    real(dp), intent(out) :: p(3, n), t(3, n), tc(3, n), sc(3, n), scal(9, n)
    integer, intent(out) :: status(n), nsteps(n), stat
    type(ray_result_t), allocatable :: res(:)
    integer :: k
    allocate(res(n))
    call intersect_rays(dem, s, l, step_mode, tangent_mode, res, stat, threads, method, pyr)
    if (stat /= stat_ok) then
      p = 0.0_dp; t = 0.0_dp; tc = 0.0_dp; sc = 0.0_dp; scal = 0.0_dp
      status = -1; nsteps = 0
      return
    end if
    do k = 1, n
      p(:, k) = res(k)%p
      t(:, k) = res(k)%t
      tc(:, k) = res(k)%tc
      sc(:, k) = res(k)%sc
      scal(:, k) = [res(k)%lat, res(k)%lon, res(k)%radius, res(k)%altitude, res(k)%emission, &
                    res(k)%tangent_lat, res(k)%tangent_lon, res(k)%tangent_altitude, res(k)%tangent_height]
      status(k) = res(k)%status
      nsteps(k) = res(k)%nsteps
    end do
  end subroutine intersect_packed

  !> True when the header defines a reference spheroid (not Table 1's
  !> f = 0, re = 1 placeholder for irregular bodies).
  pure logical function has_spheroid(dem)
    type(dem_t), intent(in) :: dem
    has_spheroid = .not. (dem%f == 0.0_dp .and. dem%re == 1.0_dp)
  end function has_spheroid

end module pi_intersect
