!> Exact first hit of a ray with the paper's bilinear DEM surface (eqs. 10-12,
!> with the polar caps of section 2.2), accelerated by a max-pyramid.
!>
!> The surface over one DEM cell is bilinear in (latitude, longitude), so it
!> never exceeds the largest of its four corner radii, and over a sub-box of the
!> cell its maximum is the largest of the surface values at the sub-box corners.
!> The pyramid holds, for blocks of 2^k x 2^k cells (k >= 1), the largest node
!> radius bordering the block (as float32, rounded up and one ulp more, so it is
!> never below the float64 value). A ray segment [a, b] cannot enter the surface if
!> its smallest distance from the centre is at or above the highest surface
!> radius over the latitude/longitude box the segment can touch; otherwise, where
!> the ray is still descending and enters the sphere of that radius far enough
!> into the segment, the part before the entry is dropped (it is above that
!> sphere); otherwise the segment is split where it crosses the coarsest block
!> boundary inside its box (a latitude cone or a meridian half-plane), or in the
!> middle when the box lies in one block, and the earlier part is searched
!> first: a top-down walk of the pyramid along the ray. A segment inside one cell is searched by certified
!> Newton steps on the cell's bilinear patch (cell_search). A segment shorter
!> than `tol` that cannot be excluded is tested at its middle and end; the
!> first with |g| < r is the hit, refined by bisection.
!>
!> Guarantee: every part of the ray before the returned point is either proven
!> above the surface, or lies in a tested leaf shorter than tol, or in a gap
!> shorter than tol/4 at a block boundary: the hit is the first entry into the
!> surface except for chords shorter than tol along the ray, and lies within
!> tol of that entry. The returned point is below the surface (|g| < r) and
!> within tol/1000 of a point found at or above it. No hit is reported where
!> |g| >= r.
module pi_exact
  use pi_kinds, only: dp, sp, i8
  use pi_status
  use pi_vector, only: rad, deg, pi
  use pi_dem, only: dem_t, dem_radius, dem_cell_nodes
  implicit none
  private

  public :: pyramid_t, exact_search, pyramid_attach

  !> The max-pyramid: levels 1..nlev in one flat array; level k has rows(k) x
  !> cols(k) blocks of 2^k x 2^k cells, stored column-fastest from offset off(k).
  !> Cell rows: 0 = south cap, 1..nlat-1 between DEM rows, nlat = north cap.
  type :: pyramid_t
    integer :: nlev = 0
    integer :: rows(40) = 0, cols(40) = 0
    integer(i8) :: off(40) = 0
    real(sp), pointer, contiguous :: data(:) => null()
  end type pyramid_t

  !> Stack depth of the subdivision (segments halve each level).
  integer, parameter :: max_depth = 200
  !> Most segments one ray may examine (its bound on any input; rays at 128 ppd
  !> take ~8 on average and a few hundred at most): past it the search stops
  !> with stat_unresolved (docs/paper-notes.md, note 19).
  integer, parameter :: max_nodes = 2000000
  !> A segment is shortened to where the ray enters the sphere of its box's
  !> highest radius when that cuts off at least this fraction of it (else it is
  !> split): 0.3 was the fastest of 0-0.7 on the 128 ppd limb scan.
  real(dp), parameter :: clip_min = 0.3_dp
  !> Angles (as tangents) up to which lat_near and lon_near use atan_small.
  real(dp), parameter :: small_angle = 2.0_dp**(-10)

contains

  !> Planetocentric latitude and east longitude [0, 2 pi) of x (radians): the
  !> same as pi_vector's latlon_of to an ulp or two, from one-argument atan of
  !> a ratio no larger than 1 in magnitude (or of z/rho) instead of atan2, and
  !> sqrt instead of hypot (x is never near overflow here). glibc's atan2 and
  !> hypot were a third of the search's time.
  pure subroutine ll(x, lat, lon)
    real(dp), intent(in) :: x(3)
    real(dp), intent(out) :: lat, lon
    lat = lat_of(x)
    lon = lon_of(x)
  end subroutine ll

  !> Planetocentric latitude of x (radians), as in ll.
  pure real(dp) function lat_of(x) result(lat)
    real(dp), intent(in) :: x(3)
    real(dp) :: rho
    rho = rho_of(x)
    if (rho > 0.0_dp) then
      lat = atan(x(3)/rho)
    else
      lat = sign(0.5_dp*pi, x(3))
      if (x(3) == 0.0_dp) lat = 0.0_dp
    end if
  end function lat_of

  !> atan(u) for |u| <= small_angle, by its series to u^7 (the next term, u^9/9,
  !> is below 1e-28).
  pure real(dp) function atan_small(u)
    real(dp), intent(in) :: u
    real(dp) :: u2
    u2 = u*u
    atan_small = u - u*u2*(1.0_dp/3.0_dp - u2*(0.2_dp - u2/7.0_dp))
  end function atan_small

  !> Latitude of x (radians) from the latitude lat0 of a nearby point x0: lat0
  !> plus the angle between (rho, z) and (rho0, z0), by atan_small when that is
  !> small (within a cell, or a split of a fine segment), else lat_of. glibc's
  !> atan, with its rounding-mode save/restore, was 12 % of the hit rays' time.
  !> rho, rho0: the distances of x and x0 from the axis (rho_of), which the
  !> callers have at hand.
  pure real(dp) function lat_near(x, rho, x0, rho0, lat0) result(lat)
    real(dp), intent(in) :: x(3), rho, x0(3), rho0, lat0
    real(dp) :: c, d
    c = x(3)*rho0 - x0(3)*rho
    d = rho*rho0 + x(3)*x0(3)
    if (d > 0.0_dp .and. abs(c) <= small_angle*d) then
      lat = lat0 + atan_small(c/d)
    else
      lat = lat_of(x)
    end if
  end function lat_near

  !> Distance of x from the polar axis.
  pure real(dp) function rho_of(x)
    real(dp), intent(in) :: x(3)
    rho_of = sqrt(x(1)*x(1) + x(2)*x(2))
  end function rho_of

  !> East longitude [0, 2 pi) of x from the longitude lon0 of a nearby point x0:
  !> lon0 plus the angle between their xy projections, as lat_near.
  pure real(dp) function lon_near(x, x0, lon0) result(lon)
    real(dp), intent(in) :: x(3), x0(3), lon0
    real(dp) :: c, d
    c = x0(1)*x(2) - x0(2)*x(1)
    d = x0(1)*x(1) + x0(2)*x(2)
    if (d > 0.0_dp .and. abs(c) <= small_angle*d) then
      lon = lon0 + atan_small(c/d)
      if (lon < 0.0_dp) lon = lon + 2.0_dp*pi
      if (lon >= 2.0_dp*pi) lon = lon - 2.0_dp*pi
    else
      lon = lon_of(x)
    end if
  end function lon_near

  !> East longitude [0, 2 pi) of x (radians), as in ll.
  pure real(dp) function lon_of(x) result(lon)
    real(dp), intent(in) :: x(3)
    if (abs(x(1)) >= abs(x(2))) then
      if (x(1) == 0.0_dp) then
        lon = 0.0_dp                                  ! on the axis
      else
        lon = atan(x(2)/x(1))                         ! in [-pi/4, pi/4]
        if (x(1) < 0.0_dp) lon = lon + pi
      end if
    else
      lon = 0.5_dp*pi - atan(x(1)/x(2))               ! in (pi/4, 3 pi/4)
      if (x(2) < 0.0_dp) lon = lon + pi
    end if
    if (lon < 0.0_dp) lon = lon + 2.0_dp*pi
    if (lon >= 2.0_dp*pi) lon = 0.0_dp
  end function lon_of

  !> East longitude difference lon - lon0 wrapped into [0, 2 pi), for angles
  !> within 2 pi of each other (the exact search's longitudes lie in [0, 2 pi)):
  !> pi_vector's lon_diff without the fmod call.
  pure real(dp) function east_of(lon0, lon) result(delta)
    real(dp), intent(in) :: lon0, lon
    delta = lon - lon0
    if (delta < 0.0_dp) delta = delta + 2.0_dp*pi
    if (delta >= 2.0_dp*pi) delta = delta - 2.0_dp*pi
    if (delta < 0.0_dp) delta = 0.0_dp              ! a tiny negative plus 2 pi rounded to 2 pi
  end function east_of

  !> |x|, as sqrt of the sum of squares: gfortran's norm2 scales each term to
  !> guard against overflow (three divisions), which planetary radii never need.
  pure real(dp) function length(x)
    real(dp), intent(in) :: x(3)
    length = sqrt(x(1)*x(1) + x(2)*x(2) + x(3)*x(3))
  end function length

  !> Attach a pyramid built by the caller (planet_intersect.dem.DEM.pyramid):
  !> meta(1:3, k) = rows, columns and 0-based offset of level k in data.
  !> The arrays must outlive the pyramid_t.
  subroutine pyramid_attach(data, meta, pyr)
    real(sp), intent(in), target, contiguous :: data(:)
    integer, intent(in) :: meta(:, :)
    type(pyramid_t), intent(out) :: pyr
    integer :: k
    pyr%nlev = min(size(meta, 2), size(pyr%rows))
    do k = 1, pyr%nlev
      pyr%rows(k) = meta(1, k)
      pyr%cols(k) = meta(2, k)
      pyr%off(k) = meta(3, k)
    end do
    pyr%data => data
  end subroutine pyramid_attach

  !> Search [d_start, d_end] of the ray s + d l for its first entry into the DEM
  !> surface. hit: found; d_hit: its distance. nodes: segments examined.
  subroutine exact_search(dem, pyr, s, l, d_start, d_end, tol, hit, d_hit, nodes, stat)
    type(dem_t), intent(in) :: dem
    type(pyramid_t), intent(in) :: pyr
    real(dp), intent(in) :: s(3), l(3), d_start, d_end, tol
    logical, intent(out) :: hit
    real(dp), intent(out) :: d_hit
    integer, intent(out) :: nodes, stat
    real(dp) :: stack(6, max_depth), a, b, mid, fm, fb, la_a, lo_a, la_b, lo_b
    !> the precision of the returned entry (the leaves of the search are tol long)
    real(dp) :: tol_hit
    !> the distance along the ray of its closest approach to the centre, and the
    !> square of that distance from the centre
    real(dp) :: d_near, tn2
    !> the highest surface radius over the last excluded-or-not box (exclude)
    real(dp) :: box_top
    real(dp) :: d_in, g_in(3), g_a(3)
    !> the first row's latitude (degrees) and first column's longitude (radians),
    !> as dem_radius computes them (a division each, once per ray, not per test)
    real(dp) :: lat_first, lon_first
    integer :: top, cell_c, cell_i, box_c0, box_c1, box_i0, box_i1
    !> the cell of the last one-cell box (load_cell): its node radii (eqs. 2-5;
    !> r1, r2 south, r3, r4 north), latitude band (degrees), first longitude
    !> (radians) and d(fraction)/d(angle) in latitude and longitude (per radian;
    !> kx is the same for every cell and set once)
    real(dp) :: r1, r2, r3, r4, lat0, lat1, lon0, ky, kx
    logical :: excluded, found, done, box_full, split_ok

    hit = .false.
    d_hit = 0.0_dp
    tol_hit = 1.0e-3_dp*tol
    d_near = -dot_product(s, l)
    g_in = s + d_near*l
    tn2 = dot_product(g_in, g_in)
    lat_first = -90.0_dp + 0.5_dp/dem%ppd
    lon_first = rad*0.5_dp/dem%ppd
    kx = dem%ppd*deg
    nodes = 0
    stat = stat_ok
    ! the stack holds segment ends with their latitude and longitude, so that each
    ! point along the ray is converted once, and where the next segment resumes
    ! (after a gap shorter than tol/4 at a block boundary; see split_at_boundary)
    a = d_start
    call ll(s + a*l, la_a, lo_a)
    top = 1
    stack(1, 1) = d_end
    call ll(s + d_end*l, stack(2, 1), stack(3, 1))
    stack(4:6, 1) = stack(1:3, 1)
    do while (top > 0)
      b = stack(1, top)
      la_b = stack(2, top)
      lo_b = stack(3, top)
      nodes = nodes + 1
      if (nodes > max_nodes .or. .not. (b >= a)) then
        stat = stat_unresolved               ! budget spent, or NaN: never a guessed answer
        return
      end if
      call exclude(a, b, excluded)
      if (stat /= stat_ok) return
      if (excluded) then
        call resume()
        cycle
      end if
      if (cell_c >= 0) then
        ! inside one cell: certified steps (a lower bound of the height from its
        ! value, slope and a bound on its curvature) either reach b or the entry
        call cell_search(a, b, found, done)
        if (stat /= stat_ok) return
        if (found) then
          hit = .true.
          return
        end if
        if (done) then
          call resume()
          cycle
        end if
      end if
      if (cell_c < 0 .and. a < d_near) then
        ! the ray descends to the sphere of the box's highest radius, entering it at
        ! d_in; where that cuts off at least clip_min of [a, b], start the segment
        ! there (and test it again, in its smaller box) instead of splitting it
        d_in = box_top**2 - tn2
        if (d_in > 0.0_dp) then
          d_in = d_near - sqrt(d_in)
          if (d_in > a + clip_min*(b - a) .and. d_in < b) then
            g_in = s + d_in*l
            g_a = s + a*l
            la_a = lat_near(g_in, rho_of(g_in), g_a, rho_of(g_a), la_a)
            lo_a = lon_near(g_in, g_a, lo_a)
            a = d_in
            cycle
          end if
        end if
      end if
      if (b - a <= tol .or. top >= max_depth) then
        mid = 0.5_dp*(a + b)
        fm = height(mid)
        fb = height(b)
        if (stat /= stat_ok) return
        if (fm < 0.0_dp .or. fb < 0.0_dp) then
          ! entry in [a, x], x the first tested point below the surface
          hit = .true.
          d_hit = entry(a, merge(mid, b, fm < 0.0_dp))
          return
        end if
        call resume()
        cycle
      end if
      ! split: search the earlier part first. At the coarsest pyramid block boundary
      ! that the segment's box crosses, each part then lies in fewer and smaller
      ! blocks (a top-down walk of the pyramid); where no boundary is crossed, at
      ! the middle
      top = top + 1
      call split_at_boundary(a, b, stack(:, top), split_ok)
      if (.not. split_ok) then
        mid = 0.5_dp*(a + b)
        stack(1, top) = mid
        call ll(s + mid*l, stack(2, top), stack(3, top))
        stack(4:6, top) = stack(1:3, top)
      end if
    end do

  contains

    !> The segment ending at the top of the stack is done: move on to where the
    !> next one starts.
    subroutine resume()
      a = stack(4, top); la_a = stack(5, top); lo_a = stack(6, top)
      top = top - 1
    end subroutine resume

    !> Split [a, b] where the ray crosses the coarsest block boundary of the box
    !> found by the last exclude (a latitude cone or a meridian half-plane):
    !> entry(1:3) = the last point on a's side (distance, latitude, longitude),
    !> entry(4:6) = the first point past the boundary. The two are found by
    !> stepping out from the computed crossing until cell_row/col_of put them on
    !> either side; the gap between them (under tol/4) is not searched, which
    !> the guarantee allows (a chord shorter than tol). ok = .false. if the box
    !> crosses no boundary or the crossing cannot be placed: split at the middle.
    subroutine split_at_boundary(a, b, entry_out, ok)
      real(dp), intent(in) :: a, b
      real(dp), intent(out) :: entry_out(6)
      logical, intent(out) :: ok
      integer :: hr, hc, cb, ib, k
      real(dp) :: ga(3), phi, lam, sp2, cp2, qa, qb, qc, disc, q, t, t1, t2, nrm(3), dn, x, dx, la, lo, len
      real(dp) :: x0, g0(3), rho2, rho0, dla, dlo, la0, lo0, sb, cb_
      logical :: by_row, side_a
      ok = .false.
      hr = -1
      hc = -1
      if (box_c1 > box_c0) hr = bit_size(box_c0) - 1 - leadz(ieor(box_c0, box_c1))
      if (.not. box_full) then
        if (box_i1 >= dem%nlon) then
          hc = huge(1)                                  ! the 0/360 E seam bounds blocks of every level
        else if (box_i1 > box_i0) then
          hc = bit_size(box_i0) - 1 - leadz(ieor(box_i0, box_i1))
        end if
      end if
      if (hr < 0 .and. hc < 0) return
      len = b - a
      ga = s + a*l
      by_row = hr >= hc
      t = -1.0_dp
      if (by_row) then
        ! latitude cone phi: cos^2 phi z^2 = sin^2 phi (x^2 + y^2), z on phi's side
        cb = ishft(ishft(box_c1, -hr), hr)              ! first row of the upper block
        phi = (-90.0_dp + (cb - 0.5_dp)/dem%ppd)*rad
        sb = sin(phi)
        cb_ = cos(phi)
        sp2 = sb*sb
        cp2 = cb_*cb_
        qa = cp2*l(3)**2 - sp2*(l(1)**2 + l(2)**2)
        qb = 2.0_dp*(cp2*ga(3)*l(3) - sp2*(ga(1)*l(1) + ga(2)*l(2)))
        qc = cp2*ga(3)**2 - sp2*(ga(1)**2 + ga(2)**2)
        disc = qb*qb - 4.0_dp*qa*qc
        if (disc < 0.0_dp) return
        q = -0.5_dp*(qb + sign(sqrt(disc), qb))
        t1 = -1.0_dp
        t2 = -1.0_dp
        if (qa /= 0.0_dp) t1 = q/qa
        if (q /= 0.0_dp) t2 = qc/q
        ! keep the roots inside the segment and on phi's nappe of the cone
        if (.not. (t1 > 0.0_dp .and. t1 < len .and. (ga(3) + t1*l(3))*phi > 0.0_dp)) t1 = -1.0_dp
        if (.not. (t2 > 0.0_dp .and. t2 < len .and. (ga(3) + t2*l(3))*phi > 0.0_dp)) t2 = -1.0_dp
        if (t1 > 0.0_dp .and. t2 > 0.0_dp) then
          t = min(t1, t2)
        else
          t = max(t1, t2)
        end if
        ib = 0
        side_a = cell_row(la_a) >= cb
      else
        ! meridian half-plane lam: (x, y) . (-sin lam, cos lam) = 0, (x, y) . (cos lam, sin lam) > 0
        if (hc == huge(1)) then
          ib = dem%nlon
        else
          ib = ishft(ishft(box_i1, -hc), hc)
        end if
        lam = (ib + 0.5_dp)/dem%ppd*rad
        sb = sin(lam)
        cb_ = cos(lam)
        nrm = [-sb, cb_, 0.0_dp]
        dn = dot_product(l, nrm)
        if (dn == 0.0_dp) return
        t = -dot_product(ga, nrm)/dn
        if ((ga(1) + t*l(1))*cb_ + (ga(2) + t*l(2))*sb <= 0.0_dp) return
        cb = 0
        side_a = col_past(lo_a, ib)
      end if
      if (.not. (t > 0.0_dp .and. t < len)) return
      x = a + t
      ! step out from x until the two points fall on either side; within a few
      ! tol/512 of x, latitude and longitude are linear in the distance to far
      ! below rounding (the steps are ~1e-12 of the radius), so the points beside
      ! x take them from x's values and their derivatives along the ray
      entry_out(1) = -1.0_dp
      entry_out(4) = -1.0_dp
      dx = tol/512.0_dp
      x0 = x
      g0 = s + x0*l
      rho2 = g0(1)*g0(1) + g0(2)*g0(2)
      if (rho2 <= 0.0_dp) return                      ! on the axis: split at the middle
      rho0 = sqrt(rho2)
      dla = (l(3)*rho2 - g0(3)*(g0(1)*l(1) + g0(2)*l(2)))/(rho0*(rho2 + g0(3)*g0(3)))
      dlo = (g0(1)*l(2) - g0(2)*l(1))/rho2
      ! the crossing's own coordinate is the boundary's (to the root's rounding)
      if (by_row) then
        la0 = phi
        lo0 = lon_near(g0, ga, lo_a)
      else
        la0 = lat_near(g0, rho0, ga, rho_of(ga), la_a)
        lo0 = east_of(0.0_dp, lam)
      end if
      la = la0
      lo = lo0
      if (past(by_row, cb, ib, la, lo) .eqv. side_a) then
        entry_out(1:3) = [x, la, lo]
      else
        entry_out(4:6) = [x, la, lo]
      end if
      do k = 1, 8
        if (entry_out(1) < 0.0_dp) then
          x = entry_out(4) - dx
          if (x <= a) return
          la = la0 + (x - x0)*dla
          lo = east_of(0.0_dp, lo0 + (x - x0)*dlo)
          if (past(by_row, cb, ib, la, lo) .eqv. side_a) entry_out(1:3) = [x, la, lo]
        else if (entry_out(4) < 0.0_dp) then
          x = entry_out(1) + dx
          if (x >= b) return
          la = la0 + (x - x0)*dla
          lo = east_of(0.0_dp, lo0 + (x - x0)*dlo)
          if (.not. (past(by_row, cb, ib, la, lo) .eqv. side_a)) entry_out(4:6) = [x, la, lo]
        else
          exit
        end if
        dx = 2.0_dp*dx
      end do
      ok = entry_out(1) > a .and. entry_out(4) > entry_out(1) .and. entry_out(4) < b
    end subroutine split_at_boundary

    !> Whether the point at latitude/longitude (la, lo) lies past boundary row cb
    !> (by_row) or column ib.
    logical function past(by_row, cb, ib, la, lo)
      logical, intent(in) :: by_row
      integer, intent(in) :: cb, ib
      real(dp), intent(in) :: la, lo
      if (by_row) then
        past = cell_row(la) >= cb
      else
        past = col_past(lo, ib)
      end if
    end function past

    !> Whether east longitude lon (radians) lies in a cell column at or past ib,
    !> counting columns from box_i0 eastwards across the seam.
    logical function col_past(lon, ib)
      real(dp), intent(in) :: lon
      integer, intent(in) :: ib
      integer :: u
      u = min(int(east_of(lon_first, lon)*deg*dem%ppd), dem%nlon - 1)
      if (u < box_i0) u = u + dem%nlon
      col_past = u >= ib
    end function col_past

    !> First entry of the ray into the surface over [a, b], which lies in cell
    !> load_cell's cell. With K >= |f''| on the cell (f = |g| - R along the ray):
    !>   f(x + t) >= f(x) + f'(x) t - K t^2 / 2,
    !> so no root lies before the positive root t* of the right-hand side; the
    !> search moves x by t* (a Newton step from the safe side) until x passes b
    !> (done, no entry) or the bound puts the surface within tol_hit of x; the
    !> point tol_hit further on is then the entry if it is below the surface
    !> (found), else the steps go on from there. K comes from the bilinear patch:
    !> R_tt = R_pp = 0, and along a line |theta'| <= 1/r, |phi'| <= 1/rho,
    !> |theta''| <= (2 + |tan theta|)/r^2, |phi''| <= 2/rho^2, ||g|''| <= 1/r, so
    !> |f''| <= 1/r + 2|R_tp|/(r rho) + |R_t| (2 + |tan theta|)/r^2 + 2|R_p|/rho^2.
    !> If the steps stall (more than 200), done = .false. hands [a, b] back to
    !> the subdivision.
    subroutine cell_search(a, b, found, done)
      real(dp), intent(in) :: a, b
      logical, intent(out) :: found, done
      real(dp) :: rt, rp, rtp, rlo, clo, tlo, k, x, f, fp
      real(dp) :: g(3), gn, la, lo_, ct, st_, cp, sp_, nh(3), eh(3), rh, th1, fy, fxx, t, lo2, hi2, fx2, x2, x_prev
      real(dp) :: ga(3), rho_a
      integer :: j
      found = .false.
      done = .false.
      rt = max(abs(r3 - r1), abs(r4 - r2))*ky
      rp = max(abs(r2 - r1), abs(r4 - r3))*kx
      rtp = abs(r1 - r2 - r3 + r4)*ky*kx
      rlo = length(s + min(max(d_near, a), b)*l)
      th1 = max(abs(lat0), abs(lat1))*rad
      clo = cos(th1)
      if (clo <= 1.0e-9_dp) return                     ! at a pole: leave it to the subdivision
      tlo = tan(th1)
      k = (1.0_dp/rlo + 2.0_dp*rtp/(rlo*rlo*clo) + rt*(2.0_dp + tlo)/rlo**2 + 2.0_dp*rp/(rlo*clo)**2) &
          *1.001_dp + 1.0e-12_dp
      ga = s + a*l
      rho_a = rho_of(ga)
      x = a
      x_prev = a
      do j = 1, 200
        ! height and its slope at x, within this cell's patch
        g = s + x*l
        gn = length(g)
        rh = rho_of(g)                                 ! > 0: the poles are left to the subdivision
        la = lat_near(g, rh, ga, rho_a, la_a)
        lo_ = lon_near(g, ga, lo_a)
        ct = rh/gn; st_ = g(3)/gn; cp = g(1)/rh; sp_ = g(2)/rh
        nh = [-st_*cp, -st_*sp_, ct]                   ! local north
        eh = [-sp_, cp, 0.0_dp]                        ! local east
        fy = frac_lat(la)
        fxx = frac_lon(lo_)
        f = gn - patch(fy, fxx)
        fp = dot_product(g, l)/gn &
             - ((r3 - r1)*(1.0_dp - fxx) + (r4 - r2)*fxx)*ky*dot_product(l, nh)/gn &
             - ((r2 - r1)*(1.0_dp - fy) + (r4 - r3)*fy)*kx*dot_product(l, eh)/max(rh, 1.0e-300_dp)
        if (f < 0.0_dp) then
          ! below already (the bound is tight only to rounding): the entry lies after
          ! x_prev, the last point known to be at or above the surface
          lo2 = x_prev; hi2 = x
          exit
        end if
        t = (fp + sqrt(fp*fp + 2.0_dp*k*f))/k       ! first zero of f + fp t - k t^2/2
        if (x + t >= b) then
          done = .true.
          return
        end if
        if (t <= tol_hit) then
          ! the surface is within tol_hit: look just ahead for the entry
          x2 = min(x + tol_hit, b)
          fx2 = height(x2)
          if (fx2 < 0.0_dp) then
            d_hit = x2                                  ! below, within tol_hit of x (above)
            found = .true.
            return
          end if
          x_prev = x2
          x = x2                                        ! a chord shorter than tol_hit may be skipped
          cycle
        end if
        x_prev = x
        x = x + t
      end do
      if (j > 200) return                               ! stalled: subdivide instead
      d_hit = entry(lo2, hi2)
      found = .true.
    end subroutine cell_search

    !> Bisect [lo, hi], height(hi) < 0, to the entry: the returned point is below
    !> the surface and within tol_hit of the last point found at or above it.
    real(dp) function entry(lo_in, hi_in)
      real(dp), intent(in) :: lo_in, hi_in
      real(dp) :: lo, hi, m
      integer :: it
      lo = lo_in
      hi = hi_in
      do it = 1, 60
        m = 0.5_dp*(lo + hi)
        if (height(m) < 0.0_dp) then
          hi = m
        else
          lo = m
        end if
        if (hi - lo <= tol_hit) exit
      end do
      entry = hi
    end function entry

    !> |g(d)| - r(g(d)): negative below the surface.
    real(dp) function height(d)
      real(dp), intent(in) :: d
      real(dp) :: g(3), la, lo_, r
      integer :: st
      g = s + d*l
      call ll(g, la, lo_)
      call dem_radius(dem, la, lo_, r, st)
      if (st /= stat_ok) stat = st
      height = length(g) - r
    end function height

    !> excluded = the segment [a, b] provably stays at or above the surface.
    subroutine exclude(a, b, excluded)
      real(dp), intent(in) :: a, b
      logical, intent(out) :: excluded
      integer :: c_one, i_one
      real(dp) :: dc, rmin, ga(3), gb(3), lat_lo, lat_hi, dstar, den, gs(3), gl
      real(dp) :: la_s, sweep, rmax_box, x_a, span
      logical :: full_lon
      ! smallest distance of the segment from the centre
      dc = min(max(d_near, a), b)
      rmin = length(s + dc*l)
      if (rmin >= dem%rmax) then
        excluded = .true.
        return
      end if
      ga = s + a*l
      lat_lo = min(la_a, la_b)
      lat_hi = max(la_a, la_b)
      ! the one interior extremum of latitude along a line (d/dd of z/|g| = 0)
      gl = dot_product(ga, l)
      den = l(3)*gl - ga(3)
      if (abs(den) > 0.0_dp) then
        dstar = a + (ga(3)*gl - l(3)*dot_product(ga, ga))/den
        if (dstar > a .and. dstar < b) then
          gs = s + dstar*l
          la_s = lat_near(gs, rho_of(gs), ga, rho_of(ga), la_a)
          lat_lo = min(lat_lo, la_s)
          lat_hi = max(lat_hi, la_s)
        end if
      end if
      ! longitude sweeps monotonically along a line, from lo_a by the signed angle
      ! between the xy projections (less than pi: the difference of the two
      ! longitudes, wrapped); a projection through the axis sweeps anything
      sweep = lo_b - lo_a
      if (sweep > pi) sweep = sweep - 2.0_dp*pi
      if (sweep < -pi) sweep = sweep + 2.0_dp*pi
      full_lon = abs(sweep) > 0.9_dp*pi .or. (ga(1) == 0.0_dp .and. ga(2) == 0.0_dp)
      if (.not. full_lon) then
        gb = s + b*l
        full_lon = gb(1) == 0.0_dp .and. gb(2) == 0.0_dp
      end if
      x_a = lo_a
      if (sweep < 0.0_dp) x_a = lo_b          ! the interval [x_a, x_a + |sweep|]
      span = abs(sweep)
      rmax_box = box_max(lat_lo, lat_hi, x_a, span, full_lon, c_one, i_one)
      excluded = rmin >= rmax_box
      box_top = rmax_box
      cell_c = c_one
      cell_i = i_one
    end subroutine exclude

    !> Highest surface radius over latitudes [lat_lo, lat_hi] and east
    !> longitudes [lon_w, lon_w + span] (radians; span < pi), or all longitudes.
    real(dp) function box_max(lat_lo, lat_hi, lon_w, span, full_lon, c_one, i_one) result(m)
      real(dp), intent(in) :: lat_lo, lat_hi, lon_w, span
      logical, intent(in) :: full_lon
      !> the cell row and column when the box lies in one cell, else -1
      integer, intent(out) :: c_one, i_one
      integer :: c0, c1, i0, i1, ncell_c, ncell_i, k, bc0, bc1, bi0, bi1, bc, bi, ii
      real(dp) :: x0, x1, y0, y1
      c0 = cell_row(lat_lo)
      c1 = cell_row(lat_hi)
      if (full_lon) then
        i0 = 0
        i1 = dem%nlon - 1
      else
        x0 = east_of(lon_first, lon_w)*deg*dem%ppd
        x1 = x0 + span*deg*dem%ppd
        i0 = min(int(x0), dem%nlon - 1)
        i1 = int(x1)                         ! may exceed nlon - 1: wraps below
        if (i1 < i0) i1 = i0
      end if
      ncell_c = c1 - c0 + 1
      ncell_i = i1 - i0 + 1
      box_c0 = c0
      box_c1 = c1
      box_i0 = i0
      box_i1 = i1
      box_full = full_lon
      c_one = -1
      i_one = -1
      if (ncell_c == 1 .and. ncell_i == 1) then
        c_one = c0
        i_one = i0
        call load_cell(c0, i0)
        if (full_lon) then
          m = huge(1.0_dp)
          return
        end if
        ! inside one cell: the bilinear maximum over the sub-box is at its corners
        ! (plus tol_hit for rounding in the corners' fractions, ~1e-11 of a pixel)
        y0 = frac_lat(lat_lo)
        y1 = frac_lat(lat_hi)
        x0 = frac_lon(lon_w)
        x1 = frac_lon(lon_w + span)
        m = max(patch(y0, x0), patch(y0, x1), patch(y1, x0), patch(y1, x1)) + tol_hit
        return
      end if
      if (ncell_i >= dem%nlon) then
        i0 = 0
        i1 = dem%nlon - 1
        ncell_i = dem%nlon
      end if
      ! two levels below the one whose blocks are at least as large as the box
      ! (2^k >= n): blocks of a quarter of the box or more, at most 5 x 5 of them
      ! touched (k >= 1). The finer bound drops more segments without splitting
      ! them: 26.1 -> 23.5 segments per hit on the 128 ppd limb scan
      k = bit_size(ncell_c) - leadz(max(ncell_c, ncell_i, 2) - 1)
      k = min(max(k - 2, 1), pyr%nlev)
      bc0 = ishft(c0, -k)
      bc1 = min(ishft(c1, -k), pyr%rows(k) - 1)
      m = -huge(1.0_dp)
      ! columns i0..i1 may run past the last column: the wrapped part is 0..i1-nlon
      do ii = 1, 2
        if (ii == 1) then
          bi0 = ishft(i0, -k)
          bi1 = ishft(min(i1, dem%nlon - 1), -k)
        else
          if (i1 < dem%nlon) exit
          bi0 = 0
          bi1 = ishft(i1 - dem%nlon, -k)
        end if
        do bc = bc0, bc1
          do bi = bi0, min(bi1, pyr%cols(k) - 1)
            m = max(m, real(pyr%data(pyr%off(k) + int(bc, i8)*pyr%cols(k) + bi + 1), dp))
          end do
        end do
      end do
    end function box_max

    !> Make cell (c, i) the current cell: its node radii and extent. Cell row c
    !> lies between DEM rows c and c + 1 (0 and nlat + 1: the poles, section 2.2),
    !> cell column i between DEM columns i + 1 and i + 2.
    subroutine load_cell(c, i)
      integer, intent(in) :: c, i
      real(dp) :: rc(4)
      integer :: st
      if (c == 0) then
        lat0 = -90.0_dp; lat1 = -90.0_dp + 0.5_dp/dem%ppd; ky = 2.0_dp*dem%ppd*deg
      else if (c == dem%nlat) then
        lat0 = 90.0_dp - 0.5_dp/dem%ppd; lat1 = 90.0_dp; ky = 2.0_dp*dem%ppd*deg
      else
        lat0 = -90.0_dp + (c - 0.5_dp)/dem%ppd; lat1 = lat0 + 1.0_dp/dem%ppd; ky = dem%ppd*deg
      end if
      lon0 = (i + 0.5_dp)/dem%ppd*rad
      call dem_cell_nodes(dem, i, c, rc, st)                   ! eqs. 2-5
      if (st /= stat_ok) stat = st
      r1 = rc(1); r2 = rc(2); r3 = rc(3); r4 = rc(4)
    end subroutine load_cell

    !> Fractional row offset (eq. 12's m_pix delta-theta, or its polar-cap
    !> form) of latitude la (radians) in the current cell, clamped to [0, 1].
    pure real(dp) function frac_lat(la)
      real(dp), intent(in) :: la
      frac_lat = min(max((la*deg - lat0)/(lat1 - lat0), 0.0_dp), 1.0_dp)
    end function frac_lat

    !> Fractional column offset (eqs. 10-11's m_pix delta-phi) of east
    !> longitude lo (radians) in the current cell, clamped to [0, 1].
    pure real(dp) function frac_lon(lo)
      real(dp), intent(in) :: lo
      frac_lon = east_of(lon0, lo)*deg*dem%ppd
      if (frac_lon > 1.5_dp) frac_lon = 0.0_dp          ! a hair west of the cell edge
      frac_lon = min(max(frac_lon, 0.0_dp), 1.0_dp)
    end function frac_lon

    !> The current cell's bilinear surface at fractional offsets (fy, fx): eqs. 10-12.
    pure real(dp) function patch(fy, fx)
      real(dp), intent(in) :: fy, fx
      real(dp) :: ra, rb
      ra = r1 + fx*(r2 - r1)                            ! eq. 10
      rb = r3 + fx*(r4 - r3)                            ! eq. 11
      patch = ra + fy*(rb - ra)                         ! eq. 12
    end function patch

    !> Cell row (0 = south cap, nlat = north cap) holding latitude lat (radians).
    integer function cell_row(lat)
      real(dp), intent(in) :: lat
      real(dp) :: y
      y = (lat*deg - lat_first)*dem%ppd
      if (y < 0.0_dp) then
        cell_row = 0
      else
        cell_row = min(int(y) + 1, dem%nlat)
      end if
    end function cell_row

  end subroutine exact_search

end module pi_exact
