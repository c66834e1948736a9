!> Exact first hit of a ray on a geodetic DSM (method "exact"), and the
!> per-ray driver of all three DSM methods (OpenMP over rays).
!>
!> The answer is the contract's (docs/shin-park-notes.md, "exact mode"): the
!> smallest r >= 0 where P(r) is over the DSM's defined area and its exact
!> geodetic height h(r) <= H(lat, lon), to refine_tol along the ray, never
!> late, never missing an entry longer than refine_tol; or the first low
!> (h <= H_max) point over no-data / outside the area.
!>
!> Algorithm:
!>  1. h(r) is convex along the line (signed distance to a convex body). The
!>     search interval is [r_in, r_end]: r_in the first crossing of H_max,
!>     r_end the first crossing of H_min (after which any point over data is a
!>     hit), else the last crossing of H_max. Newton from the outside side.
!>  2. Depth-first subdivision of [r_in, r_end] in ray order. A segment
!>     [ra, rb] gets a lower bound of h from the tangents at both ends
!>     (convexity), a longitude range from its ends (longitude is monotone
!>     along a line), and a latitude range from the ends widened by the
!>     Lipschitz bound |dlat/dr| <= (|l.north| + L kappa) / (M_min + h_low).
!>     The max-pyramid bounds the surface over that box (no-data and outside
!>     as +huge); a segment whose lowest height is above the bound is skipped.
!>  3. A segment within one "nearest" cell is solved by Newton on the convex
!>     h(r) - H_cell from its start (monotone, never past the first root).
!>     Otherwise segments are halved until shorter than refine_tol, where the
!>     end point is classified (hit, no-data, outside or still above).
!> Every loop is bounded (segment limit exact_maxseg, stack depth exact_depth).
module pi_dsm_exact
  use pi_kinds, only: dp
  use pi_status
  use pi_vector, only: pi, axis_distance, far_distance
  use pi_dsm, only: dsm_t, dsm_height, dsm_grid_uv, dsm_cells, dsm_box_bound, dsm_box_bound_wrapped, &
                    interp_nearest, pt_ok, &
                    pt_outside, pt_nodata, range_max
  use pi_follow, only: dsm_ray_t, follow_ray, iterate_ray, ray_geo, level_crossing, level_crossing_back, &
                       bowring_error, bowring_tol, &
                       set_hit, set_event, settle_start, refine_tol, newton_tol
  use pi_geodetic, only: ecr_to_geodetic
  use pi_dsm_fast, only: fast_ray, lat_second_bound
  use pi_dsm_sweep, only: sweep_fans, sweep_runs
  use pi_ray_order, only: ray_order
  use pi_ieee, only: nan_dp, ieee_is_finite => is_finite, ieee_is_nan => is_nan
  !$ use omp_lib, only: omp_get_max_threads
  implicit none
  private

  public :: exact_ray, dsm_trace_packed, dsm_method_following, dsm_method_exact, dsm_method_iterative, &
            dsm_method_exact_reference, dsm_method_exact_fast_only, ray_fast_declined, exact_maxseg

  !> method codes of dsm_trace_packed: the three public methods, and two internal
  !> ones for tests: exact_reference = exact_ray alone (no fast path),
  !> exact_fast_only = the fast path alone (status ray_fast_declined where it
  !> declines)
  integer, parameter :: dsm_method_following = 0, dsm_method_exact = 1, dsm_method_iterative = 2, &
                        dsm_method_exact_reference = 3, dsm_method_exact_fast_only = 4
  !> status of method exact_fast_only where the fast path declined (internal, tests only)
  integer, parameter :: ray_fast_declined = 99
  !> segment limit per ray (then ray_step_limit) and subdivision stack depth
  integer, parameter :: exact_maxseg = 200000, exact_depth = 128
  !> chord_class: the kinds it returns, and the largest departure of a segment's path from its chord
  !> in grid coordinates (cells) for which it applies
  integer, parameter :: chord_outside = -2, chord_cell = 1, chord_bound = 2, chord_nodata = 3
  real(dp), parameter :: chord_tol = 2.5e-16_dp
  !> a segment's latitude bounds need den = M_min + min(h_low, 0) > 0 (|dlat/dr| = |l.north|/(M + h));
  !> below den_min_frac M_min a segment gets no bound (it is split). It was 0.5, and the bottom of the
  !> slab of a DSM with H_min < -M_min/2 was never bounded: on a 13 km body with heights down to -8 km,
  !> 27-35 % of rays ended STEP_LIMIT (a review); docs/shin-park-notes.md, "Exact mode" 2
  real(dp), parameter :: den_min_frac = 0.1_dp

  !> a point of the ray with what the bounds need
  type :: rpt_t
    real(dp) :: r, lat, lon, h, dh, u, v, ln
  end type rpt_t

contains

  !> Evaluate the ray point at r: exact geodetic coordinates, dh/dr, grid
  !> coordinates and l . north.
  pure subroutine eval_pt(dsm, s, l, r, q)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r
    type(rpt_t), intent(out) :: q
    real(dp) :: p(3), nx, ny, nz, cphi
    p = s + r * l
    call ecr_to_geodetic(p(1), p(2), p(3), dsm%a, dsm%f, q%lat, q%lon, q%h, nx, ny, nz)
    q%r = r
    q%dh = l(1) * nx + l(2) * ny + l(3) * nz
    call dsm_grid_uv(dsm, q%lat, q%lon, q%u, q%v)
    ! north unit vector (-sin lat cos lon, -sin lat sin lon, cos lat) from the normal
    cphi = sqrt(nx * nx + ny * ny)
    if (cphi > 0.0_dp) then
      q%ln = (-nz * (l(1) * nx + l(2) * ny)) / cphi + cphi * l(3)
    else
      q%ln = sqrt(l(1)**2 + l(2)**2)
    end if
  end subroutine eval_pt

  !> Bounds for the segment [pa, pb]: hlow <= h on it (convexity, the end
  !> tangents), hb >= the surface over the part of its (lat, lon) box inside the
  !> DSM (+huge: unknown or no-data), out: the box reaches outside the DSM;
  !> cell >= 0 when the box lies within one "nearest" cell (its height in hb);
  !> rsplit > 0: the estimated crossing of the one cell boundary the box straddles;
  !> edge (optional): out, but only by its rounding margins (the box shrunk by
  !> twice them lies inside the grid: the segment runs along the DSM's edge,
  !> within ~1e-12 rad of it).
  pure subroutine segment_bounds(dsm, s, l, pa, pb, hlow, hb, out, cell, rsplit, edge)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3)
    type(rpt_t), intent(in) :: pa, pb
    real(dp), intent(out) :: hlow, hb, rsplit
    logical, intent(out) :: out
    integer, intent(out) :: cell
    logical, intent(out), optional :: edge
    integer :: ci0, ci1, cj0, cj1
    real(dp) :: t, ub, rb0, wu, gv, lo
    real(dp) :: rstar, mmin, den, rho, kap, keff, llen, lat_lo, lat_hi, w, v0, v1, u0, u1, du
    llen = pb%r - pa%r
    if (pa%dh >= 0.0_dp) then
      hlow = pa%h
    else if (pb%dh <= 0.0_dp) then
      hlow = pb%h
    else
      rstar = (pb%h - pa%h + pa%dh * pa%r - pb%dh * pb%r) / (pa%dh - pb%dh)
      rstar = min(max(rstar, pa%r), pb%r)
      hlow = min(pa%h, pb%h, pa%h + pa%dh * (rstar - pa%r))
    end if
    hlow = hlow - 1.0e-9_dp * (1.0_dp + abs(hlow))
    hb = huge(1.0_dp)
    out = .true.
    cell = -1
    rsplit = 0.0_dp
    if (present(edge)) edge = .false.
    mmin = dsm%a * (1.0_dp - dsm%e2)                      ! smallest meridian radius of curvature
    den = mmin + min(hlow, 0.0_dp)
    if (.not. (den > den_min_frac * mmin)) return
    rho = axis_distance(s, l, pa%r, pb%r)
    if (.not. (rho > 1.0e-9_dp * dsm%a)) then
      ! within ~6 mm of the polar axis (a drone over the pole: every segment there was subdivided to
      ! refine_tol, 200,000 of them, STEP_LIMIT): longitude is anything, and a point at axis distance
      ! rho_P has cos(lat) = rho_P / (N + h) <= rho_P / (a + h), N >= a; rho_P is largest at an end
      ! (the distance to a line is convex along a segment)
      call polar_box(dsm, s, l, pa%r, pb%r, pa%lon, pb%lon, rho, hlow, hb, out)
      return
    end if
    ! |dlat/dr| = |l . north| / (M + h); l . north changes by at most kap per unit r
    kap = 1.0_dp / den + 1.0_dp / rho
    keff = min((abs(pa%ln) + llen * kap) / den, 1.0_dp / den)
    lat_lo = min(pa%lat, pb%lat, 0.5_dp * (pa%lat + pb%lat - keff * llen))
    lat_hi = max(pa%lat, pb%lat, 0.5_dp * (pa%lat + pb%lat + keff * llen))
    w = 1.0e-12_dp * (1.0_dp + abs(lat_hi))
    v0 = (lat_lo - w - dsm%lat0) / dsm%dlat
    v1 = (lat_hi + w - dsm%lat0) / dsm%dlat
    if (v0 > v1) then                                      ! (not through w: the edge test below needs it;
      t = v0; v0 = v1; v1 = t                              ! it took the swapped row and no segment of a
    end if                                                 ! north-up grid was ever "along the edge")
    du = modulo(pb%lon - pa%lon + pi, 2.0_dp * pi) - pi
    if (.not. (abs(du) < 0.5_dp * pi)) return             ! longitude is monotone: a short sweep only
    ! the margin in u: 1e-9 cells and the rounding of the wrapped longitudes (du and each point's
    ! u come out of a modulo over +-pi: a few ulps of pi, 2.2e-9 cells on a 1 m grid; with 1e-9
    ! alone a ray reaching the ground 1.1e-9 cells outside the grid's edge got a box inside it,
    ! and no LEFT_DSM: it was a MISS, found by a review)
    wu = 1.0e-9_dp + 8.0_dp * spacing(pi) / dsm%dlon
    u0 = min(pa%u, pa%u + du / dsm%dlon) - wu
    u1 = max(pa%u, pa%u + du / dsm%dlon) + wu
    call dsm_box_bound_wrapped(dsm, u0, u1, v0, v1, hb, out)   ! (past the wrap meridian: pi_dsm)
    if (present(edge) .and. out) then
      gv = 2.0_dp * w / abs(dsm%dlat)                     ! twice the margins, in cells
      lo = 0.0_dp
      if (dsm%interp == interp_nearest) lo = -0.5_dp
      edge = v0 + gv >= lo .and. v1 - gv <= dsm%nrows - 1 - lo
      if (.not. dsm%global) edge = edge .and. u0 + 2.0_dp * wu >= lo .and. u1 - 2.0_dp * wu <= dsm%ncols - 1 - lo
    end if
    if (dsm%interp == interp_nearest .and. .not. out .and. .not. dsm%global .and. hb < huge(1.0_dp)) then
      ci0 = ceiling(v0 - 0.5_dp); ci1 = floor(v1 + 0.5_dp)
      cj0 = ceiling(u0 - 0.5_dp); cj1 = floor(u1 + 0.5_dp)
      if (ci0 == ci1 .and. cj0 == cj1) then
        cell = 1
      else if (ci1 - ci0 + cj1 - cj0 == 1) then
        ! the box straddles one cell boundary (a wall): suggest splitting just
        ! before the crossing estimated by linear interpolation of u or v, so
        ! that the part before it is one cell (where the split falls does not
        ! affect correctness, only how soon the search gets there)
        if (cj1 > cj0) then
          ub = cj0 + 0.5_dp
          rb0 = pa%u + du / dsm%dlon
          t = (ub - pa%u) / (rb0 - pa%u)
        else
          ub = ci0 + 0.5_dp
          t = (ub - pa%v) / (pb%v - pa%v)
        end if
        if (t > 0.0_dp .and. t < 1.0_dp) rsplit = pa%r + t * llen
      end if
    end if
  end subroutine segment_bounds

  !> segment_bounds' box for a segment [ra, rb] near the polar axis: latitudes from the pole down
  !> to the colatitude acos-bound of its farthest point from the axis; longitudes between its ends'
  !> (lon_a, lon_b) when the segment keeps far enough from the axis (rho, its distance) for their
  !> rounding to be small, else all (hb = +huge, out = .true. where that does not apply: the ends on
  !> both sides of the equator, or a colatitude bound above 0.1 rad).
  pure subroutine polar_box(dsm, s, l, ra, rb, lon_a, lon_b, rho, hlow, hb, out)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), ra, rb, lon_a, lon_b, rho, hlow
    real(dp), intent(out) :: hb
    logical, intent(out) :: out
    real(dp) :: pa(3), pb(3), rho_max, den, colat, lat_lo, lat_hi, v0, v1, w, lo
    real(dp) :: dlam, elam, u0, u1, vd
    integer :: i0, i1, j, cw
    hb = huge(1.0_dp)
    out = .true.
    pa = s + ra * l
    pb = s + rb * l
    if (.not. (pa(3) * pb(3) > 0.0_dp)) return
    rho_max = max(hypot(pa(1), pa(2)), hypot(pb(1), pb(2)))
    den = dsm%a + min(hlow, 0.0_dp)
    if (.not. (den > den_min_frac * dsm%a)) return
    ! >= asin(rho_max / den) (cos(lat) = rho / (N + h) <= rho_max / den); it was 1.001 rho_max / den, which
    ! is below asin above 0.0775 rad, where the box was up to 6.6e-5 rad narrow on a sphere (a review)
    colat = (1.0_dp + 1.0e-12_dp) * asin(min(1.0_dp, rho_max / den)) + 1.0e-12_dp
    if (.not. (colat < 0.1_dp)) return
    if (pa(3) > 0.0_dp) then
      lat_lo = 0.5_dp * pi - colat
      lat_hi = 0.5_dp * pi
    else
      lat_lo = -0.5_dp * pi
      lat_hi = -0.5_dp * pi + colat
    end if
    v0 = (lat_lo - dsm%lat0) / dsm%dlat
    v1 = (lat_hi - dsm%lat0) / dsm%dlat
    if (v0 > v1) then
      w = v0; v0 = v1; v1 = w
    end if
    ! longitude along a line not through the axis is monotone, sweeping the angle between its ends'
    ! projections (< pi); a point's longitude is atan2(y, x) of its x = s_x + r l_x and y (the
    ! same for y), each rounded by at most 1.1e-16 (|s_x| + 2 |r l_x|), so the angle by at most
    ! their sum over rho at each end; the bound below is four times that, plus atan2's own
    ! rounding. A drone within ~6 mm of the axis over a pole row that varies with longitude ran
    ! out of segments with all longitudes (a review); a ray exactly on the axis (x = y = 0 at every
    ! point) has its ends' longitude. The rounding of r l_x is relative to l_x: a bound taking it
    ! relative to |l| (|s| + 4 r) gave a nadir view of the pole (~4e-10 m off the axis, |l_x| ~
    ! 6e-17) a degree of longitude, whose pole-row heights it could never rule out (STEP_LIMIT,
    ! a review; shin-park-notes 3a)
    elam = -1.0_dp
    if (s(1) == 0.0_dp .and. s(2) == 0.0_dp .and. l(1) == 0.0_dp .and. l(2) == 0.0_dp) then
      elam = 0.0_dp
    else if (rho > 0.0_dp) then
      elam = 8.9e-16_dp * (abs(s(1)) + abs(s(2)) + 4.0_dp * max(abs(ra), abs(rb)) * (abs(l(1)) + abs(l(2)))) &
             / rho + 1.0e-15_dp
    end if
    dlam = modulo(lon_b - lon_a + pi, 2.0_dp * pi) - pi
    if (elam >= 0.0_dp .and. abs(dlam) + elam < 0.25_dp * pi) then
      call dsm_grid_uv(dsm, 0.0_dp, lon_a, w, vd)                 ! w = u(lon_a)
      u0 = w + (min(dlam, 0.0_dp) - elam) / dsm%dlon - 8.0_dp * spacing(pi) / dsm%dlon - 1.0e-9_dp
      u1 = w + (max(dlam, 0.0_dp) + elam) / dsm%dlon + 8.0_dp * spacing(pi) / dsm%dlon + 1.0e-9_dp
      call dsm_box_bound_wrapped(dsm, u0, u1, v0, v1, hb, out)   ! (past the wrap meridian: pi_dsm)
      ! a bilinear band inside one row of cells across more than two columns: dsm_box_bound takes
      ! the node rows' maximum, which holds the next row's heights, and a ray within ~2e-9 m of the
      ! axis (a nadir view of the pole) never got its segments ruled out (STEP_LIMIT, a review);
      ! the surface itself is linear in v on each node column and in u between them, so its
      ! largest value over the box is at v0 or v1 on a node column from floor(u0) to ceiling(u1)
      ! (u0, u1 clamped to +-2 ncols before the integer conversion: a global grid's stay inside, and
      ! a regional grid's columns are clamped to the grid anyway)
      ! (not across a regional grid's wrap meridian, whose columns it would clamp instead of wrap)
      if (dsm%interp /= interp_nearest .and. hb < huge(1.0_dp) .and. (dsm%global .or. &
          (u0 >= dsm%uw .and. u1 <= dsm%uw + dsm%uturn))) &
        hb = min(hb, band_columns(floor(max(u0, -2.0_dp * dsm%ncols)), ceiling(min(u1, 2.0_dp * dsm%ncols))))
      return
    end if
    ! the rows the band touches (nodes for bilinear, cells for nearest), every column; the grid
    ! does not hold all longitudes unless global, so the box is then partly outside (out)
    lo = 0.0_dp
    if (dsm%interp == interp_nearest) lo = 0.5_dp
    out = .not. dsm%global .or. v0 < -lo .or. v1 > dsm%nrows - 1 + lo
    hb = -huge(1.0_dp)
    if (v1 < -lo .or. v0 > dsm%nrows - 1 + lo) return
    if (dsm%interp == interp_nearest) then
      i0 = min(max(ceiling(v0 - 0.5_dp), 0), dsm%nrows - 1)
      i1 = min(max(floor(v1 + 0.5_dp), 0), dsm%nrows - 1)
    else
      i0 = min(max(floor(v0), 0), dsm%nrows - 1)
      i1 = min(max(ceiling(v1), 0), dsm%nrows - 1)
    end if
    if (dsm%interp /= interp_nearest .and. i1 <= i0 + 1) then
      ! a bilinear band inside one row of cells: the surface itself, linear in v along each node
      ! column, so its largest value is at v0 or v1 on some column (the node rows' maximum took in
      ! the next row's heights and the segments at the pole were never ruled out: a review)
      hb = band_columns(0, dsm%ncols - 1)
      return
    end if
    ! a thin band of rows across every column: range_max's square pyramid blocks would take in
    ! rows far from the pole (a tower 10 rows away kept the segments near the axis from ever being
    ! ruled out); column chunks as wide as the band is tall keep the blocks tight
    cw = max(2, i1 - i0 + 1)
    do j = 0, dsm%ncols - 1, cw
      hb = max(hb, range_max(dsm, i0, i1, j, min(j + cw - 1, dsm%ncols - 1)))
    end do
  contains
    !> The bilinear surface's largest value over rows v0..v1 (inside one row of cells) on node
    !> columns j0..j1 (0-based; wrapped on a global grid, whose last column repeats the first;
    !> clamped to the grid otherwise), +huge when v0..v1 is not inside one row of cells or a
    !> node is no-data.
    pure function band_columns(j0, j1) result(hmax)
      integer, intent(in) :: j0, j1
      real(dp) :: hmax, g0, g1, c0, c1
      integer :: k0, k1, jj, jc, period
      hmax = huge(1.0_dp)
      k0 = min(max(floor(v0), 0), dsm%nrows - 1)
      k1 = min(max(ceiling(v1), 0), dsm%nrows - 1)
      if (k1 > k0 + 1) return
      if (k1 == k0) k1 = min(k0 + 1, dsm%nrows - 1)
      g0 = min(max(v0 - k0, 0.0_dp), 1.0_dp)
      g1 = min(max(v1 - k0, 0.0_dp), 1.0_dp)
      period = dsm%ncols - 1                                ! (global bilinear: one turn of nodes)
      hmax = -huge(1.0_dp)
      do jj = j0, j1
        if (dsm%global) then
          jc = modulo(jj, period)
        else
          jc = min(max(jj, 0), dsm%ncols - 1)
        end if
        c0 = dsm%hgt(jc + 1, k0 + 1)
        c1 = dsm%hgt(jc + 1, k1 + 1)
        if (ieee_is_nan(c0) .or. ieee_is_nan(c1)) then
          hmax = huge(1.0_dp)
          return
        end if
        hmax = max(hmax, c0 + g0 * (c1 - c0), c0 + g1 * (c1 - c0))
        if (jj - j0 > dsm%ncols) exit                       ! (a full turn is enough)
      end do
      hmax = hmax + 1.0e-12_dp * (1.0_dp + abs(hmax))       ! (the rounding of the two products)
    end function band_columns
  end subroutine polar_box

  !> Exact first hit for one ray (l unit, s above the surface). clear = .true.
  !> (the fast path's res%slab_clear: it searched the whole slab and found no hit
  !> and no no-data point) skips the search of step 2; the start and end points
  !> are still settled here, then step 4 looks for the first low point outside.
  pure subroutine exact_ray(dsm, s, l, res, clear)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3)
    type(dsm_ray_t), intent(inout) :: res
    logical, intent(in), optional :: clear
    type(rpt_t) :: pa, pb, pm, p_in, p_end, stack(exact_depth)
    real(dp) :: r_in, r_end, r_far, hs, lat, lon, h, dh, hlow, hb, r, g, dr, hc, rsplit, rm
    logical :: found, out, done, edge, skip
    integer :: code, nst, nseg, it, cell
    res%nsteps = 0
    ! ---- 1. the search interval
    call ray_geo(dsm, s, l, 0.0_dp, lat, lon, h, dh)
    res%nsteps = 1
    if (h <= dsm%hmax) then
      r_in = 0.0_dp
    else
      call level_crossing(dsm, s, l, 0.0_dp, dsm%hmax, r_in, found, res%nsteps)
      if (.not. found) then
        res%status = ray_dsm_miss
        return
      end if
    end if
    call level_crossing(dsm, s, l, r_in, dsm%hmin, r_end, found, res%nsteps)
    if (.not. found) then
      ! beyond the sphere |P| = a + H_max + 1 nothing is below H_max
      r_far = far_distance(s, l, dsm%a + max(dsm%hmax, 0.0_dp) + 1.0_dp)
      call level_crossing_back(dsm, s, l, max(r_far, r_in), dsm%hmax, r_end, found, res%nsteps)
      if (.not. found) r_end = r_in
      r_end = max(r_end, r_in)
    end if
    call eval_pt(dsm, s, l, r_in, p_in)
    call eval_pt(dsm, s, l, r_end, p_end)
    res%nsteps = res%nsteps + 2
    ! ---- the start point itself
    call dsm_height(dsm, p_in%lat, p_in%lon, hs, code)
    call settle_start(dsm, s, l, r_in, p_in%h, hs, code, res, done)
    if (done) return
    ! ---- 2. depth-first subdivision for the first hit or no-data point
    pa = p_in
    pb = p_end
    nst = 0
    skip = .false.
    if (present(clear)) skip = clear
    do nseg = 1, merge(0, exact_maxseg, skip)
      call segment_bounds(dsm, s, l, pa, pb, hlow, hb, out, cell, rsplit)
      if (hlow > hb) then                                 ! nothing to meet in this segment
        call next_segment(pa, pb, stack, nst)
        if (nst < 0) exit
        cycle
      end if
      if (cell < 0 .and. pb%r - pa%r > refine_tol) then
        ! ---- the chord rule: a segment that runs along a grid line or the grid's edge within its box's
        ! margins (rays exactly along a wall, onto an edge at the surface's height: ~100,000 segments of
        ! refine_tol each and STEP_LIMIT, a review) takes the class its two ends agree on
        call chord_class(dsm, s, l, pa, pb, hlow, cell, hc)
        if (cell == chord_outside) then
          call next_segment(pa, pb, stack, nst)
          if (nst < 0) exit
          cycle
        end if
        if (cell == chord_nodata) then                   ! low, and in one no-data cell from its start
          call set_event(dsm, s, l, pa%r, ray_no_data, res)
          return
        end if
        if (cell == chord_bound) then                    ! in one bilinear cell: its bound there
          cell = -1
          hb = hc
          if (hlow > hb) then
            call next_segment(pa, pb, stack, nst)
            if (nst < 0) exit
            cycle
          end if
        end if
        if (cell == chord_cell) hb = hc
      end if
      if (cell >= 0) then                                 ! ---- 3a. one nearest cell: Newton on h - H_cell
        hc = hb
        r = pa%r
        g = pa%h - hc
        dh = pa%dh
        found = .false.
        do it = 1, 100
          if (g <= 0.0_dp) then
            found = .true.
            exit
          end if
          if (.not. (dh < 0.0_dp)) exit                   ! rising: convex h never comes back down
          dr = -g / dh
          r = r + dr
          if (r > pb%r) exit                              ! the first root lies beyond the segment
          if (dr <= newton_tol(r)) then
            found = .true.
            exit
          end if
          call ray_geo(dsm, s, l, r, lat, lon, h, dh)
          res%nsteps = res%nsteps + 1
          g = h - hc
        end do
        if (found) then
          call set_hit(dsm, s, l, r, ray_hit, res)
          return
        end if
        if (it <= 100) then
          call next_segment(pa, pb, stack, nst)
          if (nst < 0) exit
          cycle
        end if
      end if
      if (pb%r - pa%r <= refine_tol) then                 ! ---- 3b. a short segment: classify its end
        call dsm_height(dsm, pb%lat, pb%lon, hs, code)
        if (code == pt_nodata) then
          call set_event(dsm, s, l, pb%r, ray_no_data, res)
          return
        else if (code == pt_ok .and. pb%h <= hs) then
          call set_hit(dsm, s, l, pb%r, ray_hit, res)
          return
        end if
        call next_segment(pa, pb, stack, nst)
        if (nst < 0) exit
        cycle
      end if
      if (nst >= exact_depth) then
        res%status = ray_step_limit
        return
      end if
      ! split just before (or, from the boundary, just after) a wall crossing, else at the middle
      rm = 0.5_dp * (pa%r + pb%r)
      ! (not where the estimate falls within 2 % of an end: a ray within the box margins of a wall
      ! then had each split cut 1e-7 m off the segment's end and ran out of stack, STEP_LIMIT after
      ! ~170 conversions, a review)
      if (rsplit > 0.0_dp .and. abs(rsplit - rm) < 0.48_dp * (pb%r - pa%r)) then
        if (rsplit - 0.25_dp * refine_tol > pa%r + 0.125_dp * refine_tol) then
          rm = rsplit - 0.25_dp * refine_tol
        else if (rsplit + 0.25_dp * refine_tol < pb%r - 0.125_dp * refine_tol) then
          rm = rsplit + 0.25_dp * refine_tol
        end if
      end if
      call eval_pt(dsm, s, l, rm, pm)
      res%nsteps = res%nsteps + 1
      nst = nst + 1
      stack(nst) = pb
      pb = pm
    end do
    if (nst >= 0 .and. .not. skip) then
      res%status = ray_step_limit
      return
    end if
    ! ---- the interval is clear up to r_end: the end point decides (h = H_min there)
    call dsm_height(dsm, p_end%lat, p_end%lon, hs, code)
    ! (the crossing stops once its Newton step is below 1e-9 m, so h there may
    ! exceed H_min by ~1e-9 m; measured misses on flat ground at 1e-9: issue 11,
    ! tests/test_dsm_references.py antimeridian scene)
    if (code == pt_ok .and. p_end%h <= hs + 1.0e-12_dp * dsm%a + 1.0e-9_dp * abs(hs)) then
      call set_hit(dsm, s, l, r_end, ray_hit, res)
      return
    end if
    ! ---- 4. no hit, no no-data: the first low point outside the DSM, if any
    pa = p_in
    pb = p_end
    nst = 0
    do nseg = 1, exact_maxseg
      call segment_bounds(dsm, s, l, pa, pb, hlow, hb, out, cell, rsplit, edge)
      rsplit = 0.0_dp
      if (pa%r == r_in) then
        call dsm_height(dsm, pa%lat, pa%lon, hs, code)
        if (code == pt_outside) then
          call set_event(dsm, s, l, pa%r, ray_left_dsm, res)
          return
        end if
      end if
      if (.not. out) then
        call next_segment(pa, pb, stack, nst)
        if (nst < 0) exit
        cycle
      end if
      if (pb%r - pa%r <= refine_tol) then
        call dsm_height(dsm, pb%lat, pb%lon, hs, code)
        if (code == pt_outside) then
          call set_event(dsm, s, l, pb%r, ray_left_dsm, res)
          return
        end if
        call next_segment(pa, pb, stack, nst)
        if (nst < 0) exit
        cycle
      end if
      if (edge) then
        ! a segment along the edge, out of the grid only by the box's rounding margins: its points
        ! may classify either way, and a depth-first search would visit every refine_tol of it (a
        ! ray along the last row of a grid ran into exact_maxseg: STEP_LIMIT after 45 ms, found by
        ! a review). It holds a point outside when its end does; when the end is inside, the
        ! segment counts as inside: an excursion < ~1e-12 rad beyond the edge is not an event
        ! (docs/shin-park-notes.md, "Exact mode"). So it is bisected only toward an outside end.
        call dsm_height(dsm, pb%lat, pb%lon, hs, code)
        if (code /= pt_outside) then
          call next_segment(pa, pb, stack, nst)
          if (nst < 0) exit
          cycle
        end if
      end if
      if (nst >= exact_depth) exit
      call eval_pt(dsm, s, l, 0.5_dp * (pa%r + pb%r), pm)
      res%nsteps = res%nsteps + 1
      nst = nst + 1
      stack(nst) = pb
      pb = pm
    end do
    if (nst >= 0) then
      res%status = ray_step_limit
    else
      res%status = ray_dsm_miss
    end if
  end subroutine exact_ray

  !> The chord rule of exact_ray's first pass (docs/shin-park-notes.md, "Exact mode", 3a).
  !>
  !> A segment's path in grid coordinates departs from its chord (between its ends' u, v) by at
  !> most dev_u, dev_v cells: |lat''| L^2/8 and |lon''| L^2/8, with |lat''| <= kappa/den +
  !> (|dM/dlat|/den + 1)/den^2 (pi_dsm_fast) and |lon''| = 2 |C| |rho'| / rho^3 <= 2 |C| / rho^3,
  !> C = s_x l_y - s_y l_x (lon' = C / rho^2 along a line; C = 0 in a meridian plane). The chord
  !> lies in any convex region holding both ends: one "nearest" cell, or the half-plane beyond one
  !> of the grid's edges. The path lies there too when, in each direction that matters, it keeps
  !> farther from the region's boundary than its departure, or when its departure is at most
  !> chord_tol (1e-15 rad, below the lookup's own edge slack of 8 ulp(pi), 3.5e-15 rad).
  !>
  !> Outputs: kind = chord_outside (beyond one edge: nothing to meet), chord_cell (in one nearest
  !> cell with data: hc its height), chord_bound (bilinear: hc the bound of the surface over the
  !> path's own box, the chord's widened by the departure and rounding), chord_nodata (the path in
  !> one cell without data), else -1 (no rule: the usual search). (The segment's own box carries
  !> 1e-12 rad margins: one that took in a no-data neighbour only through them had no bound, and a
  !> ray near a corner node beside a no-data node took 65,828 conversions, a review.) The
  !> departure-below-chord_tol shortcut never applies to a cell without data or to bilinear cells.
  pure subroutine chord_class(dsm, s, l, pa, pb, hlow, kind, hc)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), hlow
    type(rpt_t), intent(in) :: pa, pb
    integer, intent(out) :: kind
    real(dp), intent(out) :: hc
    real(dp) :: llen, den, rho, lat2, dlat_r, dlon_r, dev_u, dev_v, ub, cmom, lo
    real(dp) :: ev, eu, gap
    logical :: out
    integer :: fa, fb, ia, ja, ib, jb, common
    integer :: ia0, ia1, ja0, ja1, ib0, ib1, jb0, jb1, ii, jj
    real(dp) :: w
    logical :: tight_u, tight_v, oka, okb
    kind = -1
    hc = 0.0_dp
    llen = pb%r - pa%r
    den = dsm%a * (1.0_dp - dsm%e2) + min(hlow, 0.0_dp)
    if (.not. (den > den_min_frac * dsm%a * (1.0_dp - dsm%e2))) return
    rho = axis_distance(s, l, pa%r, pb%r)
    if (.not. (rho > 1.0e-6_dp * dsm%a)) return
    lat2 = lat_second_bound(dsm, den, rho)
    cmom = abs(s(1) * l(2) - s(2) * l(1))
    dlat_r = 0.125_dp * lat2 * llen**2                    ! radians
    dlon_r = 0.25_dp * cmom * llen**2 / rho**3
    tight_v = dlat_r <= chord_tol
    tight_u = dlon_r <= chord_tol
    ! in cells, with the rounding of the ends' and any point's computed latitude and longitude
    ! (1e-14 rad, as the fast path allows)
    dev_v = (dlat_r + 1.0e-14_dp) / abs(dsm%dlat)
    dev_u = (dlon_r + 1.0e-14_dp) / dsm%dlon
    if (.not. (dev_u < 0.25_dp .and. dev_v < 0.25_dp)) return
    ! pb's u on pa's side of the wrap (longitude is continuous along the segment)
    ub = pa%u + (modulo(pb%lon - pa%lon + pi, 2.0_dp * pi) - pi) / dsm%dlon
    ! past a regional grid's wrap meridian (lonc +- pi) pb lies one turn back in u: no rule (its
    ! "beyond the edge" took a ray across a 350-degree wedge's gap as outside: a review)
    if (.not. dsm%global .and. .not. (ub > dsm%uw .and. ub < dsm%uw + dsm%uturn)) return
    call point_class(dsm, pa%u, pa%v, fa, ia, ja)
    call point_class(dsm, ub, pb%v, fb, ib, jb)
    common = iand(fa, fb)
    if (dsm%interp /= interp_nearest .and. common == 0) then
      ! bilinear: the surface is continuous across cells, so the bound over the path's own box (the
      ! chord's, widened by the departure and rounding) is all that is needed; a box that takes in
      ! a cell without data (+huge) gets no rule. Both ends in one cell without data, the path
      ! inside it: a no-data point from the start.
      if (ia >= 0 .and. ia == ib .and. ja == jb) then
        if (any(ieee_is_nan(dsm%hgt(ja + 1:ja + 2, ia + 1:ia + 2))) .and. &
            min(cell_gap(pa%v), cell_gap(pb%v)) > dev_v .and. min(cell_gap(pa%u), cell_gap(ub)) > dev_u) then
          kind = chord_nodata
          return
        end if
      end if
      call dsm_box_bound(dsm, min(pa%u, ub) - dev_u, max(pa%u, ub) + dev_u, &
                         min(pa%v, pb%v) - dev_v, max(pa%v, pb%v) + dev_v, hc, out)
      if (hc < huge(1.0_dp)) then
        kind = chord_bound
        return
      end if
      ! the box takes in a cell without data. A path within chord_tol of its chord whose ends the
      ! lookup puts in cells with data (the same or neighbours) is taken to be over them: a ray
      ! 2e-16 to 5e-15 rad beside a no-data node line (26 ulps; the lookup never put a point of it
      ! over no-data) had every segment's box touch the no-data cell through the rounding allowance:
      ! STEP_LIMIT (a seventh review). A flip of the lookup between the ends is not looked for (a ray
      ! exactly on such a line, where the lookup flips with the last bit, can so end in a hit).
      ! An end exactly on an interior node line (point_class: no one cell) is taken in the cell the
      ! lookup itself uses there (dsm_cells): a nadir ray in the equator's plane, along a node row
      ! at latitude 0 with a no-data node in the row beside it, had every box take in that node
      ! and ended STEP_LIMIT after 100,216 segments where the following hit (the simulation's fuzz
      ! family, seed 7301). Only when each coordinate of each end is exactly on a node line or off
      ! every node line by more than the rounding allowance: a nadir ray on a node column whose
      ! latitude sat within an ulp of a node row flickered between the rows, and the rule over the
      ! ends' row missed the no-data point between them, 100 m late (a review; docs/shin-park-notes.md,
      ! "Exact mode" 3a)
      if (tight_u .and. tight_v .and. fa == 0 .and. fb == 0 .and. (ia < 0 .or. ib < 0) .and. &
          on_or_off(pa%u, dev_u) .and. on_or_off(ub, dev_u) .and. on_or_off(pa%v, dev_v) .and. &
          on_or_off(pb%v, dev_v)) then
        call dsm_cells(dsm, pa%u, pa%v, ia0, ia1, ja0, ja1, oka)
        call dsm_cells(dsm, ub, pb%v, ib0, ib1, jb0, jb1, okb)
        if (oka .and. okb) then
          ia = ia0
          ja = ja0
          ib = ib0
          jb = jb0
        end if
      end if
      if (tight_u .and. tight_v .and. ia >= 0 .and. ib >= 0) then
        if (abs(ia - ib) <= 1 .and. abs(ja - jb) <= 1) then
          call dsm_box_bound(dsm, max(min(pa%u, ub) - dlon_r / dsm%dlon, real(min(ja, jb), dp)), &
                             min(max(pa%u, ub) + dlon_r / dsm%dlon, max(ja, jb) + 1.0_dp), &
                             max(min(pa%v, pb%v) - dlat_r / abs(dsm%dlat), real(min(ia, ib), dp)), &
                             min(max(pa%v, pb%v) + dlat_r / abs(dsm%dlat), max(ia, ib) + 1.0_dp), hc, out)
          if (hc < huge(1.0_dp)) kind = chord_bound
        end if
      end if
      return
    end if
    if (common /= 0) then
      lo = 0.0_dp
      if (dsm%interp == interp_nearest) lo = 0.5_dp
      ev = dsm%ev
      eu = dsm%eu
      ! beyond the edge by more than the departure (or the departure below chord_tol)
      if (iand(common, 1) /= 0) then
        gap = (-lo - ev) - max(pa%v, pb%v)
        if (tight_v .or. gap > dev_v) kind = chord_outside
      end if
      if (iand(common, 2) /= 0) then
        gap = min(pa%v, pb%v) - (dsm%nrows - 1 + lo + ev)
        if (tight_v .or. gap > dev_v) kind = chord_outside
      end if
      if (iand(common, 4) /= 0) then
        gap = (-lo - eu) - max(pa%u, ub)
        if (tight_u .or. gap > dev_u) kind = chord_outside
      end if
      if (iand(common, 8) /= 0) then
        gap = min(pa%u, ub) - (dsm%ncols - 1 + lo + eu)
        if (tight_u .or. gap > dev_u) kind = chord_outside
      end if
    else if (fa == 0 .and. fb == 0 .and. ia >= 0 .and. ia == ib .and. ja == jb) then
      ! inside the cell by more than the departure, across rows and across columns (boundaries at
      ! k + 1/2); a cell without data: a no-data point from the start only if the path is in it
      if (.not. (tight_v .or. min(cell_gap(pa%v + 0.5_dp), cell_gap(pb%v + 0.5_dp)) > dev_v)) return
      if (.not. (tight_u .or. min(cell_gap(pa%u + 0.5_dp), cell_gap(ub + 0.5_dp)) > dev_u)) return
      hc = dsm%hgt(ja + 1, ia + 1)
      kind = chord_cell
      if (ieee_is_nan(hc)) then
        kind = -1
        if (min(cell_gap(pa%v + 0.5_dp), cell_gap(pb%v + 0.5_dp)) > dev_v .and. &
            min(cell_gap(pa%u + 0.5_dp), cell_gap(ub + 0.5_dp)) > dev_u) kind = chord_nodata
      end if
    else if (fa == 0 .and. fb == 0 .and. dsm%interp == interp_nearest .and. tight_u .and. tight_v) then
      ! both ends on a cell boundary (the lookup takes the cells on both sides, walls solid), the
      ! path within chord_tol of its chord: it takes the cells its ends' lookups agree on, the
      ! tallest of them, as the bilinear rule above takes its ends' cells. A ray straight down the
      ! line where two rows meet, 1.8e-9 m beside a column boundary whose other side held a taller
      ! cell, had every segment's box take in that cell through its margins, and the ground was
      ! searched refine_tol by refine_tol: STEP_LIMIT after 100,216 steps (the simulation fuzzing,
      ! 2026-12-03); docs/shin-park-notes.md, "Exact mode" 3a
      call dsm_cells(dsm, pa%u, pa%v, ia0, ia1, ja0, ja1, oka)
      call dsm_cells(dsm, ub, pb%v, ib0, ib1, jb0, jb1, okb)
      if (oka .and. okb .and. ia0 == ib0 .and. ia1 == ib1 .and. ja0 == jb0 .and. ja1 == jb1) then
        hc = -huge(1.0_dp)
        do ii = ia0, ia1
          do jj = ja0, ja1
            w = dsm%hgt(merge(dsm%ncols, jj + 1, jj < 0), ii + 1)     ! (jj = -1: the seam's last column)
            if (ieee_is_nan(w)) return
            hc = max(hc, w)
          end do
        end do
        kind = chord_cell
      end if
    end if

  contains

    !> distance from x to the nearest integer (the caller shifts nearest cells' boundaries there)
    pure function cell_gap(x) result(g)
      real(dp), intent(in) :: x
      real(dp) :: g, f
      f = x - floor(x)
      g = min(f, 1.0_dp - f)
    end function cell_gap

    !> x exactly on a node line (an integer), or farther from every node line than dev
    pure function on_or_off(x, dev) result(ok)
      real(dp), intent(in) :: x, dev
      logical :: ok
      ok = x == aint(x) .or. cell_gap(x) > dev
    end function on_or_off

  end subroutine chord_class

  !> Where a point (u, v) lies for the chord rule: flags = the edges it is beyond (1, 2: v below,
  !> above; 4, 8: u below, above; bits of a global grid's u never set), 0 inside the defined area (with
  !> height_uv's edge slack); i, j its cell as height_uv takes it (pi_dsm's dsm_cells), both -1 where
  !> the point is outside or touches several cells (a nearest cell boundary, the seam; for bilinear,
  !> an interior node line, where the cells on both sides are as near).
  pure subroutine point_class(dsm, u, v, flags, i, j)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: u, v
    integer, intent(out) :: flags, i, j
    real(dp) :: lo
    integer :: i0, i1, j0, j1
    logical :: ok
    flags = 0
    i = -1
    j = -1
    lo = 0.0_dp
    if (dsm%interp == interp_nearest) lo = 0.5_dp
    if (v < -lo - dsm%ev) flags = ior(flags, 1)
    if (v > dsm%nrows - 1 + lo + dsm%ev) flags = ior(flags, 2)
    if (.not. dsm%global) then
      if (u < -lo - dsm%eu) flags = ior(flags, 4)
      if (u > dsm%ncols - 1 + lo + dsm%eu) flags = ior(flags, 8)
    end if
    if (flags /= 0) return
    if (dsm%interp /= interp_nearest) then
      if (v == aint(v) .and. v > 0.0_dp .and. v < dsm%nrows - 1) return   ! on a node row
      if (u == aint(u) .and. u > 0.0_dp .and. u < dsm%ncols - 1) return   ! on a node column
    end if
    call dsm_cells(dsm, u, v, i0, i1, j0, j1, ok)
    if (.not. ok .or. i0 /= i1 .or. j0 /= j1) return
    i = i0
    j = j0
  end subroutine point_class

  !> Move on to the next pending segment [pb, top of the stack]; nst = -1
  !> when none is left.
  pure subroutine next_segment(pa, pb, stack, nst)
    type(rpt_t), intent(inout) :: pa, pb
    type(rpt_t), intent(in) :: stack(:)
    integer, intent(inout) :: nst
    pa = pb
    if (nst == 0) then
      nst = -1
      return
    end if
    pb = stack(nst)
    nst = nst - 1
  end subroutine next_segment

  !> Trace n rays with one of the three methods; OpenMP over rays with a
  !> num_threads clause (threads <= 0: all), no shared mutable state, so the
  !> results are bit-identical for any thread count. The rays are traced in
  !> pi_ray_order's order (spatially sorted unless the batch is coherent
  !> already); the results are the same in any order.
  !>
  !> Inputs: dsm; s(3, n), l(3, n) ECR (l any non-zero length); method.
  !> Outputs: p(3, n) hit points, q(3, n) event points; scal(10, n) = lat, lon,
  !> h, H, r, incidence (hits; radians), qlat, qlon, qh, qr (events), NaN
  !> where not set; status(n) ray_* codes; nsteps(n). stat: stat_bad_mode for
  !> an unknown method. method: 0 following, 1 exact (pi_dsm_fast's fast path,
  !> exact_ray where it declines), 2 iterative; internal (tests): 3 exact_ray
  !> alone, 4 the fast path alone (ray_fast_declined where it declines).
  !> fan >= 2 (exact method only): the rays come in consecutive groups of fan
  !> (the last may be shorter); a group whose rays share one focal point is
  !> first swept as a whole (pi_dsm_sweep) and each ray's search starts at its
  !> certified clear distance (pi_dsm_fast's fast_from). The answers are the
  !> exact mode's to its tolerance, not bit for bit those without fans.
  !> fan = -1 (pi_dsm_sweep's sweep_runs): the groups are the runs of
  !> consecutive rays with one focal point (pi.intersect's exact method).
  subroutine dsm_trace_packed(dsm, n, s, l, method, threads, p, q, scal, status, nsteps, stat, fan)
    type(dsm_t), intent(in) :: dsm
    integer, intent(in) :: n, method, threads
    real(dp), intent(in) :: s(3, n), l(3, n)
    real(dp), intent(out) :: p(3, n), q(3, n), scal(10, n)
    integer, intent(out) :: status(n), nsteps(n), stat
    !> rays per fan (0 or 1: none; -1: runs of one focal point)
    integer, intent(in), optional :: fan
    integer :: kk, nt, nf
    real(dp) :: nan
    real(dp), allocatable :: rclear(:)
    integer, allocatable :: order(:)
    logical :: fans, sorted, exact_steps
    nan = nan_dp
    stat = stat_ok
    if (method < 0 .or. method > 4) then
      p = nan; q = nan; scal = nan; status = ray_bad_direction; nsteps = 0
      stat = stat_bad_mode
      return
    end if
    ! (no fill of the outputs first: trace_one writes every column, order being a permutation of
    ! 1..n, and the f2py wrapper hands over its arrays unfilled (intent(out, cache)); the two
    ! passes over 136 bytes a ray were ~3 % of an image simulation's time: simulation note 15)
    nt = 1
    !$ nt = omp_get_max_threads()
    if (threads > 0) nt = threads
    nf = 0
    if (present(fan)) nf = fan
    fans = (nf >= 2 .or. nf == sweep_runs) .and. method == dsm_method_exact
    if (fans) then
      allocate(rclear(n))
      call sweep_fans(dsm, n, s, l, nf, nt, rclear)
    end if
    ! the rays in an order that keeps the grid in cache (pi_ray_order; each ray's answer depends on
    ! its own s, l and rclear alone and goes to its own column: the same results in any order)
    allocate(order(n))
    call ray_order(dsm, n, s, l, order, sorted)
    ! the following steps by eq. 2 unless it is off on this body at these heights [note 10]
    exact_steps = .false.
    if (method == dsm_method_following) exact_steps = bowring_error(dsm) > bowring_tol * dsm%a
    !$omp parallel do schedule(dynamic, 64) num_threads(nt) default(shared) private(kk)
    do kk = 1, n
      call trace_one(order(kk))
    end do
    !$omp end parallel do

  contains

    !> One ray: checks, then the method; results into column k.
    subroutine trace_one(k)
      integer, intent(in) :: k
      type(dsm_ray_t) :: res
      real(dp) :: ln, lu(3), lat, lon, h, hs, dh
      integer :: code, nfast
      logical :: ok, clear
      res%p = nan; res%lat = nan; res%lon = nan; res%h = nan; res%hs = nan; res%r = nan
      res%incidence = nan; res%q = nan; res%qlat = nan; res%qlon = nan; res%qh = nan; res%qr = nan
      res%nsteps = 0
      ln = norm2(l(:, k))
      if (.not. (ieee_is_finite(ln) .and. ln > 0.0_dp)) then
        res%status = ray_bad_direction
      else if (.not. all(ieee_is_finite(s(:, k)))) then
        res%status = ray_bad_position
      else
        lu = l(:, k) / ln
        ! s outside the sphere |P| = a + H_max (h > H_max there) cannot be inside: skip the conversion
        code = pt_outside
        h = 0.0_dp
        hs = 0.0_dp
        if (.not. (dot_product(s(:, k), s(:, k)) > (dsm%a + max(dsm%hmax, 0.0_dp) + 1.0e-9_dp * dsm%a)**2)) then
          call ray_geo(dsm, s(:, k), lu, 0.0_dp, lat, lon, h, dh)
          call dsm_height(dsm, lat, lon, hs, code)
        end if
        if (code == pt_ok .and. h <= hs) then
          res%status = ray_inside
        else if (method == dsm_method_following) then
          call follow_ray(dsm, s(:, k), lu, res, exact_steps)
        else if (method == dsm_method_exact) then
          if (fans) then                                  ! the fast path (from the sweep's clear distance)
            call fast_ray(dsm, s(:, k), lu, res, ok, rclear(k))
          else
            call fast_ray(dsm, s(:, k), lu, res, ok)        ! the fast path, exact_ray where it declines
          end if
          if (.not. ok) then
            nfast = res%nsteps
            clear = res%slab_clear                        ! (a copy: no aliasing with res)
            call exact_ray(dsm, s(:, k), lu, res, clear)
            res%nsteps = res%nsteps + nfast
          end if
        else if (method == dsm_method_exact_reference) then
          call exact_ray(dsm, s(:, k), lu, res)
        else if (method == dsm_method_exact_fast_only) then
          call fast_ray(dsm, s(:, k), lu, res, ok)
          if (.not. ok) res%status = ray_fast_declined
        else
          call iterate_ray(dsm, s(:, k), lu, res)
        end if
      end if
      p(:, k) = res%p
      q(:, k) = res%q
      scal(:, k) = [res%lat, res%lon, res%h, res%hs, res%r, res%incidence, res%qlat, res%qlon, res%qh, res%qr]
      status(k) = res%status
      nsteps(k) = res%nsteps
    end subroutine trace_one

  end subroutine dsm_trace_packed

end module pi_dsm_exact
