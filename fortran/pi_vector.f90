!> Small vector and angle helpers: the paper's `zcrossp`, `zrotate_about_vector`,
!> `flondiff` (the function Delta of section 2.2) and `fvsep`, plus the
!> Cartesian <-> planetocentric conversions of eqs. 13-15 and 29-30.
!>
!> All angles are in radians. All routines are pure.
module pi_vector
  use pi_kinds, only: dp
  implicit none
  private

  public :: pi, deg, rad, cross, unit_vector, rotate_about_vector, lon_diff, vsep, &
            latlon_of, xyz_of, axis_distance, far_distance

  !> pi to double precision.
  real(dp), parameter :: pi = 3.14159265358979323846264338327950288_dp
  !> Degrees per radian.
  real(dp), parameter :: deg = 180.0_dp / pi
  !> Radians per degree.
  real(dp), parameter :: rad = pi / 180.0_dp

contains

  !> Cross product `a x b` (the paper's zcrossp; eq. 16 uses it).
  pure function cross(a, b) result(c)
    real(dp), intent(in) :: a(3), b(3)
    real(dp) :: c(3)
    c(1) = a(2)*b(3) - a(3)*b(2)
    c(2) = a(3)*b(1) - a(1)*b(3)
    c(3) = a(1)*b(2) - a(2)*b(1)
  end function cross

  !> `a / |a|`; the zero vector is returned unchanged.
  pure function unit_vector(a) result(u)
    real(dp), intent(in) :: a(3)
    real(dp) :: u(3), n
    n = norm2(a)
    if (n > 0.0_dp) then
      u = a / n
    else
      u = a
    end if
  end function unit_vector

  !> Rotate `v` by `angle` (radians, right-handed) about the axis `axis`
  !> (any non-zero length): Rodrigues' formula (the paper's zrotate_about_vector).
  pure function rotate_about_vector(v, axis, angle) result(w)
    real(dp), intent(in) :: v(3), axis(3), angle
    real(dp) :: w(3), k(3), c, s
    k = unit_vector(axis)
    c = cos(angle)
    s = sin(angle)
    w = v*c + cross(k, v)*s + k*dot_product(k, v)*(1.0_dp - c)
  end function rotate_about_vector

  !> The function Delta(phi1, phi2) of section 2.2: the eastward angle of
  !> `phi2` from `phi1`, in [0, 2 pi). Both in radians, any range.
  pure function lon_diff(phi1, phi2) result(delta)
    real(dp), intent(in) :: phi1, phi2
    real(dp) :: delta
    delta = modulo(phi2 - phi1, 2.0_dp*pi)
    if (delta >= 2.0_dp*pi) delta = 0.0_dp   ! modulo of a tiny negative rounds to 2 pi
  end function lon_diff

  !> Angle between two vectors in [0, pi] (the paper's fvsep), computed as
  !> atan2(|a x b|, a.b), accurate near 0 and pi where acos is not.
  pure function vsep(a, b) result(angle)
    real(dp), intent(in) :: a(3), b(3)
    real(dp) :: angle
    angle = atan2(norm2(cross(a, b)), dot_product(a, b))
  end function vsep

  !> Planetocentric latitude and east longitude (radians, lon in [0, 2 pi))
  !> of a Cartesian point: eqs. 29-30 (and 42-43, 59-60). Latitude is computed
  !> as atan2(z, sqrt(x^2+y^2)), equal to the paper's asin(z/|g|) but accurate
  !> near the poles; longitude uses the quadrant-aware atan2.
  pure subroutine latlon_of(x, lat, lon)
    real(dp), intent(in) :: x(3)
    real(dp), intent(out) :: lat, lon
    lat = atan2(x(3), hypot(x(1), x(2)))
    lon = lon_diff(0.0_dp, atan2(x(2), x(1)))
  end subroutine latlon_of

  !> Cartesian position of (lat, lon, r): eqs. 13-15 (radians).
  pure function xyz_of(lat, lon, r) result(x)
    real(dp), intent(in) :: lat, lon, r
    real(dp) :: x(3)
    x(1) = r*cos(lat)*cos(lon)
    x(2) = r*cos(lat)*sin(lon)
    x(3) = r*sin(lat)
  end function xyz_of

  !> Smallest distance from the z axis of the points s + r l, r in [r0, r1].
  pure function axis_distance(s, l, r0, r1) result(d)
    real(dp), intent(in) :: s(3), l(3), r0, r1
    real(dp) :: d, ll, rr
    ll = l(1)**2 + l(2)**2
    if (ll > 0.0_dp) then
      rr = -(s(1) * l(1) + s(2) * l(2)) / ll
    else
      rr = r0
    end if
    rr = min(max(rr, r0), r1)
    d = sqrt((s(1) + rr * l(1))**2 + (s(2) + rr * l(2))**2)
  end function axis_distance

  !> Distance along the ray to where it leaves the sphere of radius rad (0 if never inside).
  pure function far_distance(s, l, rad) result(r)
    real(dp), intent(in) :: s(3), l(3), rad
    real(dp) :: r, b, c, disc
    b = dot_product(s, l)
    c = dot_product(s, s) - rad * rad
    disc = b * b - c
    r = 0.0_dp
    if (disc > 0.0_dp) r = max(0.0_dp, -b + sqrt(disc))
  end function far_distance

end module pi_vector
