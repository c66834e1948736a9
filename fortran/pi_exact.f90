!> Exact first hit of a ray with the paper's bilinear DEM surface (eqs. 10-12,
!> with the polar caps of section 2.2), accelerated by a max-pyramid.
!>
!> The surface over one DEM cell is bilinear in (latitude, longitude), so it
!> never exceeds the largest of its four corner radii, and over a sub-box of the
!> cell its maximum is the largest of the surface values at the sub-box corners.
!> The pyramid holds, for blocks of 2^k x 2^k cells (k >= 1), the largest node
!> radius bordering the block. A ray segment [a, b] cannot enter the surface if
!> its smallest distance from the centre is at or above the highest surface
!> radius over the latitude/longitude box the segment can touch; otherwise it is
!> split in two and the earlier half is searched first. A segment shorter than
!> `tol` that cannot be excluded is tested at its middle and end; the first with
!> |g| < r is the hit, refined by bisection.
!>
!> Guarantee: every part of the ray before the returned point is either proven
!> above the surface, or lies in a tested leaf shorter than tol: the hit is the
!> first entry into the surface except for chords shorter than tol along the
!> ray, and lies within tol of that entry. No hit is reported where |g| >= r.
module pi_exact
  use pi_kinds, only: dp, i8
  use pi_status
  use pi_vector, only: rad, deg, lon_diff, latlon_of, pi
  use pi_dem, only: dem_t, dem_radius
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
    real(dp), pointer, contiguous :: data(:) => null()
  end type pyramid_t

  !> Stack depth of the subdivision (segments halve each level).
  integer, parameter :: max_depth = 200

contains

  !> Attach a pyramid built by the caller (planet_intersect.dem.DEM.pyramid):
  !> meta(1:3, k) = rows, columns and 0-based offset of level k in data.
  !> The arrays must outlive the pyramid_t.
  subroutine pyramid_attach(data, meta, pyr)
    real(dp), intent(in), target, contiguous :: data(:)
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
    real(dp) :: stack(max_depth), a, b, mid, fm, fb, lo, hi, fx
    integer :: top, it
    logical :: excluded

    hit = .false.
    d_hit = 0.0_dp
    nodes = 0
    stat = stat_ok
    a = d_start
    top = 1
    stack(1) = d_end
    do while (top > 0)
      b = stack(top)
      nodes = nodes + 1
      call exclude(a, b, excluded)
      if (stat /= stat_ok) return
      if (excluded) then
        a = b
        top = top - 1
        cycle
      end if
      if (b - a <= tol .or. top >= max_depth) then
        mid = 0.5_dp*(a + b)
        fm = height(mid)
        fb = height(b)
        if (stat /= stat_ok) return
        if (fm < 0.0_dp .or. fb < 0.0_dp) then
          ! entry in [a, x], x the first tested point below the surface: bisect
          lo = a
          hi = merge(mid, b, fm < 0.0_dp)
          do it = 1, 60
            mid = 0.5_dp*(lo + hi)
            fx = height(mid)
            if (fx < 0.0_dp) then
              hi = mid
            else
              lo = mid
            end if
            if (hi - lo <= 1.0e-15_dp*max(1.0_dp, abs(hi))) exit
          end do
          hit = .true.
          d_hit = hi
          return
        end if
        a = b
        top = top - 1
        cycle
      end if
      ! split: search [a, mid] first, then [mid, b]
      mid = 0.5_dp*(a + b)
      top = top + 1
      stack(top) = mid
    end do

  contains

    !> |g(d)| - r(g(d)): negative below the surface.
    real(dp) function height(d)
      real(dp), intent(in) :: d
      real(dp) :: g(3), la, lo_, r
      integer :: st
      g = s + d*l
      call latlon_of(g, la, lo_)
      call dem_radius(dem, la, lo_, r, st)
      if (st /= stat_ok) stat = st
      height = norm2(g) - r
    end function height

    !> excluded = the segment [a, b] provably stays at or above the surface.
    subroutine exclude(a, b, excluded)
      real(dp), intent(in) :: a, b
      logical, intent(out) :: excluded
      real(dp) :: dc, rmin, ga(3), gb(3), la_a, lo_a, la_b, lo_b, lat_lo, lat_hi, dstar, den, gs(3)
      real(dp) :: la_s, lo_s, sweep, rmax_box, x_a, span
      logical :: full_lon
      ! smallest distance of the segment from the centre
      dc = min(max(-dot_product(s, l), a), b)
      rmin = norm2(s + dc*l)
      if (rmin >= dem%rmax) then
        excluded = .true.
        return
      end if
      ga = s + a*l
      gb = s + b*l
      call latlon_of(ga, la_a, lo_a)
      call latlon_of(gb, la_b, lo_b)
      lat_lo = min(la_a, la_b)
      lat_hi = max(la_a, la_b)
      ! the one interior extremum of latitude along a line (d/dd of z/|g| = 0)
      den = l(3)*dot_product(ga, l) - ga(3)
      if (abs(den) > 0.0_dp) then
        dstar = a + (ga(3)*dot_product(ga, l) - l(3)*dot_product(ga, ga))/den
        if (dstar > a .and. dstar < b) then
          gs = s + dstar*l
          call latlon_of(gs, la_s, lo_s)
          lat_lo = min(lat_lo, la_s)
          lat_hi = max(lat_hi, la_s)
        end if
      end if
      ! longitude sweeps monotonically along a line, from lo_a by the signed angle
      ! between the xy projections; a projection through the axis sweeps anything
      sweep = atan2(ga(1)*gb(2) - ga(2)*gb(1), ga(1)*gb(1) + ga(2)*gb(2))
      full_lon = hypot(ga(1), ga(2)) == 0.0_dp .or. hypot(gb(1), gb(2)) == 0.0_dp &
                 .or. abs(sweep) > 0.9_dp*pi
      x_a = lo_a
      if (sweep < 0.0_dp) x_a = lo_b          ! the interval [x_a, x_a + |sweep|]
      span = abs(sweep)
      rmax_box = box_max(lat_lo, lat_hi, x_a, span, full_lon)
      excluded = rmin >= rmax_box
    end subroutine exclude

    !> Highest surface radius over latitudes [lat_lo, lat_hi] and east
    !> longitudes [lon0, lon0 + span] (radians; span < pi), or all longitudes.
    real(dp) function box_max(lat_lo, lat_hi, lon0, span, full_lon) result(m)
      real(dp), intent(in) :: lat_lo, lat_hi, lon0, span
      logical, intent(in) :: full_lon
      integer :: c0, c1, i0, i1, ncell_c, ncell_i, k, bc0, bc1, bi0, bi1, bc, bi, ii
      real(dp) :: x0, x1, r, corners(2, 2)
      integer :: st, p, q
      c0 = cell_row(lat_lo)
      c1 = cell_row(lat_hi)
      if (full_lon) then
        i0 = 0
        i1 = dem%nlon - 1
      else
        x0 = lon_diff(rad*0.5_dp/dem%ppd, lon0)*deg*dem%ppd
        x1 = x0 + span*deg*dem%ppd
        i0 = min(int(x0), dem%nlon - 1)
        i1 = int(x1)                         ! may exceed nlon - 1: wraps below
        if (i1 < i0) i1 = i0
      end if
      ncell_c = c1 - c0 + 1
      ncell_i = i1 - i0 + 1
      if (ncell_c == 1 .and. ncell_i == 1) then
        ! inside one cell: the bilinear maximum over the sub-box is at its corners
        do p = 1, 2
          do q = 1, 2
            if (full_lon) then
              corners(p, q) = huge(1.0_dp)
            else
              call dem_radius(dem, merge(lat_lo, lat_hi, p == 1), lon0 + merge(0.0_dp, span, q == 1), r, st)
              if (st /= stat_ok) stat = st
              corners(p, q) = r
            end if
          end do
        end do
        m = maxval(corners)
        return
      end if
      if (ncell_i >= dem%nlon) then
        i0 = 0
        i1 = dem%nlon - 1
        ncell_i = dem%nlon
      end if
      ! the level whose blocks are at least as large as the box: the box touches at most 2 x 2 of them
      k = 1
      do while (k < pyr%nlev .and. (2**k < ncell_c .or. 2**k < ncell_i))
        k = k + 1
      end do
      bc0 = c0/2**k
      bc1 = min(c1/2**k, pyr%rows(k) - 1)
      m = -huge(1.0_dp)
      ! columns i0..i1 may run past the last column: the wrapped part is 0..i1-nlon
      do ii = 1, 2
        if (ii == 1) then
          bi0 = i0/2**k
          bi1 = min(i1, dem%nlon - 1)/2**k
        else
          if (i1 < dem%nlon) exit
          bi0 = 0
          bi1 = (i1 - dem%nlon)/2**k
        end if
        do bc = bc0, bc1
          do bi = bi0, min(bi1, pyr%cols(k) - 1)
            m = max(m, pyr%data(pyr%off(k) + int(bc, i8)*pyr%cols(k) + bi + 1))
          end do
        end do
      end do
    end function box_max

    !> Cell row (0 = south cap, nlat = north cap) holding latitude lat (radians).
    integer function cell_row(lat)
      real(dp), intent(in) :: lat
      real(dp) :: y
      y = (lat*deg - (-90.0_dp + 0.5_dp/dem%ppd))*dem%ppd
      if (y < 0.0_dp) then
        cell_row = 0
      else
        cell_row = min(int(y) + 1, dem%nlat)
      end if
    end function cell_row

  end subroutine exact_search

end module pi_exact
