!> Fast path of the exact DSM mode (method "exact"): the same answer as
!> pi_dsm_exact's exact_ray (the guarantee of docs/shin-park-notes.md, "Exact mode", to
!> refine_tol along the ray), with far fewer exact geodetic conversions
!> (docs/shin-park-notes.md, "Fast exact path").
!>
!> exact_ray converts every point of its depth-first subdivision (~0.3 us
!> each). Here the subdivision runs on cheap points whose bounds stay rigorous:
!>  * height: h(r) is convex along the line, so the tangents at the exact end
!>    points of a piece are lower bounds everywhere; a segment's lowest height
!>    is bounded by the larger of the two tangents (no conversion);
!>  * longitude: linear between the piece's exact ends, widened by L^2/(4 rho^2)
!>    (rho^2 lambda' is constant along a line, so |lambda''| <= 2/rho^2);
!>  * latitude: linear between the exact ends, widened by psi''max L^2 / 8 with
!>    |psi''| <= kap/den + (|dM/dpsi|/den + 1)/den^2 (psi' = (l.north)/(M + h);
!>    |d(l.north)/dr| <= kap = 1/den + 1/rho as in pi_dsm_exact; |l.north| <= 1,
!>    |h'| <= 1; den = M_min + min(h_low, 0), rho the piece's axis distance).
!> The slab [r_in, r_end] (first crossings of H_max and H_min) is cut into
!> pieces of at most fast_piece (units of a) with exact ends. A segment that
!> cannot be ruled out has its start moved past the prefix where a falling
!> tangent is still above the box's surface bound; one of at most fast_sub
!> becomes a sub-piece with exact ends (tangent bound within ~1e-7 m of h),
!> where a "nearest" cell is solved by Newton and a bilinear cell's candidate
!> entry in closed form (a quadratic), then classified by one conversion.
!> A certified ray's first piece (fast_from, after pi_dsm_sweep) has one exact
!> end: its far end is a first-order model (tangent_end), its (u, v) models
!> widened by the remainder from one end, converted only when the search goes
!> past it (docs/shin-park-notes.md, "Seventh look").
!>
!> The fast path declines (ok = .false.; the caller then runs exact_ray) when
!> its assumptions do not hold: a slab longer than fast_maxlen, a latitude or
!> longitude widening above fast_maxdv cells (near the poles, huge spans), a
!> ray that meets no hit and no data over the slab and whose first low point
!> outside the DSM left_search cannot pin down (then res%slab_clear: exact_ray
!> skips its own search for hits; docs/shin-park-notes.md, "Eleventh look"),
!> or its segment limit. So correctness never depends on its coverage; the
!> statuses and distances equal exact_ray's to refine_tol (tests/test_dsm_fast.py).
module pi_dsm_fast
  use pi_kinds, only: dp
  use pi_status
  use pi_vector, only: pi, axis_distance, far_distance
  use pi_dsm, only: dsm_t, dsm_height, dsm_grid_uv, dsm_box_bound, interp_nearest, interp_bilinear, pt_ok, &
                    pt_nodata, pt_outside
  use pi_follow, only: dsm_ray_t, ray_geo, level_crossing_back, ellipsoid_entry, set_hit, set_event, settle_start, &
                       refine_tol, newton_tol
  use pi_geodetic, only: ecr_to_geodetic_near
  use pi_ieee, only: ieee_is_nan => is_nan        ! (one test per bilinear cell solve: not in the hot loop)
  implicit none
  private

  public :: fast_ray, fast_piece, fast_sub, fast_maxlen, fast_maxdv, lat_second_bound

  !> longest piece with one linear latitude model (units of a: ~640 m on Earth;
  !> its widening there is ~0.004 m on the ground)
  real(dp), parameter :: fast_piece = 1.0e-4_dp
  !> longest slab the fast path takes (units of a: ~64 km on Earth)
  real(dp), parameter :: fast_maxlen = 1.0e-2_dp
  !> largest latitude widening (grid rows) the fast path accepts
  real(dp), parameter :: fast_maxdv = 0.25_dp
  !> longest candidate segment searched as a piece of its own (units of a: ~1.9 m on Earth)
  real(dp), parameter :: fast_sub = 3.0e-7_dp
  !> rounding margins of the bounds: the exact conversion's height (relative
  !> to a; its Newton stops at a step of 1e-15 (|t| + a^2), then rounding of a
  !> few ulps of a) and latitude (radians; atan2 of the foot-point gradient)
  real(dp), parameter :: fast_hmarg = 1.0e-14_dp, fast_latmarg = 1.0e-14_dp
  !> where a segment is split (fraction of its length from its start; only
  !> speed depends on it: 0.35 gave the fewest segments on the building and
  !> city rays, 0.5 ~7 % more, 0.15 or 0.65 ~17 % more)
  real(dp), parameter :: fast_split = 0.35_dp
  !> segment limit per ray and subdivision stack depth
  integer, parameter :: fast_maxseg = 20000, fast_depth = 128
  !> what a refine_tol leaf counts toward fast_maxseg (so at most ~200 leaves before the decline)
  integer, parameter :: fast_leaf = 100
  !> segments a certified ray's one-ended first piece may take (fast_from) before it is searched
  !> again with an exact far end (a ray takes ~5-20 there; a leaf counts fast_leaf)
  integer, parameter :: fast_onebudget = 250
  !> largest (u, v) widening of a one-ended piece (grid cells; ~2e-5 on a 9 degree ray over 1 m cells
  !> on Earth, ~0.3 over 10 m cells of a 13 km body, where it cost more segments than it saved)
  real(dp), parameter :: fast_onedv = 1.0e-3_dp
  !> conversions after which the fast path declines: rays aimed within ~1e-8 deg of a cell corner
  !> took 3,800-6,300 here where exact_ray needs 19-43 (a review); a benchmark ray takes ~6
  integer, parameter :: fast_maxconv = 1000
  !> outcomes of a piece search
  integer, parameter :: out_clear = 0, out_decided = 1, out_declined = 2
  !> pieces a slab may have for left_search (more: exact_ray's search for the first point outside)
  integer, parameter :: left_maxpc = 16
  !> margin of left_search's edge tests beyond the models' widening (cells: dsm_grid_uv's rounding
  !> of u, v near the grid, a few ulps of pi / dlon, as segment_bounds' wu)
  real(dp), parameter :: left_marg = 1.0e-9_dp
  !> widest interval left_search halves to refine_tol on the lookup's classes (units of length:
  !> a crossing pinned by the models' rounding margin only, ~1e-6-1e-5 m on Earth; wider ones,
  !> rays grazing an edge, are exact_ray's)
  real(dp), parameter :: left_maxw = 1.0e-4_dp
  !> left_search and res%slab_clear only for a slab that starts inside the area by this many cells
  !> and where the ray descends through H_max at least this steeply (dh/dr; 1e-3: 0.06 deg)
  real(dp), parameter :: left_start_marg = 1.0e-3_dp, left_min_dh = 1.0e-3_dp

  !> an exact ray point: r, geodetic lat, lon, h, dh/dr, grid u, v, the
  !> ellipsoid normal there (ECR)
  type :: xpt_t
    real(dp) :: r, lat, lon, h, dh, u, v, nx, ny, nz
  end type xpt_t

  !> a cheap ray point: r, grid u (exact to rounding), v of the linear latitude model
  type :: lpt_t
    real(dp) :: r, u, v
  end type lpt_t

  !> a piece [A, B]: its exact ends and the latitude widening dv (grid rows);
  !> set by piece_ends: 1 / (B - A), the tangents' kink rk (+huge: none) and
  !> their value there, the ends' falling tangents' 1 / h' (0: not falling)
  type :: piece_t
    type(xpt_t) :: a, b
    real(dp) :: dv, du, hmarg
    real(dp) :: ilen = 0, rk = 0, tk = 0, ida = 0, idb = 0
    !> b is an exact ray point (.false.: tangent_end's model end; eval_p then converts there)
    logical :: bx = .true.
  end type piece_t

contains

  !> Exact ray point at r (one conversion); with ref, an exact point of the
  !> same ray nearby, by pi_geodetic's ecr_to_geodetic_near (Newton started
  !> from ref's tangent, angles as increments on ref's: the same answer to
  !> ~1e-15 relative, about a third of the cost). ref must not be q itself.
  !> Without ref the same routine starts from the DSM's centre (dsm_t's clat, clon and
  !> normal) and the slab's middle height: on a regional DSM no atan2 and 1-2 fewer Newton
  !> steps than ecr_to_geodetic_nb, to which it falls back beyond 0.01 rad of the centre.
  pure subroutine eval_x(dsm, s, l, r, q, ref)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r
    type(xpt_t), intent(out) :: q
    type(xpt_t), intent(in), optional :: ref
    real(dp) :: p(3)
    p = s + r * l                                           ! Shin & Park eq. 1
    if (present(ref)) then
      call ecr_to_geodetic_near(p(1), p(2), p(3), dsm%a, dsm%f, ref%lat, ref%lon, ref%nx, ref%ny, ref%nz, &
                                ref%h + ref%dh * (r - ref%r), q%lat, q%lon, q%h, q%nx, q%ny, q%nz)
    else
      ! no point of this ray yet: the DSM's centre as the reference (ecr_to_geodetic_near falls
      ! back to ecr_to_geodetic_nb beyond 0.01 rad of it) and the slab's middle as the height
      ! estimate; the same answer as ecr_to_geodetic_nb to ~1e-15 relative, without its two
      ! atan2 and with 1-2 fewer Newton steps on a regional DSM
      call ecr_to_geodetic_near(p(1), p(2), p(3), dsm%a, dsm%f, dsm%clat, dsm%clon, dsm%cnx, dsm%cny, dsm%cnz, &
                                0.5_dp * (dsm%hmax + dsm%hmin), q%lat, q%lon, q%h, q%nx, q%ny, q%nz)
    end if
    q%dh = l(1) * q%nx + l(2) * q%ny + l(3) * q%nz          ! dh/dr = l . n
    q%r = r
    call dsm_grid_uv(dsm, q%lat, q%lon, q%u, q%v)
  end subroutine eval_x

  !> The ray point at r from the exact point x a short way before it
  !> (0 <= r - x%r <= 1e-8 min(a, rho), ~6 cm on Earth), without a conversion: latitude
  !> and longitude to first order along the ray (dpsi/dr = (l.north)/(M + h),
  !> dlambda/dr = (l.east)/((N + h) cos psi); the second-order terms are below
  !> (3/M^2 + 2/rho^2) d^2/2 ~ 3e-16 rad, under the conversion's own rounding
  !> margin fast_latmarg), h to first order (h'' <= 1/M_min: <= 3e-10 m) and
  !> h' with the curvature (1 - h'^2)/(N + h) (error <= d e^2/a: ~1e-10).
  !> ok = .false. (q not set) when d is out of range or the point is within
  !> 1e-3 rad of a pole.
  pure subroutine extrapolate(dsm, l, x, r, q, ok)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: l(3), r
    type(xpt_t), intent(in) :: x
    type(xpt_t), intent(out) :: q
    logical, intent(out) :: ok
    real(dp) :: d, cp, mm, nn, ln, le
    d = r - x%r
    call local_rates(dsm, l, x, cp, nn, mm, ln, le)
    ! d at most 1e-8 of the axis distance rho = (N + h) cos(lat) too: the longitude's second-order
    ! term grows as d^2 / rho^2 (a review measured 7.7e-13 rad 6 km from the pole with d = 1e-8 a)
    ok = d >= 0.0_dp .and. d <= 1.0e-8_dp * min(dsm%a, (nn + x%h) * cp) .and. cp > 1.0e-3_dp
    if (.not. ok) return
    q = x
    q%r = r
    q%lat = x%lat + d * ln / (mm + x%h)
    q%lon = x%lon + d * le / ((nn + x%h) * cp)
    q%h = x%h + d * x%dh
    q%dh = x%dh + d * (1.0_dp - x%dh**2) / (nn + x%h)
    call dsm_grid_uv(dsm, q%lat, q%lon, q%u, q%v)
  end subroutine extrapolate

  !> At the exact point x: cos(latitude) cp (from the normal), the prime vertical and
  !> meridian radii of curvature nn and mm, and the components ln = l.north, le = l.east
  !> of the ray's direction (north = (-sin psi cos lambda, -sin psi sin lambda, cos psi),
  !> east = (-sin lambda, cos lambda, 0)); shared by extrapolate and tangent_end. ln and le
  !> are not used (and may be huge or NaN) when cp is 0.
  pure subroutine local_rates(dsm, l, x, cp, nn, mm, ln, le)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: l(3)
    type(xpt_t), intent(in) :: x
    real(dp), intent(out) :: cp, nn, mm, ln, le
    real(dp) :: w
    cp = sqrt(x%nx**2 + x%ny**2)                            ! cos(latitude)
    w = 1.0_dp - dsm%e2 * x%nz**2
    nn = dsm%a / sqrt(w)                                    ! prime vertical radius of curvature
    mm = nn * (1.0_dp - dsm%e2) / w                         ! meridian radius of curvature
    if (cp > 0.0_dp) then
      ln = (-x%nz * (l(1) * x%nx + l(2) * x%ny)) / cp + l(3) * cp
      le = (-l(1) * x%ny + l(2) * x%nx) / cp
    else
      ln = 0.0_dp
      le = 0.0_dp
    end if
  end subroutine local_rates

  !> The far end of a one-ended piece: the point len (> 0) after the exact point x
  !> on the first-order models of extrapolate (latitude and longitude; u, v from
  !> them), with h and h' of x's tangent, without a conversion. It is not the ray
  !> point there: make_piece (one = .true.) widens the piece's (u, v) models by
  !> the models' remainders from one end, |psi''| len^2 / 2 and |lambda''| len^2 / 2
  !> (<= len^2 / rho^2), and eval_p converts instead of returning it; its tangent
  !> is x's, a lower bound of h everywhere (convexity), so h_lower and
  !> clear_prefix hold as they are. ok = .false. (q not set) within 1e-3 rad of
  !> a pole or when len is not positive and finite.
  pure subroutine tangent_end(dsm, l, x, len, q, ok)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: l(3), len
    type(xpt_t), intent(in) :: x
    type(xpt_t), intent(out) :: q
    logical, intent(out) :: ok
    real(dp) :: cp, mm, nn, ln, le
    call local_rates(dsm, l, x, cp, nn, mm, ln, le)
    ok = len > 0.0_dp .and. len < huge(1.0_dp) .and. cp > 1.0e-3_dp
    if (.not. ok) return
    q = x
    q%r = x%r + len
    q%lat = x%lat + len * ln / (mm + x%h)                   ! dpsi/dr = (l.north)/(M + h)
    q%lon = x%lon + len * le / ((nn + x%h) * cp)            ! dlambda/dr = (l.east)/rho
    q%h = x%h + len * x%dh                                  ! the tangent: below h (convexity)
    call dsm_grid_uv(dsm, q%lat, q%lon, q%u, q%v)
  end subroutine tangent_end

  !> Exact ray point at r, reusing the piece's exact end when r is one of
  !> them (the same conversion: bit-identical); n counts conversions made.
  pure subroutine eval_p(dsm, s, l, pc, r, q, n)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r
    type(piece_t), intent(in) :: pc
    type(xpt_t), intent(out) :: q
    integer, intent(inout) :: n
    if (r == pc%a%r) then
      q = pc%a
    else if (r == pc%b%r .and. pc%bx) then
      q = pc%b
    else
      call eval_x(dsm, s, l, r, q, pc%a)
      n = n + 1
    end if
  end subroutine eval_p

  !> Cheap ray point at r on piece pc: u and v of the linear models.
  pure subroutine eval_l(pc, r, q)
    type(piece_t), intent(in) :: pc
    real(dp), intent(in) :: r
    type(lpt_t), intent(out) :: q
    real(dp) :: w
    w = (r - pc%a%r) * pc%ilen
    q%u = pc%a%u + w * (pc%b%u - pc%a%u)
    q%v = pc%a%v + w * (pc%b%v - pc%a%v)
    q%r = r
  end subroutine eval_l

  !> Cheap point of an exact one.
  pure function to_l(x) result(q)
    type(xpt_t), intent(in) :: x
    type(lpt_t) :: q
    q%r = x%r
    q%u = x%u
    q%v = x%v
  end function to_l

  !> Lower bound of h on [ra, rb] from the tangents at the piece's exact ends
  !> (convexity: each tangent is below h everywhere; their maximum is convex
  !> and piecewise linear, so its minimum is at an end or at the kink).
  pure function h_lower(pc, ra, rb) result(hlow)
    type(piece_t), intent(in) :: pc
    real(dp), intent(in) :: ra, rb
    real(dp) :: hlow
    hlow = min(tmax(ra), tmax(rb))
    if (pc%rk > ra .and. pc%rk < rb) hlow = min(hlow, pc%tk)   ! the tangents' kink (piece_ends)
    hlow = hlow - pc%hmarg - 1.0e-13_dp * abs(hlow)
  contains
    pure function tmax(r) result(t)
      real(dp), intent(in) :: r
      real(dp) :: t
      t = max(pc%a%h + pc%a%dh * (r - pc%a%r), pc%b%h + pc%b%dh * (r - pc%b%r))
    end function tmax
  end function h_lower

  !> End of the clear prefix from r0: the largest r where a falling tangent of
  !> the piece is still above hb (with h_lower's margins), less 1e-3 refine_tol
  !> for rounding; h >= that tangent > hb on [r0, rc]. rc = r0 when none.
  pure function clear_prefix(pc, r0, hb) result(rc)
    type(piece_t), intent(in) :: pc
    real(dp), intent(in) :: r0, hb
    real(dp) :: rc, lev
    lev = hb + pc%hmarg + 1.0e-13_dp * (abs(hb) + abs(pc%a%h) + abs(pc%b%h))
    rc = r0
    if (pc%ida < 0.0_dp) rc = max(rc, pc%a%r + (lev - pc%a%h) * pc%ida - 1.0e-3_dp * refine_tol)
    if (pc%idb < 0.0_dp) rc = max(rc, pc%b%r + (lev - pc%b%h) * pc%idb - 1.0e-3_dp * refine_tol)
  end function clear_prefix

  !> Bounds of the segment [pa, pb] of piece pc (as pi_dsm_exact's
  !> segment_bounds): hlow <= h on it, hb >= the surface over its box (+huge
  !> unknown or no-data), cell >= 0 when the box is one "nearest" cell, rsplit
  !> the estimated crossing of the one cell boundary it straddles (clamped to
  !> the segment when only the widening straddles it; 0: none), wm the half
  !> width along the ray of the band around it where the widened box straddles
  !> the boundary (at least refine_tol / 4). Only speed depends on them.
  !> wj >= 0 when that boundary is the meridian between columns wj and wj + 1
  !> of the one row wi ("nearest", the box inside the grid): search_piece's
  !> wall crossing in closed form (wall_cross); -1 otherwise.
  pure subroutine seg_bounds(dsm, pc, pa, pb, hlow, hb, cell, rsplit, wm, wi, wj)
    type(dsm_t), intent(in) :: dsm
    type(piece_t), intent(in) :: pc
    type(lpt_t), intent(in) :: pa, pb
    real(dp), intent(out) :: hlow, hb, rsplit, wm
    integer, intent(out) :: cell, wi, wj
    real(dp) :: v0, v1, u0, u1, t, dm, w
    integer :: ci0, ci1, cj0, cj1
    logical :: out
    hlow = h_lower(pc, pa%r, pb%r)
    cell = -1
    wi = -1
    wj = -1
    rsplit = 0.0_dp
    wm = 0.25_dp * refine_tol
    v0 = min(pa%v, pb%v) - pc%dv
    v1 = max(pa%v, pb%v) + pc%dv
    u0 = min(pa%u, pb%u) - pc%du
    u1 = max(pa%u, pb%u) + pc%du
    call dsm_box_bound(dsm, u0, u1, v0, v1, hb, out)
    if (dsm%interp == interp_bilinear .and. .not. out .and. .not. dsm%global .and. hb < huge(1.0_dp)) then
      ! a box within at most 2 x 2 cells whose nodes all have one height: the bilinear surface is
      ! that height all over it, a flat top as "nearest" has (cell = 1: Newton on h - hb). Near a
      ! tangency over a flat roof the bilinear leaf never decided (h - H within the bounds' rounding
      ! for metres: STEP_LIMIT after ~101,000 segments; shin-park-notes, "Thirteenth look")
      if (u0 >= 0.0_dp .and. v0 >= 0.0_dp .and. u1 <= dsm%ncols - 1 .and. v1 <= dsm%nrows - 1) then
        cj0 = int(u0); cj1 = min(int(u1) + 1, dsm%ncols - 1)
        ci0 = int(v0); ci1 = min(int(v1) + 1, dsm%nrows - 1)
        if (ci1 - ci0 <= 2 .and. cj1 - cj0 <= 2) then
          if (flat_cells(dsm, ci0, ci1, cj0, cj1, dsm%hgt(cj0 + 1, ci0 + 1))) then
            hb = dsm%hgt(cj0 + 1, ci0 + 1)
            cell = 1
          end if
        end if
      end if
    end if
    if (dsm%interp == interp_nearest .and. .not. out .and. .not. dsm%global .and. hb < huge(1.0_dp)) then
      ci0 = ceiling(v0 - 0.5_dp); ci1 = floor(v1 + 0.5_dp)
      cj0 = ceiling(u0 - 0.5_dp); cj1 = floor(u1 + 0.5_dp)
      if (ci0 == ci1 .and. cj0 == cj1) then
        cell = 1
      else if (ci1 - ci0 <= 1 .and. cj1 - cj0 <= 1 .and. flat_cells(dsm, ci0, ci1, cj0, cj1, hb)) then
        cell = 1                                          ! 2 or 4 cells of one height: one flat top
      else if (ci1 - ci0 + cj1 - cj0 == 1) then
        ! one wall between: split just before its estimated crossing (only speed depends on it)
        ! (a crossing outside the segment: only the widening straddles, at the nearer end)
        if (cj1 > cj0) then
          dm = pb%u - pa%u
          t = cj0 + 0.5_dp - pa%u
          w = pc%du
          if (ci0 >= 0 .and. ci0 <= dsm%nrows - 1 .and. cj0 >= 0 .and. cj1 <= dsm%ncols - 1) then
            wi = ci0
            wj = cj0
          end if
        else
          dm = pb%v - pa%v
          t = ci0 + 0.5_dp - pa%v
          w = pc%dv
        end if
        if (abs(dm) > 0.0_dp) then                       ! (no division by zero)
          t = t / dm
          wm = max(wm, 1.5_dp * w * (pb%r - pa%r) / abs(dm))
          if (t > -1.0e6_dp .and. t < 1.0e6_dp) rsplit = pa%r + min(max(t, 0.0_dp), 1.0_dp) * (pb%r - pa%r)
        end if
        if (.not. (rsplit > 0.0_dp .and. wm < huge(1.0_dp))) then
          rsplit = 0.0_dp
          wm = 0.25_dp * refine_tol
        end if
      end if
    end if
  end subroutine seg_bounds

  !> True when every cell of rows ci0..ci1, columns cj0..cj1 (inside the
  !> grid) has the height hb ("nearest": the surface is then hb all over
  !> their union, shared boundaries included; "bilinear", called with node
  !> indices: the four nodes of each of their cells are hb, and so is the
  !> surface on those cells). A NaN hb is never flat.
  pure function flat_cells(dsm, ci0, ci1, cj0, cj1, hb) result(flat)
    type(dsm_t), intent(in) :: dsm
    integer, intent(in) :: ci0, ci1, cj0, cj1
    real(dp), intent(in) :: hb
    logical :: flat
    integer :: i, j
    flat = .false.
    if (.not. (ci0 >= 0 .and. cj0 >= 0 .and. ci1 <= dsm%nrows - 1 .and. cj1 <= dsm%ncols - 1)) return
    do i = ci0, ci1
      do j = cj0, cj1
        if (.not. (dsm%hgt(j + 1, i + 1) == hb)) return
      end do
    end do
    flat = .true.
  end function flat_cells

  !> Within one bilinear cell with data at its four nodes: the first r in
  !> [pa, pb] where the lower bound of h (the larger tangent, a line on each
  !> side of the tangents' kink) meets an upper bound of the surface (the
  !> bilinear along the linear (u, v) models, a quadratic in r, plus the
  !> models' widening times the surface's slopes and a rounding margin).
  !> st = 0: not one bilinear cell with data (not used); 1: h stays above the
  !> surface on [pa, pb]; 2: no entry before rstar (the candidate).
  pure subroutine cell_solve(dsm, pc, pa, pb, st, rstar)
    type(dsm_t), intent(in) :: dsm
    type(piece_t), intent(in) :: pc
    type(lpt_t), intent(in) :: pa, pb
    integer, intent(out) :: st
    real(dp), intent(out) :: rstar
    real(dp) :: v0, v1, u0, u1, h00, h01, h10, h11, c, su, sv, m, fa, fb, al, be, len
    real(dp) :: a0, a1, a2, tk, ta, tb, troot
    integer :: i, j, side
    st = 0
    rstar = pb%r
    if (dsm%interp == interp_nearest) return
    v0 = min(pa%v, pb%v) - pc%dv
    v1 = max(pa%v, pb%v) + pc%dv
    u0 = min(pa%u, pb%u) - pc%du
    u1 = max(pa%u, pb%u) + pc%du
    if (.not. (v0 >= 0.0_dp .and. u0 >= 0.0_dp .and. v1 <= dsm%nrows - 1 .and. u1 <= dsm%ncols - 1)) return
    i = min(int(v0), dsm%nrows - 2)
    j = min(int(u0), dsm%ncols - 2)
    if (v1 > i + 1 .or. u1 > j + 1) return
    h00 = dsm%hgt(j + 1, i + 1)
    h01 = dsm%hgt(j + 2, i + 1)
    h10 = dsm%hgt(j + 1, i + 2)
    h11 = dsm%hgt(j + 2, i + 2)
    if (ieee_is_nan(h00) .or. ieee_is_nan(h01) .or. ieee_is_nan(h10) .or. ieee_is_nan(h11)) return
    c = h00 - h01 - h10 + h11
    su = max(abs(h01 - h00), abs(h11 - h10))               ! |dH/du| in the cell
    sv = max(abs(h10 - h00), abs(h11 - h01))               ! |dH/dv|
    m = su * pc%du + sv * pc%dv + 1.0e-13_dp * (abs(h00) + abs(h01) + abs(h10) + abs(h11)) + pc%hmarg
    len = pb%r - pa%r
    if (.not. (len > 0.0_dp)) return
    fa = pa%u - j
    fb = pa%v - i
    al = (pb%u - pa%u) / len
    be = (pb%v - pa%v) / len
    ! upper bound of the surface U(t) = a0 + a1 t + a2 t^2, t = r - pa%r (bilinear of the linear models)
    a0 = h00 + (h01 - h00) * fa + (h10 - h00) * fb + c * fa * fb + m
    a1 = (h01 - h00) * al + (h10 - h00) * be + c * (fa * be + fb * al)
    a2 = c * al * be
    if (.not. (abs(a0) + abs(a1) + abs(a2) < huge(1.0_dp))) return   ! not finite: leave it to the halving
    ! the tangents' kink in t (tangent A is the larger before it, B after)
    tk = huge(1.0_dp)
    ! (relative to A's r: products dh r round at ulp(r), ~7e-9 m from a GEO distance; a review)
    if (pc%a%dh < pc%b%dh) tk = (pc%b%h - pc%a%h - pc%b%dh * (pc%b%r - pc%a%r)) / (pc%a%dh - pc%b%dh) &
                                + (pc%a%r - pa%r)
    st = 1
    do side = 1, 2
      if (side == 1) then
        ta = 0.0_dp
        tb = min(len, tk)
        if (.not. (tb >= ta)) cycle
        call first_root(tangent(pc%a, pa%r) - a0, pc%a%dh - a1, -a2, ta, tb, troot)
      else
        ta = max(0.0_dp, min(tk, len))
        tb = len
        call first_root(tangent(pc%b, pa%r) - a0, pc%b%dh - a1, -a2, ta, tb, troot)
      end if
      if (troot <= tb) then
        st = 2
        rstar = pa%r + max(ta, troot - 1.0e-12_dp * abs(troot) - 1.0e-3_dp * refine_tol)
        return
      end if
    end do
  contains
    !> the tangent at x evaluated at r0 (its value at t = 0), less the rounding margins
    pure function tangent(x, r0) result(v)
      type(xpt_t), intent(in) :: x
      real(dp), intent(in) :: r0
      real(dp) :: v
      v = x%h + x%dh * (r0 - x%r)
      v = v - 1.0e-13_dp * abs(v)
    end function tangent
  end subroutine cell_solve

  !> Smallest t in [ta, tb] with e0 + e1 t + e2 t^2 <= 0 (tb + 1 when none).
  pure subroutine first_root(e0, e1, e2, ta, tb, t)
    real(dp), intent(in) :: e0, e1, e2, ta, tb
    real(dp), intent(out) :: t
    real(dp) :: disc, q, r1, r2, w
    t = tb + 1.0_dp
    if (e0 + ta * (e1 + ta * e2) <= 0.0_dp) then
      t = ta
      return
    end if
    ! where the roots say the polynomial is <= 0, the first point of that set at or after ta (ta
    ! itself when rounding put ta inside it although the value there came out positive: an earlier
    ! candidate only costs a classification, a later one could skip an entry; found by a review)
    if (e2 == 0.0_dp) then
      if (e1 < 0.0_dp) then
        r1 = -e0 / e1
        if (max(ta, r1) <= tb) t = max(ta, r1)
      else if (e1 > 0.0_dp) then
        if (ta <= -e0 / e1) t = ta
      end if
      return
    end if
    disc = e1 * e1 - 4.0_dp * e2 * e0
    q = 0.0_dp
    if (disc >= 0.0_dp) q = -0.5_dp * (e1 + sign(sqrt(disc), e1))
    if (q == 0.0_dp) then                               ! no roots (or a NaN): <= 0 everywhere when e2 < 0
      if (e2 < 0.0_dp) t = ta
      return
    end if
    r1 = q / e2
    r2 = e0 / q
    if (r1 > r2) then
      w = r1; r1 = r2; r2 = w
    end if
    if (e2 > 0.0_dp) then                               ! <= 0 on [r1, r2]
      if (r2 >= ta .and. max(ta, r1) <= tb) t = max(ta, r1)
    else                                                ! <= 0 outside (r1, r2)
      if (ta <= r1 .or. ta >= r2) then
        t = ta
      else if (r2 <= tb) then
        t = r2
      end if
    end if
  end subroutine first_root

  !> First r >= r0 with h(r) <= level, as pi_follow's level_crossing (Newton
  !> from the left on the convex h - level, started on the raised ellipsoid),
  !> returning the exact point x there (r within 1e-9 before the crossing).
  !> It stops without the confirming step: after a Newton step of length d
  !> from a point with slope dh < 0, h'' <= c = 1/(M_min + min(level, 0)) puts
  !> the crossing within c d^2 / |dh| after the new point (when that is below
  !> 0.4 d). neval counts conversions.
  pure subroutine fast_crossing(dsm, s, l, r0, level, x, found, neval)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r0, level
    type(xpt_t), intent(out) :: x
    type(xpt_t) :: xp
    logical, intent(out) :: found
    integer, intent(inout) :: neval
    real(dp) :: r, rg, c, d, eps, den
    logical :: hit, have
    integer :: it
    found = .false.
    have = .false.
    r = r0
    den = dsm%a * (1.0_dp - dsm%e2) + min(level, 0.0_dp)
    c = huge(1.0_dp)
    if (den > 0.0_dp) c = 1.0_dp / den
    if (level > -0.5_dp * dsm%b) then
      rg = level + 1.0e-9_dp * dsm%a + dsm%e2**2 * abs(level) / 8.0_dp
      call ellipsoid_entry(dsm%a + rg, dsm%b + rg, s, l, rg, hit)
      if (hit .and. rg > r0) then
        call eval_x(dsm, s, l, rg, x)
        neval = neval + 1
        if (x%h - level > 0.0_dp .and. x%dh < 0.0_dp) then
          r = rg
          have = .true.
        end if
      end if
    end if
    do it = 1, 300
      if (.not. have) then
        if (it == 1) then
          call eval_x(dsm, s, l, r, x)
        else
          xp = x
          call eval_x(dsm, s, l, r, x, xp)
        end if
        neval = neval + 1
      end if
      have = .false.
      if (x%h - level <= 0.0_dp) then
        found = .true.
        return
      end if
      if (.not. (x%dh < 0.0_dp)) return                ! rising or NaN: never reaches the level
      d = -(x%h - level) / x%dh
      r = r + d
      if (d <= newton_tol(r)) then
        found = .true.
        xp = x
        call eval_x(dsm, s, l, r, x, xp)
        neval = neval + 1
        return
      end if
      eps = c * d * d / (-x%dh)
      if (eps <= 1.0e-9_dp .and. eps <= 0.4_dp * d) then
        found = .true.
        xp = x
        call eval_x(dsm, s, l, r, x, xp)
        neval = neval + 1
        return
      end if
    end do
  end subroutine fast_crossing

  !> The first crossing of level after r0 (the slab's H_max entry and H_min
  !> exit) with one conversion where it can: the point x on the raised
  !> ellipsoid (before the crossing, h > level, falling) and rs = x%r + d, d
  !> the Newton step from x: the crossing lies in [rs, rs + c d^2 / |dh|] (c
  !> as in fast_crossing) and is accepted when that is <= 1e-9 (so h(rs) >=
  !> level, and rs is within 1e-9 before the crossing: fast_crossing's end
  !> point, not converted). Otherwise fast_crossing (then x%r = rs).
  pure subroutine fast_entry(dsm, s, l, r0, level, x, rs, found, neval)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r0, level
    type(xpt_t), intent(out) :: x
    real(dp), intent(out) :: rs
    logical, intent(out) :: found
    integer, intent(inout) :: neval
    real(dp) :: rg, c, d, eps, den
    logical :: hit
    if (level > -0.5_dp * dsm%b) then
      den = dsm%a * (1.0_dp - dsm%e2) + min(level, 0.0_dp)
      rg = level + 1.0e-9_dp * dsm%a + dsm%e2**2 * abs(level) / 8.0_dp
      call ellipsoid_entry(dsm%a + rg, dsm%b + rg, s, l, rg, hit)
      if (hit .and. rg > r0 .and. den > 0.0_dp) then
        call eval_x(dsm, s, l, rg, x)
        neval = neval + 1
        if (x%h - level > 0.0_dp .and. x%dh < 0.0_dp) then
          d = -(x%h - level) / x%dh
          c = 1.0_dp / den
          eps = c * d * d / (-x%dh)
          if (eps <= 1.0e-9_dp .and. eps <= 0.4_dp * d) then
            found = .true.
            rs = rg + d
            return
          end if
        end if
      end if
    end if
    call fast_crossing(dsm, s, l, r0, level, x, found, neval)
    rs = x%r
  end subroutine fast_entry

  !> Set the piece's ends and what depends on them alone (piece_t).
  pure subroutine piece_ends(xa, xb, pc)
    type(xpt_t), intent(in) :: xa, xb
    type(piece_t), intent(inout) :: pc
    real(dp) :: den
    pc%a = xa
    pc%b = xb
    pc%ilen = 0.0_dp
    if (xb%r > xa%r) pc%ilen = 1.0_dp / (xb%r - xa%r)
    pc%rk = huge(1.0_dp)
    pc%tk = huge(1.0_dp)
    den = xa%dh - xb%dh
    if (den < 0.0_dp) then                                  ! the tangents cross
      pc%rk = xa%r + (xb%h - xa%h - xb%dh * (xb%r - xa%r)) / den   ! (relative to xa%r: as in cell_solve)
      pc%tk = max(xa%h + xa%dh * (pc%rk - xa%r), xb%h + xb%dh * (pc%rk - xb%r))
    end if
    pc%ida = 0.0_dp
    pc%idb = 0.0_dp
    if (xa%dh < 0.0_dp) pc%ida = 1.0_dp / xa%dh
    if (xb%dh < 0.0_dp) pc%idb = 1.0_dp / xb%dh
  end subroutine piece_ends

  !> Build piece [xa, xb]: its latitude widening in grid rows (ok = .false.
  !> when the bound does not apply or exceeds fast_maxdv). one = .true.: xb is
  !> tangent_end's model end, not an exact point (pc%bx = .false.).
  pure subroutine make_piece(dsm, s, l, xa, xb, pc, ok, one)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3)
    type(xpt_t), intent(in) :: xa, xb
    type(piece_t), intent(out) :: pc
    logical, intent(out) :: ok
    logical, intent(in), optional :: one
    real(dp) :: mmin, den, rho, psi2, len, flat, flon
    call piece_ends(xa, xb, pc)
    ! the models' error: linear interpolation between two exact ends, psi'' L^2/8 and
    ! lambda'' L^2/8 (<= L^2/(4 rho^2)); the first-order model from one end (tangent_end),
    ! psi'' L^2/2 and lambda'' L^2/2 (<= L^2/rho^2)
    flat = 0.125_dp
    flon = 0.25_dp
    if (present(one)) then
      if (one) then
        pc%bx = .false.
        flat = 0.5_dp
        flon = 1.0_dp
      end if
    end if
    pc%dv = huge(1.0_dp)
    pc%hmarg = fast_hmarg * dsm%a
    ok = .false.
    len = xb%r - xa%r
    if (.not. (len > 0.0_dp)) return
    mmin = dsm%a * (1.0_dp - dsm%e2)                         ! smallest meridian radius of curvature
    den = mmin + min(h_lower(pc, xa%r, xb%r), 0.0_dp)
    if (.not. (den > 0.5_dp * mmin)) return
    rho = axis_distance(s, l, xa%r, xb%r)
    if (.not. (rho > 1.0e-3_dp * dsm%a)) return
    psi2 = lat_second_bound(dsm, den, rho)                    ! |psi''|
    ! interpolation error psi2 L^2 / 8 and rounding of the exact latitudes
    pc%dv = (flat * psi2 * len * len + fast_latmarg * (1.0_dp + abs(xa%lat) + abs(xb%lat))) / abs(dsm%dlat)
    ! longitude along a line: rho^2 lambda' is constant, so |lambda''| = 2 |lambda' rho'| / rho <= 2 / rho^2;
    ! linear interpolation error <= L^2 / (4 rho^2) (from one end: L^2 / rho^2)
    pc%du = (flon * (len / rho)**2 + fast_latmarg * (1.0_dp + pi)) / dsm%dlon
    ok = pc%dv <= fast_maxdv .and. pc%du <= fast_maxdv .and. abs(xb%u - xa%u) < 0.25_dp * pi / dsm%dlon
    ! a one-ended piece only with widenings below fast_onedv (speed: wider boxes straddle more cell
    ! boundaries; the caller then builds the piece with an exact end)
    if (.not. pc%bx) ok = ok .and. pc%dv <= fast_onedv .and. pc%du <= fast_onedv
  end subroutine make_piece

  !> A bound of |psi''|, the second derivative of geodetic latitude along a straight line, on a
  !> stretch whose lowest height h_low gives den = M_min + min(h_low, 0) and whose distance from the
  !> polar axis is at least rho: kappa/den + (|dM/dpsi|/den + 1)/den^2 with kappa = 1/den + 1/rho
  !> (how fast l.north turns; module header). Used by make_piece and pi_dsm_exact's chord rule.
  pure function lat_second_bound(dsm, den, rho) result(psi2)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: den, rho
    real(dp) :: psi2, kap
    kap = 1.0_dp / den + 1.0_dp / rho                        ! |d(l.north)/dr|
    psi2 = kap / den + (dsm%dmdpsi / den + 1.0_dp) / den**2   ! (dmdpsi: |dM/dpsi|, dsm_attach)
  end function lat_second_bound

  !> The exact mode's answer for one ray (l unit, s above the surface), or
  !> ok = .false. (res%nsteps counts its conversions; nothing else is set)
  !> when the fast path declines and exact_ray must be run.
  pure subroutine fast_ray(dsm, s, l, res, ok, rclear)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3)
    type(dsm_ray_t), intent(inout) :: res
    logical, intent(out) :: ok
    !> optional: a distance before which the ray meets nothing (a certificate of
    !> pi_dsm_sweep; <= 0: none); the search then starts there (fast_from)
    real(dp), intent(in), optional :: rclear
    type(xpt_t) :: x_in, x_end, xtmp
    real(dp) :: r_in, r_end, hs, hb, rho, dr, den, gu, gv
    logical :: found, out, used, done
    integer :: code
    ok = .true.
    res%nsteps = 0
    if (present(rclear)) then
      if (rclear > 0.0_dp) then
        call fast_from(dsm, s, l, rclear, res, ok, used)
        if (used) return
      end if
    end if
    ! ---- 1. the search interval (as exact_ray, with the crossings' end points kept):
    ! x_in exact at or (by ~1e-9 a) before r_in, the search's start
    call slab_start(dsm, s, l, x_in, r_in, found, res%nsteps)
    if (.not. found) then
      res%status = ray_dsm_miss
      return
    end if
    ! x_end exact at or (by ~1e-9 a) before r_end; the tail [x_end%r, r_end] is
    ! converted and searched only when the search gets there
    call slab_end(dsm, s, l, r_in, x_end, r_end, res%nsteps)
    ! ---- the start point itself (a box bound below its height over data settles it without the lookup)
    if (x_in%r < r_in) then
      ! x_in is before the start: the box of all points within dr of x_in, dr = r_in - x_in%r
      ! (|dlat/dr| <= 1/den, |dlon/dr| <= 1/rho), where h >= h(r_in) >= H_max (the tangent at x_in)
      dr = 2.0_dp * (r_in - x_in%r) + 1.0e-9_dp * dsm%a
      rho = axis_distance(s, l, x_in%r, r_in + dr)
      den = dsm%a * (1.0_dp - dsm%e2) + min(dsm%hmin, 0.0_dp)
      gv = 1.0e-9_dp + fast_latmarg * (1.0_dp + abs(x_in%lat)) / abs(dsm%dlat)
      gu = 1.0e-9_dp + fast_latmarg * (1.0_dp + pi) / dsm%dlon
      if (rho > 0.0_dp .and. den > 0.0_dp) then
        gv = gv + dr / (den * abs(dsm%dlat))
        gu = gu + dr / (rho * dsm%dlon)
      else
        gv = huge(1.0_dp)
      end if
      hb = huge(1.0_dp)
      out = .true.
      if (gu < 1.0_dp .and. gv < 1.0_dp) &
        call dsm_box_bound(dsm, x_in%u - gu, x_in%u + gu, x_in%v - gv, x_in%v + gv, hb, out)
      if (.not. (hb < dsm%hmax - fast_hmarg * dsm%a - 1.0e-13_dp * abs(dsm%hmax) .and. .not. out)) then
        xtmp = x_in
        call eval_x(dsm, s, l, r_in, x_in, xtmp)         ! not settled: the start point exactly
        res%nsteps = res%nsteps + 1
      end if
    end if
    if (x_in%r < r_in) then
      code = pt_ok                                       ! settled above: no hit, no no-data there
      hs = hb
    else
      call dsm_box_bound(dsm, x_in%u - 1.0e-9_dp, x_in%u + 1.0e-9_dp, x_in%v - 1.0e-9_dp, x_in%v + 1.0e-9_dp, hb, out)
      if (hb < x_in%h .and. .not. out) then
        code = pt_ok
        hs = hb
      else
        call dsm_height(dsm, x_in%lat, x_in%lon, hs, code)
      end if
    end if
    call settle_start(dsm, s, l, r_in, x_in%h, hs, code, res, done)
    if (done) return
    if (.not. (r_end - r_in <= fast_maxlen * dsm%a)) then
      ok = .false.
      return
    end if
    call search_slab(dsm, s, l, x_in, r_in, x_end, r_end, res, ok)
  end subroutine fast_ray

  !> The slab's start (fast_ray's, and left_search's on a certified ray): r_in, the ray's
  !> first point with h <= H_max (0 when s is there already), and x exact at or (by ~1e-9 a)
  !> before it; found = .false. when there is none. neval counts conversions.
  pure subroutine slab_start(dsm, s, l, x, r_in, found, neval)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3)
    type(xpt_t), intent(out) :: x
    real(dp), intent(out) :: r_in
    logical, intent(out) :: found
    integer, intent(inout) :: neval
    real(dp) :: lat, lon, h, dh
    found = .true.
    r_in = 0.0_dp
    if (dot_product(s, s) > (dsm%a + max(dsm%hmax, 0.0_dp) + 1.0e-9_dp * dsm%a)**2) then
      h = huge(1.0_dp)                                   ! outside the sphere |P| = a + H_max: h > H_max
    else
      call ray_geo(dsm, s, l, 0.0_dp, lat, lon, h, dh)
      neval = neval + 1
    end if
    if (h <= dsm%hmax) then
      call eval_x(dsm, s, l, 0.0_dp, x)
      neval = neval + 1
    else
      call fast_entry(dsm, s, l, 0.0_dp, dsm%hmax, x, r_in, found, neval)
    end if
  end subroutine slab_start

  !> fast_ray's answer for a ray known to meet nothing before rc (pi_dsm_sweep's
  !> certificate covers the ray's points with h >= H_min). used = .false.
  !> (nothing decided; res%nsteps counts the conversion made) unless the point
  !> at rc lies in the slab and descends: H_min < h(rc) <= H_max and h'(rc) < 0,
  !> so that h >= h(rc) > H_min on [0, rc] (h is convex along the line, its
  !> tangent at rc a lower bound). The search then starts at rc: first a short
  !> piece of 1.5 cells of horizontal travel, which holds the first event of
  !> almost every certified ray (it stops about a unit before it), never
  !> past the tangent's H_min crossing (so inside the slab), then the rest of the
  !> slab as fast_ray searches it.
  pure subroutine fast_from(dsm, s, l, rc, res, ok, used)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), rc
    type(dsm_ray_t), intent(inout) :: res
    logical, intent(out) :: ok, used
    type(xpt_t) :: x_in, x1, x_end
    real(dp) :: hs, len1, cell, hor, r_end, den
    integer :: code, outcome, nseg
    logical :: done, tok
    ok = .true.
    used = .false.
    if (.not. (rc > 0.0_dp .and. rc < huge(1.0_dp))) return
    call eval_x(dsm, s, l, rc, x_in)
    res%nsteps = res%nsteps + 1
    if (.not. (x_in%h > dsm%hmin .and. x_in%h <= dsm%hmax .and. x_in%dh < 0.0_dp)) return
    used = .true.
    call dsm_height(dsm, x_in%lat, x_in%lon, hs, code)
    call settle_start(dsm, s, l, rc, x_in%h, hs, code, res, done)
    if (done) return
    cell = dsm%a * max(abs(dsm%dlat), dsm%dlon * sqrt(x_in%nx**2 + x_in%ny**2))   ! (cos(lat) from the normal)
    hor = sqrt(max(0.0_dp, 1.0_dp - x_in%dh**2))
    len1 = min(1.5_dp * cell / max(hor, 0.05_dp), (1.0_dp - 1.0e-9_dp) * (x_in%h - dsm%hmin) / (-x_in%dh))
    x1 = x_in
    if (len1 > 10.0_dp * refine_tol) then
      ! first as a one-ended piece (its far end tangent_end's model: no conversion), which holds the
      ! answer of most rays; its end is converted only when the search goes on past it. Only where
      ! its tangent bound stays within refine_tol / 2 of h ((hor len1)^2 / (2 den), h'' <= hor^2/den):
      ! on coarse cells or small bodies the looser bound costs more classifications than it saves
      ! (a review: 13 km body, 10 m cells, 192 -> 219 conversions a ray; 26 -> 42 on its nadir
      ! bilinear rays with 10 refine_tol here). Only speed depends on it.
      ! It gets a budget of fast_onebudget segments (a leaf counts fast_leaf): past it (rays along a
      ! wall or a grid line within the wider boxes' margins) the piece is searched again with an
      ! exact end, as before (a review: corner fans 63 -> 101 conversions a ray without the budget).
      nseg = fast_maxseg - fast_onebudget
      outcome = out_declined
      den = dsm%a * (1.0_dp - dsm%e2) + min(dsm%hmin, 0.0_dp)
      tok = .false.
      if (den > 0.0_dp) tok = (hor * len1)**2 <= refine_tol * den
      if (tok) call tangent_end(dsm, l, x_in, len1, x1, tok)
      if (tok) call search_piece(dsm, s, l, x_in, x1, rc, 1, res, outcome, nseg, .true.)
      if (outcome == out_decided) return
      call eval_x(dsm, s, l, rc + len1, x1, x_in)       ! clear (go on from its end), or not applicable
      res%nsteps = res%nsteps + 1
      if (outcome == out_declined) then
        nseg = 0
        call search_piece(dsm, s, l, x_in, x1, rc, 1, res, outcome, nseg)
        if (outcome == out_decided) return
        if (outcome == out_declined) then
          ok = .false.
          return
        end if
      end if
    end if
    call slab_end(dsm, s, l, x1%r, x_end, r_end, res%nsteps)
    if (.not. (r_end - x1%r <= fast_maxlen * dsm%a)) then
      ok = .false.
      return
    end if
    ! (from the certificate, not the slab's start: a certificate may pass low points outside
    ! the grid, pi_dsm_sweep, so left_search starts at the slab's true start)
    call search_slab(dsm, s, l, x1, x1%r, x_end, r_end, res, ok, x_in)
  end subroutine fast_from

  !> The slab's end after r_from: r_end, the first crossing of H_min (or, when
  !> the ray never reaches it, the last crossing of H_max before it leaves the
  !> sphere |P| = a + H_max, at least r_from), and x_end exact at or (by
  !> ~1e-9 a) before it. neval counts conversions.
  pure subroutine slab_end(dsm, s, l, r_from, x_end, r_end, neval)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r_from
    type(xpt_t), intent(out) :: x_end
    real(dp), intent(out) :: r_end
    integer, intent(inout) :: neval
    real(dp) :: r_far
    logical :: found
    call fast_entry(dsm, s, l, r_from, dsm%hmin, x_end, r_end, found, neval)
    if (.not. found) then
      r_far = far_distance(s, l, dsm%a + max(dsm%hmax, 0.0_dp) + 1.0_dp)
      call level_crossing_back(dsm, s, l, max(r_far, r_from), dsm%hmax, r_end, found, neval)
      if (.not. found) r_end = r_from
      r_end = max(r_end, r_from)
      call eval_x(dsm, s, l, r_end, x_end)
      neval = neval + 1
    end if
  end subroutine slab_end

  !> The search of [r_in, r_end] (x_in exact at r_in; x_end exact at or just
  !> before r_end), nothing before r_in: pieces in ray order, each searched
  !> depth-first on cheap points, then the end point; ok = .false. where the
  !> fast path declines (as fast_ray).
  pure subroutine search_slab(dsm, s, l, x_in, r_in, x_end_in, r_end, res, ok, xcert)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r_in, r_end
    type(xpt_t), intent(in) :: x_in, x_end_in
    type(dsm_ray_t), intent(inout) :: res
    logical, intent(out) :: ok
    !> present (fast_from): r_in is not the slab's start but a point past a line-sweep
    !> certificate, xcert the exact point at the certificate (at or before x_in). A slab
    !> found clear is searched for its first point outside the grid (left_search) from the
    !> slab's true start, found then (a certificate may pass points outside the grid)
    type(xpt_t), intent(in), optional :: xcert
    type(xpt_t) :: x_end, xa, xb, pe(0:left_maxpc), pf(0:left_maxpc + 2), x0
    real(dp) :: rho, lp, rnext, hs, r0
    integer :: k, npc, outcome, nseg, code, ne, nf
    logical :: done, found
    ok = .true.
    x_end = x_end_in
    pe(0) = x_in
    ne = 0
    ! ---- 2. pieces in ray order, each searched depth-first on cheap points
    ! piece length: at least fast_piece, longer on coarse grids, where the
    ! widenings psi''L^2/8 (|psi''| ~ 3/M_min^2) and L^2/(4 rho^2) stay near 0.01 cells
    ! (only speed depends on it: make_piece computes the bounds and declines above fast_maxdv)
    rho = axis_distance(s, l, r_in, r_end)
    lp = max(fast_piece * dsm%a, min(sqrt(0.08_dp * abs(dsm%dlat) / 3.0_dp) * dsm%a * (1.0_dp - dsm%e2), &
                                     sqrt(0.04_dp * dsm%dlon) * rho))
    npc = max(1, ceiling(min((r_end - r_in) / lp, 1.0e6_dp)))
    xb = x_in
    nseg = 0
    do k = 1, npc
      xa = xb
      if (k == npc) then
        xb = x_end
      else
        rnext = r_in + (r_end - r_in) * (real(k, dp) / npc)
        call eval_x(dsm, s, l, rnext, xb, xa)
        res%nsteps = res%nsteps + 1
      end if
      if (.not. (xb%r > xa%r)) cycle
      call search_piece(dsm, s, l, xa, xb, max(r_in, xa%r), 1, res, outcome, nseg)
      if (outcome == out_decided) return
      if (outcome == out_declined) then
        ok = .false.
        return
      end if
      ne = ne + 1                                         ! (past left_maxpc pieces: no left_search)
      if (ne <= left_maxpc) pe(ne) = xb
    end do
    if (x_end%r < r_end) then                            ! the tail: its end exactly, then its search
      xa = x_end
      call eval_x(dsm, s, l, r_end, x_end, xa)
      res%nsteps = res%nsteps + 1
      call search_piece(dsm, s, l, xa, x_end, xa%r, 1, res, outcome, nseg)
      if (outcome == out_decided) return
      if (outcome == out_declined) then
        ok = .false.
        return
      end if
      ne = ne + 1
      if (ne <= left_maxpc) pe(ne) = x_end
    end if
    ! ---- the interval is clear up to r_end: the end point decides (as exact_ray)
    call dsm_height(dsm, x_end%lat, x_end%lon, hs, code)
    if (code == pt_ok .and. x_end%h <= hs + 1.0e-12_dp * dsm%a + 1.0e-9_dp * abs(hs)) then
      call set_hit(dsm, s, l, r_end, ray_hit, res)
      return
    end if
    ! ---- no hit, no no-data: the first low point outside, where the pieces' models find it
    ! (left_search), else exact_ray's search, which need not search the slab for hits again
    ! (res%slab_clear)
    ! Only where the slab starts inside the area and the ray crosses H_max there at a clear
    ! angle (a review: where it starts outside, a touch of the area shorter than refine_tol, a
    ! ray through a corner node below the surface, was a hit exact_ray finds and this search
    ! may step over; where it grazes H_max, the two searches' slab starts differ by up to mm,
    ! and a hit ~1e-9 m deep between them was lost): elsewhere exact_ray decides, as before.
    ok = .false.
    if (ne >= 1 .and. ne <= left_maxpc) then
      if (.not. present(xcert)) then
        if (.not. left_start_ok(dsm, pe(0))) return
        call left_search(dsm, s, l, pe(0:ne), r_in, res, done)
        if (done) then
          ok = .true.
          return
        end if
      else
        ! the slab's true start, then the certificate's point and the pieces searched from it
        call slab_start(dsm, s, l, x0, r0, found, res%nsteps)
        if (.not. (found .and. r0 < xcert%r)) return
        if (.not. left_start_ok(dsm, x0)) return
        pf(0) = x0
        nf = 0
        if (xcert%r < pe(0)%r) then
          nf = 1
          pf(1) = xcert
        end if
        pf(nf + 1:nf + 1 + ne) = pe(0:ne)
        call left_search(dsm, s, l, pf(0:nf + 1 + ne), r0, res, done)
        if (done) then
          ok = .true.
          return
        end if
      end if
      res%slab_clear = .true.
    end if
  end subroutine search_slab

  !> True when the exact point x at (or ~1e-9 a before) a slab's start lies inside the DSM's
  !> defined area by more than left_start_marg cells and the ray descends there at least as
  !> steeply as left_min_dh (search_slab's conditions for left_search and res%slab_clear).
  pure function left_start_ok(dsm, x) result(okay)
    type(dsm_t), intent(in) :: dsm
    type(xpt_t), intent(in) :: x
    logical :: okay
    real(dp) :: lo, m
    lo = 0.0_dp                                           ! the area's edge beyond the edge nodes
    if (dsm%interp == interp_nearest) lo = -0.5_dp
    m = left_start_marg
    okay = x%dh <= -left_min_dh .and. .not. dsm%global &
           .and. x%u > lo + m .and. x%u < dsm%ncols - 1 - lo - m &
           .and. x%v > lo + m .and. x%v < dsm%nrows - 1 - lo - m
  end function left_start_ok

  !> The first low point outside the DSM's defined area of a ray whose slab [r_in, r_end]
  !> holds no hit and no no-data point (search_slab): LEFT_DSM there, as exact_ray's step 4
  !> finds it, at most refine_tol after the first point outside (as exact_ray's).
  !> pe(0:ne) are the pieces' exact ends in ray order (pe(0) at or just before r_in, pe(ne)
  !> at r_end). On each piece's linear (u, v) models, widened by the piece's du, dv and
  !> left_marg cells, the first r where the ray may be outside (r_lo) and the first where
  !> it surely is (r_hi) are found per edge in closed form; [r_lo, r_hi] becomes a piece
  !> of its own (two conversions; its widening ~1e-14 rad of rounding), whose r_hi is
  !> classified by one conversion. done = .false. (nothing set) where that does not
  !> settle it: a global grid, a piece without models, a ray still possibly outside where
  !> it is not surely outside (along or back from an edge, grazing), a crossing not pinned
  !> to left_maxw (the conversions' rounding margin, 1e-14 rad, is ~2.6e-7 m on Earth: a
  !> ray crossing an edge at 30 deg is pinned to ~8e-7 m, at 9 deg to ~3e-6 m, then halved
  !> on the lookup's classes to refine_tol), a classification that
  !> disagrees, or no point outside (a MISS):
  !> exact_ray's step 4 then decides.
  pure subroutine left_search(dsm, s, l, pe, r_in, res, done)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), r_in
    type(xpt_t), intent(in) :: pe(0:)
    type(dsm_ray_t), intent(inout) :: res
    logical, intent(out) :: done
    type(piece_t) :: pc
    type(xpt_t) :: ya, yb, x, xm
    real(dp) :: lo(2), hi(2), r_lo, r_hi, r_lo2, r_hi2, hs, rm
    integer :: k, code, it
    logical :: pok
    done = .false.
    if (dsm%global) return
    if (dsm%interp == interp_nearest) then
      lo = [-0.5_dp - dsm%eu, -0.5_dp - dsm%ev]
      hi = [dsm%ncols - 0.5_dp + dsm%eu, dsm%nrows - 0.5_dp + dsm%ev]
    else
      lo = [-dsm%eu, -dsm%ev]
      hi = [dsm%ncols - 1.0_dp + dsm%eu, dsm%nrows - 1.0_dp + dsm%ev]
    end if
    do k = 1, size(pe) - 1
      if (.not. (pe(k)%r > pe(k - 1)%r)) return
      call make_piece(dsm, s, l, pe(k - 1), pe(k), pc, pok)
      if (.not. pok) return
      call edge_exit(pc, max(r_in, pe(k - 1)%r), lo, hi, r_lo, r_hi)
      if (r_lo > pe(k)%r) cycle                           ! surely inside all along the piece
      if (.not. (r_hi <= pe(k)%r)) return                 ! possibly out, never surely: exact_ray's
      ! [r_lo, r_hi] as a piece of its own, exact ends
      if (r_lo == pe(k - 1)%r) then
        ya = pe(k - 1)
      else
        call eval_x(dsm, s, l, r_lo, ya, pe(k - 1))
        res%nsteps = res%nsteps + 1
      end if
      if (r_hi == pe(k)%r) then
        yb = pe(k)
      else
        call eval_x(dsm, s, l, r_hi, yb, pe(k - 1))
        res%nsteps = res%nsteps + 1
      end if
      if (r_hi > r_lo) then
        call make_piece(dsm, s, l, ya, yb, pc, pok)
        if (.not. pok) return
        call edge_exit(pc, ya%r, lo, hi, r_lo2, r_hi2)
        if (.not. (r_lo2 <= yb%r .and. r_hi2 <= yb%r .and. r_hi2 - r_lo2 <= left_maxw)) return
      else
        r_lo2 = r_lo
        r_hi2 = r_hi                                      ! possibly and surely out from the same point
      end if
      ! the point at r_hi2, surely outside on the models: outside by the lookup, or exact_ray's
      if (r_hi2 == yb%r) then
        x = yb
      else
        call eval_x(dsm, s, l, r_hi2, x, ya)
        res%nsteps = res%nsteps + 1
      end if
      call dsm_height(dsm, x%lat, x%lon, hs, code)
      if (code /= pt_outside) return
      ! [r_lo2, r_hi2] holds the first point outside (the models: inside before r_lo2); wider
      ! than refine_tol where the conversions' rounding margin (1e-14 rad, ~2.6e-7 m on Earth)
      ! is large against the ray's rate across the edge (steep rays): halved on the lookup's
      ! classes (one crossing of one edge line within a few um: the classes change once, up to
      ! the lookups' own rounding, ~1e-8 m)
      do it = 1, 60
        if (r_hi2 - r_lo2 <= refine_tol) exit
        rm = 0.5_dp * (r_lo2 + r_hi2)
        call eval_x(dsm, s, l, rm, xm, ya)
        res%nsteps = res%nsteps + 1
        call dsm_height(dsm, xm%lat, xm%lon, hs, code)
        if (code == pt_outside) then
          r_hi2 = rm
        else
          r_lo2 = rm
        end if
      end do
      if (.not. (r_hi2 - r_lo2 <= refine_tol)) return
      call set_event(dsm, s, l, r_hi2, ray_left_dsm, res)
      done = .true.
      return
    end do
  end subroutine left_search

  !> On piece pc's linear models of u and v (widened by du, dv and left_marg cells), from r0:
  !> r_lo, the first r where the ray may be outside the area lo(1) <= u <= hi(1),
  !> lo(2) <= v <= hi(2), and r_hi, the first r where it surely is (+huge: none before the
  !> piece's end; each as the earliest over the four edges, in closed form).
  pure subroutine edge_exit(pc, r0, lo, hi, r_lo, r_hi)
    type(piece_t), intent(in) :: pc
    real(dp), intent(in) :: r0, lo(2), hi(2)
    real(dp), intent(out) :: r_lo, r_hi
    real(dp) :: c0, g, w, len
    integer :: ax, side
    r_lo = huge(1.0_dp)
    r_hi = huge(1.0_dp)
    len = pc%b%r - pc%a%r
    if (.not. (len > 0.0_dp)) then
      r_lo = r0
      return
    end if
    do ax = 1, 2
      if (ax == 1) then
        c0 = pc%a%u + (r0 - pc%a%r) * pc%ilen * (pc%b%u - pc%a%u)     ! the model at r0
        g = (pc%b%u - pc%a%u) * pc%ilen                                 ! and its rate per unit r
        w = pc%du + left_marg
      else
        c0 = pc%a%v + (r0 - pc%a%r) * pc%ilen * (pc%b%v - pc%a%v)
        g = (pc%b%v - pc%a%v) * pc%ilen
        w = pc%dv + left_marg
      end if
      do side = 1, 2
        ! outward distance of the model from the edge, d(r) = d0 + gd (r - r0): may be out where
        ! d >= -w, surely out where d > w
        if (side == 1) then
          call edge_first(lo(ax) - c0, -g, w, r0, r_lo, r_hi)
        else
          call edge_first(c0 - hi(ax), g, w, r0, r_lo, r_hi)
        end if
      end do
    end do
  end subroutine edge_exit

  !> One edge of edge_exit: the model's outward distance from it d(r) = d0 + gd (r - r0)
  !> (cells); r_lo and r_hi lowered to where d >= -w (may be out) and just past d > w (surely
  !> out), when that comes after r0 (d0 already there: r0).
  pure subroutine edge_first(d0, gd, w, r0, r_lo, r_hi)
    real(dp), intent(in) :: d0, gd, w, r0
    real(dp), intent(inout) :: r_lo, r_hi
    real(dp) :: r
    if (d0 >= -w) then
      r_lo = min(r_lo, r0)
    else if (gd > 0.0_dp) then
      r = r0 + (-w - d0) / gd
      if (r < huge(1.0_dp)) r_lo = min(r_lo, r)
    end if
    if (d0 > w) then
      r_hi = min(r_hi, r0)
    else if (gd > 0.0_dp) then
      ! just past d = w (the nudge: the rounding of r on the ray's scale)
      r = r0 + (w - d0) / gd
      r = r + 1.0e-15_dp * (abs(r) + 1.0_dp) + 1.0e-3_dp * refine_tol
      if (r < huge(1.0_dp)) r_hi = min(r_hi, r)
    end if
  end subroutine edge_first

  !> Depth-first search of the piece [xa, xb] (exact ends) for the first hit or
  !> no-data point, in ray order, on cheap points. At level 1 a segment that
  !> cannot be ruled out and is at most fast_sub long is searched as a piece of
  !> its own (level 2: exact ends, so its tangent bound is within
  !> fast_sub^2 / (8 M_min) of h). outcome: out_clear (nothing on the piece),
  !> out_decided (res holds the hit or no-data event), out_declined. one = .true.:
  !> xb is tangent_end's model end (make_piece's one-ended piece).
  recursive pure subroutine search_piece(dsm, s, l, xa, xb, rs, level, res, outcome, nseg, one)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3)
    !> where the search starts (xa%r <= rs < xb%r: [xa%r, rs) is not searched)
    real(dp), intent(in) :: rs
    type(xpt_t), intent(in) :: xa, xb
    integer, intent(in) :: level
    type(dsm_ray_t), intent(inout) :: res
    integer, intent(out) :: outcome
    integer, intent(inout) :: nseg
    logical, intent(in), optional :: one
    type(piece_t) :: pc
    type(xpt_t) :: xc, xd
    type(lpt_t) :: pa, pb, pm, stack(fast_depth)
    real(dp) :: dh, hs, hlow, hb, r, g, dr, hc, rsplit, rm, rstar, rc, cn, eps, wm, rw, ew, hn
    logical :: found, pok, near
    integer :: code, nst, it, cell, sub, cst, wi, wj
    outcome = out_declined
    call make_piece(dsm, s, l, xa, xb, pc, pok, one)
    if (.not. pok) return
    pa = to_l(xa)
    if (rs > xa%r) call eval_l(pc, rs, pa)
    pb = to_l(xb)
    nst = 0
    do
      nseg = nseg + 1
      if (nseg > fast_maxseg .or. res%nsteps > fast_maxconv) then
        outcome = out_declined
        return
      end if
      call seg_bounds(dsm, pc, pa, pb, hlow, hb, cell, rsplit, wm, wi, wj)
      if (hlow > hb) then                                 ! nothing to meet in this segment
        call next_segment(pa, pb, stack, nst)
        if (nst < 0) exit
        cycle
      end if
      if (hb < huge(1.0_dp)) then
        ! the prefix where a falling tangent is still above the box's surface bound is clear:
        ! move the start there (a cheap step toward the first candidate, DDA-like)
        rc = clear_prefix(pc, pa%r, hb)
        if (rc >= pb%r) then
          call next_segment(pa, pb, stack, nst)
          if (nst < 0) exit
          cycle
        end if
        if (rc - pa%r > 0.01_dp * (pb%r - pa%r)) then
          call eval_l(pc, rc, pa)
          if (cell < 0) cycle
        end if
      end if
      if (wj >= 0) then
        ! one meridian wall between two cells of a row: its crossing rw in closed form, to +-ew
        ! (wall_cross). Before rw - ew the ray is in the near cell, which it clears when h_lower
        ! there is above that cell's height; the point rw + ew (at most 2 ew <= refine_tol / 2
        ! after the true crossing) is then classified exactly, one conversion, where the halving
        ! search took ~3 (the widened boxes straddle the boundary all along its band)
        call wall_cross(dsm, s, l, pa, pb, wi, wj, rw, ew, hn)
        if (ew <= 0.25_dp * refine_tol) then
          if (h_lower(pc, pa%r, rw - ew) > hn) then
            r = rw + ew
            call classify(dsm, s, l, pc, r, res, outcome)
            if (outcome == out_decided) return
            call eval_l(pc, r, pa)                        ! [pa, r] is clear (to stays below 2 ew)
            cycle
          end if
        end if
      end if
      if (level == 2 .and. cell < 0) then                 ! one bilinear cell: the candidate in closed form
        call cell_solve(dsm, pc, pa, pb, cst, rstar)
        if (cst == 1) then
          call next_segment(pa, pb, stack, nst)
          if (nst < 0) exit
          cycle
        else if (cst == 2) then
          ! no entry before rstar: classify rstar + tol/2 (a leaf of length tol/2)
          r = min(rstar + 0.5_dp * refine_tol, pb%r)
          call classify(dsm, s, l, pc, r, res, outcome)
          if (outcome == out_decided) return
          if (r >= pb%r) then
            call next_segment(pa, pb, stack, nst)
            if (nst < 0) exit
          else
            call eval_l(pc, r, pa)                        ! [pa, r] is clear; go on from r
          end if
          cycle
        end if
      end if
      if (cell >= 0) then                                 ! one nearest cell: Newton on h - H_cell
        hc = hb
        cn = huge(1.0_dp)
        if (dsm%a * (1.0_dp - dsm%e2) + min(hc, 0.0_dp) > 0.0_dp) cn = 1.0_dp / (dsm%a * (1.0_dp - dsm%e2) + min(hc, 0.0_dp))
        r = pa%r
        call eval_p(dsm, s, l, pc, r, xc, res%nsteps)
        g = xc%h - hc
        dh = xc%dh
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
          ! h'' <= cn: the root is within cn dr^2 / |dh| after r (as fast_crossing); when that is
          ! below 1e-9 and inside the segment, r is the answer (no confirming step)
          eps = cn * dr * dr / (-dh)
          if (eps <= 1.0e-9_dp .and. eps <= 0.4_dp * dr .and. r + eps <= pb%r) then
            found = .true.
            exit
          end if
          xd = xc
          call eval_x(dsm, s, l, r, xc, xd)
          res%nsteps = res%nsteps + 1
          g = xc%h - hc
          dh = xc%dh
        end do
        if (found) then
          if (xc%r /= r) then                             ! the last step was below 1e-9
            call extrapolate(dsm, l, xc, r, xd, near)     ! (at most ~6 cm: no conversion)
            if (near) then
              xc = xd
            else
              xd = xc
              call eval_x(dsm, s, l, r, xc, xd)           ! convert there
              res%nsteps = res%nsteps + 1
            end if
          end if
          call dsm_height(dsm, xc%lat, xc%lon, hs, code)  ! the contract's H there (walls: the larger)
          call fast_hit(s, l, xc, hs, res)
          outcome = out_decided
          return
        end if
        if (it <= 100) then
          call next_segment(pa, pb, stack, nst)
          if (nst < 0) exit
          cycle
        end if
      end if
      if (pb%r - pa%r <= refine_tol) then                 ! a short segment: classify its end exactly
        ! a leaf counts as fast_leaf segments: a ray along a wall or the grid's edge within the boxes'
        ! margins visits leaf after leaf (~10,000 conversions before the decline); exact_ray's chord
        ! rule settles such rays
        nseg = nseg + fast_leaf - 1
        call classify(dsm, s, l, pc, pb%r, res, outcome)
        if (outcome == out_decided) return
        call next_segment(pa, pb, stack, nst)
        if (nst < 0) exit
        cycle
      end if
      if (level == 1 .and. pb%r - pa%r <= fast_sub * dsm%a) then   ! a short candidate: its own piece
        call eval_p(dsm, s, l, pc, pa%r, xc, res%nsteps)
        call eval_p(dsm, s, l, pc, pb%r, xd, res%nsteps)
        call search_piece(dsm, s, l, xc, xd, xc%r, 2, res, sub, nseg)
        if (sub /= out_clear) then
          outcome = sub
          return
        end if
        call next_segment(pa, pb, stack, nst)
        if (nst < 0) exit
        cycle
      end if
      if (nst >= fast_depth) then
        outcome = out_declined
        return
      end if
      rm = pa%r + fast_split * (pb%r - pa%r)
      if (rsplit > 0.0_dp) then                         ! around the wall's band: one cell on each side
        if (rsplit - wm > pa%r + 0.125_dp * refine_tol) then
          rm = rsplit - wm
        else if (rsplit + wm < pb%r - 0.125_dp * refine_tol) then
          rm = rsplit + wm
        end if
      end if
      call eval_l(pc, rm, pm)
      nst = nst + 1
      stack(nst) = pb
      pb = pm
    end do
    outcome = out_clear
  end subroutine search_piece

  !> Classify the exact point at rq of piece pc's ray (one conversion, counted in
  !> res%nsteps): a no-data point or a hit there decides the ray (outcome =
  !> out_decided, res set); otherwise outcome is left as it was.
  pure subroutine classify(dsm, s, l, pc, rq, res, outcome)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3), rq
    type(piece_t), intent(in) :: pc
    type(dsm_ray_t), intent(inout) :: res
    integer, intent(inout) :: outcome
    type(xpt_t) :: x
    real(dp) :: hs
    integer :: code
    call eval_p(dsm, s, l, pc, rq, x, res%nsteps)
    call dsm_height(dsm, x%lat, x%lon, hs, code)
    if (code == pt_nodata) then
      call set_event(dsm, s, l, rq, ray_no_data, res)
      outcome = out_decided
    else if (code == pt_ok .and. x%h <= hs) then
      call fast_hit(s, l, x, hs, res)
      outcome = out_decided
    end if
  end subroutine classify

  !> Where the ray crosses the meridian between columns wj and wj + 1 (the
  !> boundary u = wj + 1/2 of a "nearest" grid) inside the segment (pa, pb):
  !> the plane through the polar axis at longitude lb = lon0 + (wj + 1/2) dlon,
  !> normal n = (-sin lb, cos lb, 0), meets the line at rw = -(s.n) / (l.n)
  !> (exact up to rounding; a line crosses such a half-plane once). ew bounds
  !> the along-ray error of rw and of the boundary as the grid lookup sees it
  !> (rounding of s.n and of the longitudes, 3e-15 (|s| + rw), over |l.n|);
  !> hn is the height of the cell on pa's side, in row wi. ew = +huge: no
  !> crossing inside (pa, pb) by more than ew, the crossing on the other
  !> half of the plane, or the near cell without data. Only speed depends on
  !> when it declines (search_piece then halves as before).
  pure subroutine wall_cross(dsm, s, l, pa, pb, wi, wj, rw, ew, hn)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: s(3), l(3)
    type(lpt_t), intent(in) :: pa, pb
    integer, intent(in) :: wi, wj
    real(dp), intent(out) :: rw, ew, hn
    real(dp) :: lb, cb, sb, sn, ln, xa
    integer :: jn
    ew = huge(1.0_dp)
    rw = 0.0_dp
    hn = huge(1.0_dp)
    lb = dsm%lon0 + (wj + 0.5_dp) * dsm%dlon
    cb = cos(lb)
    sb = sin(lb)
    sn = -s(1) * sb + s(2) * cb
    ln = -l(1) * sb + l(2) * cb
    if (.not. (abs(ln) > 1.0e-3_dp)) return
    rw = -sn / ln
    if (.not. ((s(1) + rw * l(1)) * cb + (s(2) + rw * l(2)) * sb > 0.0_dp)) return   ! the other half-plane
    xa = 3.0e-15_dp * (sqrt(s(1)**2 + s(2)**2 + s(3)**2) + abs(rw)) / abs(ln)
    if (.not. (rw - xa > pa%r .and. rw + xa < pb%r)) return
    ! (s + r l).n = rho sin(lon - lb) has the sign of r - rw when ln > 0: before rw the ray is west of
    ! the meridian (column wj, dlon > 0), after it east (wj + 1); the other way round when ln < 0
    jn = merge(wj, wj + 1, ln > 0.0_dp)
    hn = dsm%hgt(jn + 1, wi + 1)
    if (.not. (abs(hn) <= huge(1.0_dp))) then              ! no data: the halving search decides
      hn = huge(1.0_dp)
      return
    end if
    ew = xa
  end subroutine wall_cross

  !> Fill res as a hit at the exact point x, where the surface height hs was
  !> found (as pi_follow's set_hit, without converting and looking up again).
  pure subroutine fast_hit(s, l, x, hs, res)
    real(dp), intent(in) :: s(3), l(3), hs
    type(xpt_t), intent(in) :: x
    type(dsm_ray_t), intent(inout) :: res
    res%status = ray_hit
    res%r = x%r
    res%p = s + x%r * l
    res%lat = x%lat
    res%lon = x%lon
    res%h = x%h
    res%hs = hs
    res%incidence = acos(max(-1.0_dp, min(1.0_dp, -x%dh)))   ! from the normal: 0 = looking straight down
  end subroutine fast_hit

  !> Move on to the next pending segment [pb, top of the stack]; nst = -1 when none is left.
  pure subroutine next_segment(pa, pb, stack, nst)
    type(lpt_t), intent(inout) :: pa, pb
    type(lpt_t), intent(in) :: stack(:)
    integer, intent(inout) :: nst
    pa = pb
    if (nst == 0) then
      nst = -1
      return
    end if
    pb = stack(nst)
    nst = nst - 1
  end subroutine next_segment

end module pi_dsm_fast
