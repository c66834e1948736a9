!> Geodetic coordinates on a reference ellipsoid (semi-major axis a,
!> flattening f): ECR (Earth-centred rotating = body-fixed) Cartesian x, y, z
!> <-> geodetic latitude phi, east longitude lambda, height h.
!>
!> * geodetic_to_ecr: the standard closed form (prime vertical radius N).
!> * ecr_to_geodetic_printed: Shin & Park eq. 2 exactly as printed
!>   (numerator z + (a^2/b^2) e^2 sin^3 theta, which is dimensionally wrong:
!>   docs/shin-park-notes.md note 1).
!> * ecr_to_geodetic_bowring: eq. 2 as Bowring (1976) and Dana (1997), the
!>   paper's source, give it: z + e'^2 b sin^3 theta [note 1].
!> * ecr_to_geodetic: exact. The foot point on the meridian ellipse is the
!>   root of Eberly's monotone function F(t) (t = h / |grad| scale), found by
!>   Newton from Bowring's estimate inside a bracket that bisection keeps
!>   shrinking: always terminates (at most geo_maxit iterations), relative
!>   accuracy ~1e-15; exact at the poles, on the equator and at the centre.
!>   h is the signed distance to the ellipsoid (negative inside).
!> * ecr_to_geodetic_near: the same exact conversion for a point near one
!>   already converted (the DSM fast path's points along one ray): Newton
!>   started from the caller's height estimate, accepted one step early where
!>   its quadratic convergence bounds the error, and the angles as increments
!>   on the reference's (a short series instead of two atan2).
!>
!> Angles in radians, lengths in the units of a. All routines are elemental.
module pi_geodetic
  use pi_kinds, only: dp
  implicit none
  private

  public :: geodetic_to_ecr, ecr_to_geodetic, ecr_to_geodetic_bowring, ecr_to_geodetic_printed, &
            geo_maxit, ecr_to_geodetic_nb, ecr_to_geodetic_near

  !> Iteration limit of the exact conversion (bisection fallback keeps it finite;
  !> Newton needs 1-3 iterations from Bowring's estimate near the surface).
  integer, parameter :: geo_maxit = 200
  !> pi (pi_vector's value; here to keep this module free of dependencies)
  real(dp), parameter :: pi_ = 3.14159265358979323846264338327950288_dp

contains

  !> ECR Cartesian point of geodetic (lat, lon, h) on the ellipsoid (a, f).
  !>
  !> Inputs: lat, lon (radians), h (units of a), a > 0, 0 <= f < 1.
  !> Outputs: x, y, z (units of a).
  elemental subroutine geodetic_to_ecr(lat, lon, h, a, f, x, y, z)
    real(dp), intent(in) :: lat, lon, h, a, f
    real(dp), intent(out) :: x, y, z
    real(dp) :: e2, sl, cl, n
    e2 = f * (2.0_dp - f)
    sl = sin(lat)
    cl = cos(lat)
    n = a / sqrt(1.0_dp - e2 * sl * sl)
    x = (n + h) * cl * cos(lon)
    y = (n + h) * cl * sin(lon)
    z = (n * (1.0_dp - e2) + h) * sl
  end subroutine geodetic_to_ecr

  !> Shin & Park eq. 2 exactly as printed (Bowring's one-step formula with the
  !> factor b missing from the numerator's second term) [note 1].
  !>
  !> Inputs: x, y, z ECR (units of a); a, f. Outputs: lat, lon (radians), h.
  elemental subroutine ecr_to_geodetic_printed(x, y, z, a, f, lat, lon, h)
    real(dp), intent(in) :: x, y, z, a, f
    real(dp), intent(out) :: lat, lon, h
    real(dp) :: b, e2, p, th
    b = a * (1.0_dp - f)
    e2 = f * (2.0_dp - f)
    p = sqrt(x * x + y * y)
    th = atan2(z * a, b * p)                                         ! Shin & Park eq. 2, theta
    lat = atan2(z + (a * a / (b * b)) * e2 * sin(th)**3, p - e2 * a * cos(th)**3)  ! eq. 2 as printed [note 1]
    lon = atan2(y, x)                                                ! eq. 2, lambda
    h = p / cos(lat) - a / sqrt(1.0_dp - e2 * sin(lat)**2)           ! eq. 2, h
    if (p == 0.0_dp) h = abs(z) - b                                  ! on the axis p/cos(lat) is 0/0 [note 2]
  end subroutine ecr_to_geodetic_printed

  !> Shin & Park eq. 2 as Bowring/Dana state it (e'^2 b sin^3 theta) [note 1]:
  !> the one-step formula the paper cites. h = p/cos(lat) - N as printed, and
  !> within ~5.7 degrees of the poles (p < |z|/10) the same h as
  !> p cos(lat) + z sin(lat) - a sqrt(1 - e2 sin^2 lat), which stays well
  !> conditioned on and near the axis (note 2).
  !>
  !> Inputs: x, y, z ECR (units of a); a, f. Outputs: lat, lon (radians), h.
  elemental subroutine ecr_to_geodetic_bowring(x, y, z, a, f, lat, lon, h)
    real(dp), intent(in) :: x, y, z, a, f
    real(dp), intent(out) :: lat, lon, h
    real(dp) :: b, e2, ep2, p, th
    b = a * (1.0_dp - f)
    e2 = f * (2.0_dp - f)
    ep2 = e2 / (1.0_dp - e2)
    p = sqrt(x * x + y * y)
    th = atan2(z * a, b * p)                                         ! Shin & Park eq. 2, theta
    lat = atan2(z + ep2 * b * sin(th)**3, p - e2 * a * cos(th)**3)   ! eq. 2, phi [note 1]
    lon = atan2(y, x)                                                ! eq. 2, lambda
    if (p >= 0.1_dp * abs(z)) then
      h = p / cos(lat) - a / sqrt(1.0_dp - e2 * sin(lat)**2)         ! eq. 2, h [note 2]
    else
      ! within ~5.7 degrees of the poles, the same h in a form that does not divide by cos(lat):
      ! p / cos(lat) turns the rounding of lat into N^2 ulp / p of height (1.4 m at 1 mm from the
      ! axis, -210 km at 10 nm, and the following's false hits 32 m over the surface near a pole;
      ! an independent review, 2026-12-05); p cos(lat) + z sin(lat) - a sqrt(1 - e2 sin^2 lat) is
      ! stationary in lat at the foot point, so lat's rounding no longer reaches h [note 2]
      h = p * cos(lat) + z * sin(lat) - a * sqrt(1.0_dp - e2 * sin(lat)**2)
    end if
    ! on the axis, the centre included (whose nearest surface point is a pole): h = |z| - b
    if (p == 0.0_dp) h = abs(z) - b
  end subroutine ecr_to_geodetic_bowring

  !> Exact ECR -> geodetic conversion (see the module header).
  !>
  !> Inputs: x, y, z ECR (units of a); a > 0; 0 <= f < 1.
  !> Outputs: lat, lon (radians; lon = atan2(y, x), 0 on the axis), h (signed
  !> distance to the ellipsoid, units of a); nx, ny, nz: the unit outward
  !> normal of the ellipsoid at the foot point (the gradient of h).
  !> On the equatorial plane inside the evolute the foot point is not unique;
  !> the northern one is returned.
  elemental subroutine ecr_to_geodetic(x, y, z, a, f, lat, lon, h, nx, ny, nz)
    real(dp), intent(in) :: x, y, z, a, f
    real(dp), intent(out) :: lat, lon, h
    real(dp), intent(out), optional :: nx, ny, nz
    call geodetic_newton(x, y, z, a, f, .true., lat, lon, h, nx, ny, nz)
  end subroutine ecr_to_geodetic

  !> Exact ECR -> geodetic conversion without Bowring's start: as
  !> ecr_to_geodetic (the same Newton on Eberly's F(t) in the same shrinking
  !> bracket, the same stopping rule and special cases), started from t = 0
  !> (the point's own ellipsoid level) instead of Bowring's one-step estimate.
  !> For points within ~10 km of the ellipsoid it needs 2-3 Newton steps and no
  !> atan2/sin/cos for the start (~100 ns less per call, measured in the DSM
  !> fast path); results equal ecr_to_geodetic's to its ~1e-15 relative
  !> accuracy, not bit for bit. Used by pi_dsm_fast.
  !>
  !> Inputs: x, y, z ECR (units of a); a > 0; 0 <= f < 1.
  !> Outputs: lat, lon (radians; lon = atan2(y, x), 0 on the axis), h (signed
  !> distance to the ellipsoid, units of a); nx, ny, nz: the unit outward
  !> normal of the ellipsoid at the foot point (the gradient of h).
  !> On the equatorial plane inside the evolute the foot point is not unique;
  !> the northern one is returned.
  elemental subroutine ecr_to_geodetic_nb(x, y, z, a, f, lat, lon, h, nx, ny, nz)
    real(dp), intent(in) :: x, y, z, a, f
    real(dp), intent(out) :: lat, lon, h
    real(dp), intent(out), optional :: nx, ny, nz
    call geodetic_newton(x, y, z, a, f, .false., lat, lon, h, nx, ny, nz)
  end subroutine ecr_to_geodetic_nb

  !> Exact ECR -> geodetic conversion of a point near a converted reference
  !> (lat_r, lon_r and its unit normal nx_r, ny_r, nz_r), with h_est an
  !> estimate of the point's height (e.g. the reference's tangent along a ray).
  !> Results equal ecr_to_geodetic_nb's to its ~1e-15 relative accuracy (not
  !> bit for bit); it falls back to it on the axis, the equatorial plane, or
  !> where the point's normal is more than 0.01 rad from the reference's.
  !>
  !> * Newton on Eberly's F(t) in the same shrinking bracket (eberly_root), started at
  !>   t = h_est a^2 / N_r (h = t N / a^2 at the foot point). A Newton step d
  !>   leaves an error <= (F''/2|F'|) d^2 <= 1.5 d^2 / (t + b^2) after it, so
  !>   a step |d| <= 1e-8 (|t| + a^2) is accepted (error <= 1.5e-16 (a/b)^2
  !>   relative: inside the stopping rule's 1e-15) without the confirming step.
  !> * lat = lat_r + atan(tan(lat - lat_r)), lon likewise, the tangents from
  !>   the foot point's gradient and (x, y) against the reference's normal,
  !>   atan by its series to z^9 for |z| <= 0.01 (truncation <= 1e-23).
  !>
  !> Inputs: x, y, z ECR (units of a); a > 0; 0 <= f < 1; the reference;
  !> h_est (units of a). Outputs as ecr_to_geodetic_nb (lon may pass +-pi by
  !> the increment's size only: it is wrapped back into [-pi, pi]).
  elemental subroutine ecr_to_geodetic_near(x, y, z, a, f, lat_r, lon_r, nx_r, ny_r, nz_r, h_est, &
                                            lat, lon, h, nx, ny, nz)
    real(dp), intent(in) :: x, y, z, a, f, lat_r, lon_r, nx_r, ny_r, nz_r, h_est
    real(dp), intent(out) :: lat, lon, h, nx, ny, nz
    real(dp) :: b, a2, b2, e2, y0, y1, t, lo, hi, g0, g1, gn, cr, sr, den, arg
    real(dp) :: rho
    b = a * (1.0_dp - f)
    a2 = a * a
    b2 = b * b
    e2 = f * (2.0_dp - f)
    y0 = sqrt(x * x + y * y)
    y1 = abs(z)
    cr = sqrt(nx_r * nx_r + ny_r * ny_r)                    ! cos and sin of the reference latitude
    sr = nz_r
    den = nx_r * x + ny_r * y
    if (y1 == 0.0_dp .or. y0 == 0.0_dp .or. .not. (cr > 1.0e-6_dp .and. den > 0.0_dp) &
        .or. .not. (abs(nx_r * y - ny_r * x) <= 1.0e-2_dp * den)) then
      call geodetic_newton(x, y, z, a, f, .false., lat, lon, h, nx, ny, nz)
      return
    end if
    lo = -b2 + b * y1
    hi = -b2 + sqrt(a2 * y0 * y0 + b2 * y1 * y1)
    t = eberly_root(y0, y1, a, b, h_est * a * sqrt(1.0_dp - e2 * sr * sr), lo, hi, .true.)   ! h_est a^2 / N_r
    ! the foot point's gradient direction (x0/a2, x1/b2) with x0 = a2 y0/(t + a2), x1 = b2 y1/(t + b2)
    g0 = y0 / (t + a2)
    g1 = sign(y1 / (t + b2), z)
    gn = sqrt(g0 * g0 + g1 * g1)
    h = t * gn
    ! latitude: the increment on lat_r, tan(d) = (cr g1 - sr g0) / (cr g0 + sr g1)
    den = cr * g0 + sr * g1
    arg = (cr * g1 - sr * g0) / den
    if (den > 0.0_dp .and. abs(arg) <= 1.0e-2_dp) then
      lat = lat_r + atan_small(arg)
    else
      lat = atan2(g1, g0)
    end if
    ! longitude: the increment on lon_r against the reference's horizontal direction (nx_r, ny_r)
    arg = (nx_r * y - ny_r * x) / (nx_r * x + ny_r * y)
    lon = lon_r + atan_small(arg)
    if (lon > pi_) lon = lon - 2.0_dp * pi_
    if (lon < -pi_) lon = lon + 2.0_dp * pi_
    ! the normal (cos(lat) x/y0, cos(lat) y/y0, sin(lat)), cos(lat) = g0/gn: one division
    rho = 1.0_dp / (gn * y0)
    nx = g0 * x * rho
    ny = g0 * y * rho
    nz = g1 * y0 * rho
  contains
    elemental function atan_small(zz) result(v)
      real(dp), intent(in) :: zz
      real(dp) :: v, w
      w = zz * zz
      v = zz * (1.0_dp + w * (-1.0_dp / 3.0_dp + w * (0.2_dp + w * (-1.0_dp / 7.0_dp + w / 9.0_dp))))
    end function atan_small
  end subroutine ecr_to_geodetic_near

  !> The root t of Eberly's F(t) = (a y0/(t + a^2))^2 + (b y1/(t + b^2))^2 - 1
  !> (convex, decreasing on (-b^2, inf)) by Newton from t0 inside the bracket
  !> (lo, hi), which bisection keeps shrinking: at most geo_maxit steps. Stops
  !> at a step <= 1e-15 (|t| + a^2) or a closed bracket; with early, also after a
  !> Newton step d <= 1e-8 (|t| + a^2) (t > -b^2/2), which leaves an error
  !> <= 1.5 d^2 / (t + b^2) (F''/2|F'| <= 1.5/(t + b^2)): 1.5e-16 relative.
  elemental function eberly_root(y0, y1, a, b, t0, lo0, hi0, early) result(t)
    real(dp), intent(in) :: y0, y1, a, b, t0, lo0, hi0
    logical, intent(in) :: early
    real(dp) :: t
    t = eberly_solve(y0, y1, a, b, a * a, b * b, t0, lo0, hi0, a * a, early, .false.)
  end function eberly_root

  !> The root u = t + b^2 of Eberly's F written in u, F(u) = (a y0/(u + c^2))^2
  !> + (b y1/u)^2 - 1 with c^2 = a^2 - b^2 = a^2 e^2 (convex, decreasing on u > 0),
  !> for roots near t = -b^2, where t + b^2 cancels: Newton from u0 (or, inside the
  !> evolute, the root's limit for y1 -> 0) in the bracket [b y1, sqrt(a^2 y0^2 + b^2 y1^2)],
  !> bisected geometrically while it spans more than a factor 4 (the root may lie
  !> hundreds of decades below its top); stops at a step <= 1e-15 u or a closed bracket.
  elemental function eberly_root_u(y0, y1, a, b, u0) result(u)
    real(dp), intent(in) :: y0, y1, a, b, u0
    real(dp) :: u, lo, hi, c2, q
    c2 = a * a * ((1.0_dp - b / a) * (1.0_dp + b / a))   ! a^2 - b^2 without cancelling a^2 against b^2
    lo = max(b * y1, tiny(1.0_dp))
    hi = sqrt((a * y0)**2 + (b * y1)**2)
    ! start: u = b^2 y1 / x1 with the foot point (x0, x1) of the equatorial plane's case
    u = u0
    q = a * y0 / c2
    if (q < 1.0_dp) then
      q = b * y1 / sqrt((1.0_dp - q) * (1.0_dp + q))
      if (q > lo .and. q < hi) u = q
    end if
    u = eberly_solve(y0, y1, a, b, c2, 0.0_dp, u, lo, hi, 0.0_dp, .false., .true.)
  end function eberly_root_u

  !> The root x of G(x) = (a y0/(x + sa))^2 + (b y1/(x + sb))^2 - 1 (convex and
  !> decreasing right of -min(sa, sb)) by Newton from x0 inside the bracket
  !> (lo0, hi0), which bisection keeps shrinking (geometric: halving the bracket's
  !> logarithm while hi > 4 lo > 0): at most geo_maxit steps. Stops at a step
  !> <= 1e-15 (|x| + scale) or a closed bracket; with early, also after a Newton
  !> step d <= 1e-8 (|x| + scale) at x > -sb/2. Eberly's F(t) is sa = a^2,
  !> sb = b^2, scale = a^2 (eberly_root); F(u) is sa = a^2 - b^2, sb = 0, scale =
  !> 0 (eberly_root_u).
  elemental function eberly_solve(y0, y1, a, b, sa, sb, x0, lo0, hi0, scale, early, geometric) result(x)
    real(dp), intent(in) :: y0, y1, a, b, sa, sb, x0, lo0, hi0, scale
    logical, intent(in) :: early, geometric
    real(dp) :: x, lo, hi, q0, q1, fv, dfv, xn, i0, i1
    integer :: it
    logical :: newton
    lo = lo0
    hi = hi0
    x = x0
    if (.not. (x > lo .and. x < hi)) x = bracket_mid(lo, hi, geometric)
    do it = 1, geo_maxit
      ! G and G' with two divisions (1/(x + sa), 1/(x + sb)) instead of four
      i0 = 1.0_dp / (x + sa)
      i1 = 1.0_dp / (x + sb)
      q0 = a * y0 * i0
      q1 = b * y1 * i1
      q0 = q0 * q0
      q1 = q1 * q1
      fv = q0 + q1 - 1.0_dp
      if (fv > 0.0_dp) then
        lo = x
      else if (fv < 0.0_dp) then
        hi = x
      else
        exit
      end if
      dfv = -2.0_dp * (q0 * i0 + q1 * i1)
      xn = x - fv / dfv
      newton = xn > lo .and. xn < hi
      if (.not. newton) xn = bracket_mid(lo, hi, geometric)
      if (abs(xn - x) <= 1.0e-15_dp * (abs(x) + scale) .or. .not. (hi - lo > 0.0_dp) .or. &
          (early .and. newton .and. x > -0.5_dp * sb .and. abs(xn - x) <= 1.0e-8_dp * (abs(x) + scale))) then
        x = xn
        exit
      end if
      x = xn
    end do
  end function eberly_solve

  !> The bisection point of the bracket (lo, hi): the geometric mean while the bracket
  !> spans more than a factor 4 above zero and geometric is set, else the midpoint.
  elemental function bracket_mid(lo, hi, geometric) result(m)
    real(dp), intent(in) :: lo, hi
    logical, intent(in) :: geometric
    real(dp) :: m
    if (geometric .and. lo > 0.0_dp .and. hi > 4.0_dp * lo) then
      m = sqrt(lo) * sqrt(hi)
    else
      m = 0.5_dp * (lo + hi)
    end if
  end function bracket_mid

  !> The exact conversion behind ecr_to_geodetic (bowring = .true.: Newton
  !> started from Bowring's one-step estimate) and ecr_to_geodetic_nb
  !> (.false.: started from t = 0); everything else is shared: Eberly's F(t),
  !> the shrinking bracket, the stopping rule and the special cases.
  elemental subroutine geodetic_newton(x, y, z, a, f, bowring, lat, lon, h, nx, ny, nz)
    real(dp), intent(in) :: x, y, z, a, f
    logical, intent(in) :: bowring
    real(dp), intent(out) :: lat, lon, h
    real(dp), intent(out), optional :: nx, ny, nz
    real(dp) :: b, a2, b2, e2, y0, y1, x0, x1, t, lo, hi, g0, g1, gn
    real(dp) :: latb, hb, sl, nn, rho, u, c2
    logical :: plane
    b = a * (1.0_dp - f)
    a2 = a * a
    b2 = b * b
    e2 = f * (2.0_dp - f)
    y0 = sqrt(x * x + y * y)
    y1 = abs(z)
    ! within 1e-250 a of the equatorial plane the point is on it for double precision
    ! (its foot point's z differs from the plane's by less than one in 1e250 of a; the
    ! root for u = t + b^2 would underflow): the plane's closed forms, z's sign kept
    plane = y1 <= 1.0e-250_dp * a
    if (y0 > 0.0_dp) then
      lon = atan2(y, x)
    else
      lon = 0.0_dp
    end if
    if (plane .and. y0 >= (a2 - b2) / a) then      ! equatorial plane, outside the evolute
      x0 = a
      x1 = 0.0_dp
      t = a * (y0 - a)                                     ! so that h = t * |g| below
    else if (plane) then                           ! equatorial plane inside the evolute
      x0 = a2 * y0 / (a2 - b2)
      x1 = b * sqrt(max(0.0_dp, 1.0_dp - (x0 / a)**2))
      t = -b2
    else if (y0 == 0.0_dp) then                           ! on the polar axis
      x0 = 0.0_dp
      x1 = b
      t = b * (y1 - b)
    else if (f == 0.0_dp) then
      ! a sphere: the foot point is along the radius. In closed form, because Eberly's
      ! t + a^2 = a |p| cancels for points near the centre (1e-16 a/|p| relative: 2e-6 m
      ! of round trip at |p| = 1e-4 a on the Moon)
      rho = hypot(y0, y1)
      x0 = a * (y0 / rho)
      x1 = a * (y1 / rho)
      t = a * (rho - a)
    else
      ! Eberly: F(t) = (a y0/(t+a2))^2 + (b y1/(t+b2))^2 - 1, decreasing on (-b2, inf)
      lo = -b2 + b * y1
      hi = -b2 + sqrt(a2 * y0 * y0 + b2 * y1 * y1)
      if (bowring) then
        ! start: Bowring's estimate, h = t |grad|, |grad| = N / a^2 at the foot point
        call ecr_to_geodetic_bowring(y0, 0.0_dp, y1, a, f, latb, nn, hb)
        sl = sin(latb)
        nn = a / sqrt(1.0_dp - e2 * sl * sl)
        t = hb * a2 / nn
      else
        ! start: t = 0 (F convex and decreasing: from either side of the root the
        ! Newton steps then approach it from the left)
        t = 0.0_dp
      end if
      t = eberly_root(y0, y1, a, b, t, lo, hi, .false.)
      x0 = a2 * y0 / (t + a2)
      x1 = b2 * y1 / (t + b2)
      if (t + b2 < 0.5_dp * b2 .and. a * y0 < 2.0_dp * (a2 - b2)) then
        ! inside the evolute near the equatorial plane the root lies close to -b^2 and
        ! t + b^2 keeps only log10(b^2/(t + b^2)) fewer digits: a point 7.8 km from the
        ! Earth's centre 1e-20 m off the plane came back 5,000 km from itself (a fuzz case).
        ! Solved again for u = t + b^2, which carries no such cancellation. (Only within
        ! twice the evolute's reach of the axis, y0 < 2 (a^2 - b^2)/a: elsewhere, a sphere's
        ! interior included, the root is not pinned to -b^2 and t is well conditioned.)
        u = eberly_root_u(y0, y1, a, b, t + b2)
        t = u - b2
        x0 = a2 * y0 / (u + a2 * e2)
        x1 = b2 * y1 / u
      else if (t + a2 < 0.5_dp * a2) then
        ! near the centre (|p| below ~a/2) the root lies close to -a^2 as well: t + a^2 ~ a |p|
        ! keeps only what the cancellation left, and x0 = a^2 y0/(t + a^2) with it (on a nearly
        ! round body, f = 1e-12, a point 6.4e-5 m from the Earth's centre came back 1,221 m
        ! high; an independent review, 2026-12-05). Solved again for v = t + a^2, which has no
        ! such cancellation: G(v) = (a y0/v)^2 + (b y1/(v - (a^2 - b^2)))^2 - 1 on the bracket
        ! the t-bracket becomes. Here v - (a^2 - b^2) = t + b^2 >= b^2/2 (else the branch above).
        c2 = a2 * ((1.0_dp - b / a) * (1.0_dp + b / a))          ! a^2 - b^2 without cancelling
        lo = max(c2 + b * y1, a * y0)
        hi = c2 + sqrt(a2 * y0 * y0 + b2 * y1 * y1)
        u = eberly_solve(y0, y1, a, b, 0.0_dp, -c2, t + a2, lo, hi, 0.0_dp, .false., .true.)
        t = u - a2
        x0 = a2 * y0 / u
        x1 = b2 * y1 / (u - c2)
      end if
    end if
    ! gradient direction at the foot point (x0/a2, x1/b2); h = t * |g|
    g0 = x0 / a2
    g1 = x1 / b2
    gn = sqrt(g0 * g0 + g1 * g1)
    if (y0 == 0.0_dp .or. (plane .and. y0 >= (a2 - b2) / a)) then
      h = merge(y1 - b, y0 - a, y0 == 0.0_dp)
    else if (plane) then
      h = -sqrt((y0 - x0)**2 + x1 * x1)
    else if (f == 0.0_dp) then
      h = hypot(y0, y1) - a
    else if (t + a2 < 0.5_dp * a2) then
      ! deep inside (the u and v branches above): the distance to the foot point put back on the
      ! ellipsoid. t |g| holds the height only at the exact root, and inside the evolute of a
      ! nearly round body the root is ill-conditioned (the nearest point is barely nearer than
      ! the rest): 1e-5 a of height at f = 1e-12 within 1.5 a e^2 of the centre (a review). The
      ! distance to the ellipsoid is stationary at the foot point, so a foot point off by d
      ! moves it by ~d^2 / a only.
      rho = sqrt((x0 / a)**2 + (x1 / b)**2)
      h = -hypot(y0 - x0 / rho, y1 - x1 / rho)
    else
      h = t * gn
    end if
    lat = atan2(g1, g0)
    if (z < 0.0_dp) lat = -lat
    if (present(nx)) then
      rho = g0 / gn                                    ! cos(lat)
      if (y0 > 0.0_dp) then
        nx = rho * x / y0
        ny = rho * y / y0
      else
        nx = rho
        ny = 0.0_dp
      end if
    end if
    if (present(nz)) nz = sign(g1 / gn, z)
  end subroutine geodetic_newton

end module pi_geodetic
