!> The reference oblate spheroid: normal (eqs. 46-50), radius (eq. 61) and
!> the tangent point of a line of sight (section 2.4.1, eqs. 51-58).
!>
!> The spheroid is x^2 + y^2 + z^2/(1-e^2) = re^2 (eq. 49) with flattening f
!> (eq. 47), e^2 = f(2-f) (eq. 48) and polar radius re(1-f). With f = 0 and
!> re = 1 (Table 1's setting for irregular bodies) it is the unit sphere and
!> the tangent point reduces to the spherical one (eq. 20).
module pi_spheroid
  use pi_kinds, only: dp
  use pi_vector, only: cross, unit_vector
  implicit none
  private

  public :: spheroid_normal, spheroid_radius, tangent_spheroid, tangent_paper, tangent_exact

  !> Newton iterations allowed for the exact tangent point, and its tolerance (radians).
  integer, parameter :: newton_maxit = 50
  real(dp), parameter :: newton_tol = 1.0e-15_dp

  !> tangent_mode values.
  integer, parameter, public :: tangent_mode_paper = 0, tangent_mode_exact = 1

contains

  !> Outward normal of the spheroid at (or through) point x, eq. 50
  !> (un-normalised): n = (x, y, z/(1-e^2)).
  pure function spheroid_normal(x, f) result(n)
    real(dp), intent(in) :: x(3), f
    real(dp) :: n(3)
    n = [x(1), x(2), x(3)/(1.0_dp - f*(2.0_dp - f))]
  end function spheroid_normal

  !> Radius of the spheroid at planetocentric latitude lat (radians), eq. 61:
  !> r_c = sqrt(re^2 (1-e^2) / (1 - e^2 cos^2 lat)).
  pure function spheroid_radius(lat, f, re) result(r)
    real(dp), intent(in) :: lat, f, re
    real(dp) :: r, e2
    e2 = f*(2.0_dp - f)
    r = sqrt(re*re*(1.0_dp - e2) / (1.0_dp - e2*cos(lat)**2))
  end function spheroid_radius

  !> Tangent point of the line x = s + a l on the spheroid (f, re).
  !>
  !> mode tangent_mode_paper: the paper's construction, eqs. 53-58;
  !> mode tangent_mode_exact: the point pair of least distance, by Newton
  !> iteration started from the paper's point (see tangent_exact).
  !>
  !> Outputs: tc (on the line), sc (on the spheroid below tc), d = |tc - sc|
  !> (eq. 58) with the sign of the side of the spheroid that tc lies on
  !> (negative inside: the line dips below the spheroid).
  pure subroutine tangent_spheroid(s, l, f, re, mode, tc, sc, d)
    real(dp), intent(in) :: s(3), l(3), f, re
    integer, intent(in) :: mode
    real(dp), intent(out) :: tc(3), sc(3), d
    if (mode == tangent_mode_exact) then
      call tangent_exact(s, l, f, re, tc, sc, d)
    else
      call tangent_paper(s, l, f, re, tc, sc, d)
    end if
  end subroutine tangent_spheroid

  !> The paper's oblate tangent point (the paper's ztangent_ellipsoid), eqs. 54-58.
  !>
  !> Stretch z by w = 1/(1-f) (eq. 54) so the spheroid becomes a sphere of
  !> radius re; t'c is the foot of the perpendicular from the centre to the
  !> stretched line (eq. 55, written as s' - (s'.l')l' so that it holds for
  !> either sign of s'.l'); s'c = t'c re/|t'c| (eq. 56); scale back to get
  !> sc, then a = l.(sc - s) (eq. 53), tc = s + a l (eq. 57), d = |tc - sc|
  !> (eq. 58), signed. The spheroid normal at sc is perpendicular to l, but
  !> tc - sc is parallel to that normal only when d = 0 or by symmetry: for
  !> d /= 0 this is an approximation of the nearest point (docs/paper-notes.md).
  pure subroutine tangent_paper(s, l, f, re, tc, sc, d)
    real(dp), intent(in) :: s(3), l(3), f, re
    real(dp), intent(out) :: tc(3), sc(3), d
    real(dp) :: w, sp(3), lp(3), tp(3), a
    w = 1.0_dp/(1.0_dp - f)                               ! eq. 54
    sp = [s(1), s(2), s(3)*w]
    lp = unit_vector([l(1), l(2), l(3)*w])
    tp = sp - dot_product(sp, lp)*lp                      ! eq. 55
    if (norm2(tp) > 0.0_dp) then
      sc = tp*(re/norm2(tp))                              ! eq. 56
    else
      sc = unit_vector(perpendicular(lp))*re              ! line through the centre: any silhouette point
    end if
    sc(3) = sc(3)/w                                       ! back to planet coordinates
    a = dot_product(l, sc - s)                            ! eq. 53
    tc = s + a*l                                          ! eq. 57
    d = norm2(tc - sc)                                    ! eq. 58
    if (norm2(tp) < re) d = -d
  end subroutine tangent_paper

  !> Exact tangent point: the points tc on the line and sc on the spheroid at
  !> which the line is closest to (or, if it enters, deepest inside) the
  !> spheroid, so that tc - sc lies along the spheroid normal at sc and is
  !> perpendicular to l (the condition of eqs. 51-52 and Fig. 6a).
  !>
  !> Particulars. sc lies on the silhouette of the spheroid seen along l, the
  !> points whose normal is perpendicular to l. In the stretched frame of eq.
  !> 54 that silhouette is the great circle of radius re perpendicular to l',
  !> sc(beta) = W^-1 re (cos(beta) u + sin(beta) v), u = t'c/|t'c| (beta = 0 is
  !> the paper's point), v = l' x u. The squared distance of sc(beta) from the
  !> line, F(beta) = |P (sc(beta) - s)|^2 with P = I - l l^T, is minimised by
  !> Newton's method from beta = 0 (a few iterations: beta is O(f)).
  pure subroutine tangent_exact(s, l, f, re, tc, sc, d)
    real(dp), intent(in) :: s(3), l(3), f, re
    real(dp), intent(out) :: tc(3), sc(3), d
    real(dp) :: w, sp(3), lp(3), tp(3), u(3), v(3), a(3), b(3), c(3), q(3), qb(3), qbb(3)
    real(dp) :: beta, g1, g2, step, cb, sb, x(3), ntp
    integer :: it
    w = 1.0_dp/(1.0_dp - f)
    sp = [s(1), s(2), s(3)*w]
    lp = unit_vector([l(1), l(2), l(3)*w])
    tp = sp - dot_product(sp, lp)*lp
    ntp = norm2(tp)
    if (ntp > 0.0_dp) then
      u = tp/ntp
    else
      u = unit_vector(perpendicular(lp))
    end if
    v = cross(lp, u)
    ! silhouette point sc(beta) = A' cos(beta) + B' sin(beta), in planet coordinates
    a = re*[u(1), u(2), u(3)/w]
    b = re*[v(1), v(2), v(3)/w]
    ! components perpendicular to l
    a = a - dot_product(a, l)*l
    b = b - dot_product(b, l)*l
    c = s - dot_product(s, l)*l
    beta = 0.0_dp
    cb = 1.0_dp                                            ! cos and sin of beta = 0
    sb = 0.0_dp
    do it = 1, newton_maxit
      if (it > 1) then
        cb = cos(beta)
        sb = sin(beta)
      end if
      q = a*cb + b*sb - c
      qb = -a*sb + b*cb
      qbb = -a*cb - b*sb
      g1 = dot_product(q, qb)                              ! F'/2
      g2 = dot_product(qb, qb) + dot_product(q, qbb)       ! F''/2
      if (g2 > 0.0_dp) then
        step = -g1/g2
      else
        step = -sign(1.0e-3_dp, g1)                        ! not convex here: walk downhill
      end if
      step = max(-0.5_dp, min(0.5_dp, step))
      beta = beta + step
      if (abs(step) <= newton_tol) exit
    end do
    x = re*(cos(beta)*u + sin(beta)*v)
    sc = [x(1), x(2), x(3)/w]
    tc = s + dot_product(l, sc - s)*l                      ! eqs. 53, 57
    d = norm2(tc - sc)                                     ! eq. 58
    if (tc(1)**2 + tc(2)**2 + (tc(3)*w)**2 < re*re) d = -d
  end subroutine tangent_exact

  !> A vector perpendicular to a (a /= 0).
  pure function perpendicular(a) result(p)
    real(dp), intent(in) :: a(3)
    real(dp) :: p(3)
    if (abs(a(1)) <= abs(a(2)) .and. abs(a(1)) <= abs(a(3))) then
      p = cross(a, [1.0_dp, 0.0_dp, 0.0_dp])
    else if (abs(a(2)) <= abs(a(3))) then
      p = cross(a, [0.0_dp, 1.0_dp, 0.0_dp])
    else
      p = cross(a, [0.0_dp, 0.0_dp, 1.0_dp])
    end if
  end function perpendicular

end module pi_spheroid
