!> Line sweep of the exact DSM mode: certified clear prefixes for a fan of
!> rays that share one focal point (an image line of a pushbroom, a row or
!> column of a frame camera), found for the whole fan at once instead of ray
!> by ray (docs/shin-park-notes.md, "Line sweep"; docs/simulation-notes.md
!> note 11).
!>
!> The output rclear(k) is a distance along ray k before which the ray meets
!> no column of the DSM: no hit and no no-data point, for every point of the
!> ray with h >= H_min (0: no certificate). It may pass low points outside the
!> grid: pi_dsm_fast's fast_from decides only hits and no-data points, and
!> declines otherwise (exact_ray then searches the whole slab again and finds
!> the LEFT_DSM point; docs/shin-park-notes.md, "Tenth look"). fast_from
!> checks H_min < h <= H_max and h' < 0 at rclear(k), which covers the ray's
!> lower points by the convexity of h along a line, and searches on from
!> there. Only speed depends on how long the prefixes are.
!>
!> Why it holds, for the rays of a chunk of the fan (at most sweep_chunk_max
!> consecutive rays) on one side of the nadir direction:
!>  * Frame: n the unit normal of the plane P of the chunk's first and last
!>    rays (through s), nu the nadir direction -s/|s| projected on P,
!>    t = n x nu. A point Q has depth x(Q) = (Q - s).nu and slope numerator
!>    y(Q) = sg (Q - s).t, sg = +-1 the side; ray k's slope is
!>    tau_k = y(l_k) / x(l_k) > 0. Each certified ray's points between the
!>    raised and the lowered ellipsoid (below) lie within w_s of P.
!>  * Separation: the plane through s spanned by l_k and n contains ray k; a
!>    point Q with x(Q) > 0 lies strictly on its nadir side iff
!>    y(Q) - tau_k x(Q) < 0. A unit's column (its footprint times
!>    [H_min, top]) lies in the hull of its 8 corners widened by delta (the
!>    bulge of its curved faces, rounding); only its part within w_s of P can
!>    meet a ray, and that part lies between two heights found from the four
!>    vertical edges (straight normal lines, along which the distance to P is
!>    affine). If every corner of that shorter column has
!>    (y + delta K) / x < tau_k, K >= sqrt(1 + tau_k^2), the column cannot
!>    meet ray k.
!>  * Order: progress is q(Q) = (Q - s).p for a unit vector p in P along which
!>    every certified ray advances (l_k.p >= sweep_tau_min): the plane's
!>    horizontal direction when the plane is near vertical (a cross-track
!>    line; columns are then thin along it), else the bisector of the extreme
!>    rays (the column parts near a tilted plane are short). Ray k can only
!>    meet a column at a progress within the column's range, which starts at
!>    q_min (less delta). With Q*_k the smallest q_min of a column not
!>    separated from ray k (a counting sort of the units by q_min and a running
!>    maximum of their slopes), ray k meets no column for r < Q*_k / (l_k.p).
!>  * Containment: every point of a certified ray with H_min <= h <= H_max
!>    lies between its entries into the raised ellipsoid (semi-axes + H_max +
!>    e2 |H_max| + 1e-9 a: contains h <= H_max) and the lowered one (+ H_min -
!>    e2 |H_min| - 1e-9 a: inside h <= H_min), so over the corridor: the
!>    footprint quadrilateral of the two extreme rays (smallest and largest
!>    tau) between the two ellipsoids, in grid (u, v), widened by 2 w_s and by
!>    four times the curvature of its edges (Meusnier's 1 / cos(tilt)
!>    included). Units of the corridor with no data are columns up to H_max
!>    (an event happens there only below H_max); units outside the grid are
!>    none (no hit or no-data point lies there), unless the grid spans so
!>    nearly a turn of longitude that the corridor could reach its wrapped
!>    copy (then columns up to H_max, as no-data).
!> A chunk side gets no certificates (rclear = 0) where an assumption fails: a
!> global grid, parallel rays, a fan plane nearly perpendicular to the nadir or
!> tilted more than ~84 degrees, rays that start inside the raised ellipsoid or
!> never reach the lowered one, a corridor within 10 degrees of a pole or with
!> more than sweep_units_per_ray units per ray (a tilted plane's corridor is as
!> wide as the slab's footprint); single rays get none where they advance by
!> less than sweep_tau_min along p or lie on the other side of the nadir.
module pi_dsm_sweep
  use pi_kinds, only: dp
  use pi_vector, only: cross
  use pi_dsm, only: dsm_t, dsm_grid_uv, interp_nearest
  use pi_follow, only: ellipsoid_entry
  use pi_geodetic, only: ecr_to_geodetic_nb
  !$ use omp_lib, only: omp_get_max_threads
  implicit none
  private

  public :: sweep_fan, sweep_fans, sweep_chunk_max, sweep_runs

  !> rays per chunk: each chunk has its own plane and corridor (short chunks
  !> keep the corridor's curvature margin and its off-plane widening small;
  !> long ones share the frame, four corner conversions and the corridor's set-up
  !> among more rays). 512 since 2026-12-04 (was 128): 1.06-1.09x the simulation
  !> benchmark's rays, 1.03-1.20x the geodetic benchmark's scans, the certified
  !> prefixes within 2 cm of 128's (mean gap to the hit 2.93 m against 2.91 m);
  !> a 512-pixel chunk of a row of 1 m pixels departs from its chord by ~6 mm
  !> (docs/simulation-notes.md note 15)
  integer, parameter :: sweep_chunk_max = 512
  !> smallest slope tau (tangent of the angle from the nadir direction in the
  !> fan's plane, ~0.06 deg) of a certified ray
  real(dp), parameter :: sweep_tau_min = 1.0e-3_dp
  !> largest |latitude| of a corridor (80 degrees, radians)
  real(dp), parameter :: sweep_lat_max = 1.3962634015954636_dp
  !> most corridor units per ray of a chunk (more: no certificates). A unit costs ~30-50 ns, a ray's
  !> search from its certificate saves ~0.5 us (simulation benchmark), so beyond ~16 the sweep
  !> would not pay; a fan plane tilted from the vertical has a corridor as wide as the slab's
  !> footprint, (H_max - H_min) tan(tilt), and gets none.
  integer, parameter :: sweep_units_per_ray = 16
  !> sweep_fans' fan argument for groups found from the focal points (runs)
  integer, parameter :: sweep_runs = -1
  !> most rays of one group in runs mode (a frame camera's single focal point:
  !> the threads share its work; a multiple of sweep_chunk_max, so that only
  !> a run's last group can end in a short chunk)
  integer, parameter :: sweep_group_max = 8 * sweep_chunk_max

contains

  !> Certified clear distances rclear(n) of n rays in consecutive groups of fan
  !> (the last may be shorter): each group whose rays share one focal point
  !> (s equal bit for bit) is one fan (sweep_fan); other groups, and all rays
  !> when fan is 0 or 1, get 0. fan = sweep_runs (-1): the groups are the
  !> maximal runs of consecutive rays with one focal point (pi.intersect: a
  !> pushbroom's lines or a frame camera's rows given as (n, 3) arrays), cut
  !> into groups of at most sweep_group_max rays; runs of one ray get 0.
  !> OpenMP over the groups (threads <= 0: all); each group's answer is its
  !> own, so the results do not depend on the count.
  subroutine sweep_fans(dsm, n, s, l, fan, threads, rclear)
    type(dsm_t), intent(in) :: dsm
    integer, intent(in) :: n, fan, threads
    real(dp), intent(in) :: s(3, n), l(3, n)
    real(dp), intent(out) :: rclear(n)
    integer :: g, k0, k1, nt, ng, k
    integer, allocatable :: gstart(:)
    rclear = 0.0_dp
    if (n < 2 .or. (fan < 2 .and. fan /= sweep_runs)) return
    if (fan == sweep_runs) then
      ! group starts: a new group where the focal point changes or the group is full
      allocate(gstart(n + 1))
      ng = 1
      gstart(1) = 1
      do k = 2, n
        if (s(1, k) /= s(1, k - 1) .or. s(2, k) /= s(2, k - 1) .or. s(3, k) /= s(3, k - 1) .or. &
            k - gstart(ng) >= sweep_group_max) then
          ng = ng + 1
          gstart(ng) = k
        end if
      end do
      gstart(ng + 1) = n + 1
    else
      ng = (n + fan - 1) / fan
      allocate(gstart(ng + 1))
      do g = 1, ng
        gstart(g) = (g - 1) * fan + 1
      end do
      gstart(ng + 1) = n + 1
    end if
    nt = 1
    !$ nt = omp_get_max_threads()
    if (threads > 0) nt = threads
    !$omp parallel do schedule(dynamic, 1) num_threads(nt) default(shared) private(g, k0, k1)
    do g = 1, ng
      k0 = gstart(g)
      k1 = gstart(g + 1) - 1
      if (k1 > k0 .and. all(s(1, k0:k1) == s(1, k0) .and. s(2, k0:k1) == s(2, k0) .and. s(3, k0:k1) == s(3, k0))) &
        call sweep_fan(dsm, s(:, k0), l(:, k0:k1), k1 - k0 + 1, rclear(k0:k1))
    end do
    !$omp end parallel do
  end subroutine sweep_fans

  !> Certified clear distances rclear(1:m) for m rays from the focal point s
  !> (ECR, units of a) with directions l(3, m) (any non-zero length), all on
  !> dsm; 0 where none (see the module header).
  pure subroutine sweep_fan(dsm, s, l, m, rclear)
    type(dsm_t), intent(in) :: dsm
    integer, intent(in) :: m
    real(dp), intent(in) :: s(3), l(3, m)
    real(dp), intent(out) :: rclear(m)
    integer :: k0, k1
    rclear = 0.0_dp
    if (m < 2 .or. dsm%global .or. dsm%nrows < 2 .or. dsm%ncols < 2) return
    if (.not. all(abs(s) < huge(1.0_dp))) return
    if (.not. (dsm%hmax >= dsm%hmin .and. abs(dsm%hmax) < huge(1.0_dp) .and. abs(dsm%hmin) < huge(1.0_dp))) return
    k0 = 1
    do while (k0 <= m)
      k1 = min(m, k0 + sweep_chunk_max - 1)
      if (m - k1 < sweep_chunk_max / 4) k1 = m          ! no short last chunk
      if (k1 > k0) call sweep_chunk(dsm, s, l(:, k0:k1), k1 - k0 + 1, rclear(k0:k1))
      k0 = k1 + 1
    end do
  end subroutine sweep_fan

  !> The certificates of one chunk of rays (module header): its frame, then
  !> each side of the nadir direction on its own.
  pure subroutine sweep_chunk(dsm, s, l, m, rc)
    type(dsm_t), intent(in) :: dsm
    integer, intent(in) :: m
    real(dp), intent(in) :: s(3), l(3, m)
    real(dp), intent(inout) :: rc(m)
    real(dp) :: lu(3, m), xk(m), yk(m), n(3), nu(3), t(3), c(3), cn, ln
    logical :: ok(m)
    integer :: k, isg
    do k = 1, m
      ln = norm2(l(:, k))
      ok(k) = ln > 0.0_dp .and. ln < huge(1.0_dp)
      lu(:, k) = 0.0_dp
      if (ok(k)) lu(:, k) = l(:, k) / ln
    end do
    if (.not. (ok(1) .and. ok(m))) return
    c = cross(lu(:, 1), lu(:, m))
    cn = norm2(c)
    if (.not. (cn > 1.0e-14_dp)) return
    n = c / cn
    nu = -s / norm2(s)
    nu = nu - dot_product(nu, n) * n
    if (.not. (norm2(nu) > 1.0e-3_dp)) return
    nu = nu / norm2(nu)
    t = cross(n, nu)
    do k = 1, m
      xk(k) = dot_product(lu(:, k), nu)
      yk(k) = dot_product(lu(:, k), t)
    end do
    do isg = 1, 2
      call sweep_side(dsm, s, lu, m, n, nu, t, merge(1.0_dp, -1.0_dp, isg == 1), &
                      ok .and. xk > 0.0_dp .and. merge(yk, -yk, isg == 1) > 0.0_dp, rc)
    end do
  end subroutine sweep_chunk

  !> The certificates of the rays `cand` of a chunk that lie on one side (sg) of
  !> the nadir direction in the chunk's frame (n, nu, t): module header.
  pure subroutine sweep_side(dsm, s, lu, m, n, nu, t, sg, cand, rc)
    type(dsm_t), intent(in) :: dsm
    integer, intent(in) :: m
    real(dp), intent(in) :: s(3), lu(3, m), n(3), nu(3), t(3), sg
    logical, intent(in) :: cand(m)
    real(dp), intent(inout) :: rc(m)
    real(dp) :: tk(m), rtop(m), rbot(m), pk(m)
    logical :: elig(m)
    real(dp) :: dhi, dlo, w_off, w_s, rmin, pc(3, 4), uc(4), vc(4), up(3), upp(3), g(3), d(3), p(3)
    real(dp) :: latc, lonc, hcor, nxc, nyc, nzc, lmax, latm, w, du, dv, o, ua, ub, dm, delta, kk, tmax, xfloor
    real(dp) :: v0, v1, qlo, qhi, width, q, qs, r, tr, ctilt, sint, vext, cost_g, cost_d, adv, sig, se
    real(dp), allocatable :: slat(:), clat(:), nrad(:), clon(:), slon(:), qmin(:), tcol(:), bmax(:), run(:)
    real(dp), allocatable :: nv(:, :, :), nw(:, :, :)
    integer, allocatable :: rja(:), rjb(:), bidx(:), bstart(:), order(:)
    integer :: k, klo, khi, i, j, i0, i1, jlo, jhi, nunit, cap, b, nb, lo, hi, mid, kc
    logical :: hit, anyu, skip_out
    elig = cand
    if (.not. any(elig)) return
    o = 0.0_dp
    if (dsm%interp == interp_nearest) o = 0.5_dp           ! unit i covers v in [i - o, i + 1 - o]
    tk = 0.0_dp
    do k = 1, m
      if (elig(k)) tk(k) = sg * dot_product(lu(:, k), t) / dot_product(lu(:, k), nu)
    end do
    ! ---- each ray's stretch between the raised ellipsoid (contains h <= H_max) and the lowered one
    ! (inside h <= H_min): the parallel surface h = H is within e2 |H| of the ellipsoid (a + H, b + H)
    dhi = 1.0e-9_dp * dsm%a + dsm%e2 * abs(dsm%hmax)
    dlo = 1.0e-9_dp * dsm%a + dsm%e2 * abs(dsm%hmin)
    if (.not. (dsm%b + dsm%hmin - dlo > 0.5_dp * dsm%b)) return
    do k = 1, m
      if (.not. elig(k)) cycle
      call ellipsoid_entry(dsm%a + dsm%hmax + dhi, dsm%b + dsm%hmax + dhi, s, lu(:, k), rtop(k), hit)
      elig(k) = hit .and. rtop(k) > 0.0_dp
      if (.not. elig(k)) cycle
      call ellipsoid_entry(dsm%a + dsm%hmin - dlo, dsm%b + dsm%hmin - dlo, s, lu(:, k), rbot(k), hit)
      elig(k) = hit .and. rbot(k) > rtop(k)
    end do
    if (.not. any(elig)) return
    klo = minloc(tk, 1, mask=elig)
    khi = maxloc(tk, 1, mask=elig)
    w_s = 0.0_dp
    tmax = 0.0_dp
    do k = 1, m
      if (.not. elig(k)) cycle
      w_s = max(w_s, rbot(k) * abs(dot_product(lu(:, k), n)))    ! farthest a ray's stretch gets from the plane
      tmax = max(tmax, tk(k))
    end do
    ! ---- the corridor: the extreme rays' footprints at both ellipsoids, in grid (u, v)
    pc(:, 1) = s + rtop(klo) * lu(:, klo)
    pc(:, 2) = s + rbot(klo) * lu(:, klo)
    pc(:, 3) = s + rbot(khi) * lu(:, khi)
    pc(:, 4) = s + rtop(khi) * lu(:, khi)
    latm = 0.0_dp
    up = 0.0_dp
    do k = 1, 4
      call ecr_to_geodetic_nb(pc(1, k), pc(2, k), pc(3, k), dsm%a, dsm%f, latc, lonc, hcor, nxc, nyc, nzc)
      up = up + [nxc, nyc, nzc]
      if (k == 1 .or. k == 4) then
        if (.not. (hcor >= dsm%hmax)) return                 ! the raised ellipsoid is above H_max
      else
        if (.not. (hcor <= dsm%hmin)) return                 ! the lowered one below H_min
      end if
      call dsm_grid_uv(dsm, latc, lonc, uc(k), vc(k))
      latm = max(latm, abs(latc))
    end do
    up = up / norm2(up)
    lmax = 0.0_dp
    do k = 1, 3
      do j = k + 1, 4
        lmax = max(lmax, norm2(pc(:, k) - pc(:, j)))
      end do
    end do
    rmin = dsm%a * (1.0_dp - dsm%e2) + min(dsm%hmin, 0.0_dp) - dlo   ! smallest radius of curvature there
    ! the plane's tilt from the vertical (Meusnier: its sections curve by 1/cos(tilt) more; the
    ! mean normal of the corners is within lmax / rmin of the normal anywhere in the corridor)
    sint = abs(dot_product(n, up))
    ctilt = sqrt(max(0.0_dp, 1.0_dp - sint**2)) - lmax / rmin - 1.0e-6_dp
    if (.not. (ctilt > 0.1_dp)) return
    ! off the plane: a certified ray's point T on the raised (lowered) ellipsoid is within w_s of P;
    ! its projection T' on P lies on the line of P through s with the ray's slope tau, at a height
    ! within w_s sig of the surface (sig >= |N.n|, N the surface normal anywhere in the corridor),
    ! so within w_s sig / se of the point T* where that line meets the surface (se <= the sine of
    ! the ray's angle with the surface). T* lies on P's section of the surface between the extreme
    ! rays' points, each within the same w_s (1 + sig / se) of the corners pc, which are actual ray
    ! points: T's footprint is within 2 w_s (1 + sig / se) of the corners' hull (and its
    ! curvature). Found by a review: with 2 w_s, a ray 1 m off a plane tilted 75 deg was certified
    ! 38.6 m past its hit.
    sig = sint + lmax / rmin + 1.0e-6_dp
    se = huge(1.0_dp)
    do k = 1, m
      if (elig(k)) se = min(se, abs(dot_product(lu(:, k), up)))
    end do
    se = se - lmax / rmin - 1.0e-6_dp
    if (.not. (se > 0.05_dp)) return
    w_off = 2.0_dp * w_s * (1.0_dp + sig / se)
    latm = latm + (lmax + w_off) / rmin + 1.0e-6_dp
    if (.not. (latm < sweep_lat_max)) return
    ! widening: off the plane, the edges' curvature in (u, v) (4x the sphere's L^2 (1 + tan(lat)) / (8 R)), rounding
    w = w_off + lmax * lmax / (2.0_dp * rmin * ctilt) * (1.0_dp + tan(latm)) + 1.0e-9_dp * dsm%a &
        + 1.0e-12_dp * norm2(s)
    du = w / ((dsm%a + min(dsm%hmin, 0.0_dp) - dlo) * cos(latm) * dsm%dlon)
    ! units outside the grid stop no ray (unit_bounds) when none of them can be a column of the grid
    ! wrapped by a turn: the corners' u lie within a turn from uw, the meridian opposite the grid's
    ! centre, which is -uw cells from both of the grid's edges, so the corridor's units reach a
    ! wrapped copy of the grid only if du + 1.5 >= -uw (a grid spanning nearly 360 degrees)
    skip_out = -dsm%uw > du + 2.0_dp
    dv = w / (rmin * abs(dsm%dlat))
    if (.not. (du < 1.0e6_dp .and. dv < 1.0e6_dp)) return
    ! ---- progress: along the plane's horizontal direction g, or along the rays' bisector d, whichever
    ! should give the shorter progress range per column for the rays' slowest advance. A column's part
    ! within w_s of the plane (the only part a ray can meet) is about dm wide horizontally and vext tall:
    ! its full height in a vertical plane, about (dm + 2 w_s) / tan(tilt) in a tilted one.
    dm = (dsm%a / (1.0_dp - dsm%e2) + max(dsm%hmax, 0.0_dp)) * sqrt(dsm%dlat**2 + dsm%dlon**2)
    vext = min(dsm%hmax - dsm%hmin, (dm + 2.0_dp * w_s) * sqrt(max(0.0_dp, 1.0_dp - sint**2)) / max(sint, 1.0e-9_dp))
    upp = up - dot_product(up, n) * n                      ! the vertical within the plane
    g = cross(n, up)
    cost_g = huge(1.0_dp)
    cost_d = huge(1.0_dp)
    if (norm2(g) > 1.0e-3_dp) then
      g = g / norm2(g)
      if (dot_product(lu(:, khi), g) < 0.0_dp) g = -g
      adv = minval(matmul(g, lu), mask=elig)
      if (adv >= sweep_tau_min) cost_g = dm / adv
    end if
    d = lu(:, klo) + lu(:, khi)
    d = d - dot_product(d, n) * n
    if (norm2(d) > 0.0_dp .and. norm2(upp) > 0.0_dp) then
      d = d / norm2(d)
      adv = minval(matmul(d, lu), mask=elig)
      if (adv >= sweep_tau_min) cost_d = (dm + vext * abs(dot_product(d, upp / norm2(upp)))) / adv
    end if
    if (.not. (min(cost_g, cost_d) < huge(1.0_dp))) return
    if (cost_g <= cost_d) then
      p = g
    else
      p = d
    end if
    do k = 1, m
      pk(k) = dot_product(lu(:, k), p)
      if (elig(k)) elig(k) = pk(k) >= sweep_tau_min
    end do
    ! ---- the corridor's units, row by row (two passes: count, then fill)
    v0 = minval(vc) - dv
    v1 = maxval(vc) + dv
    ! (grid coordinates far off the grid, tiny cells far away, would overflow the integer row and
    ! column indices below: no certificates; found by a review, 4.3e9 rows looped over)
    if (.not. (v1 - v0 < 1.0e7_dp .and. abs(v0) < 1.0e9_dp .and. abs(v1) < 1.0e9_dp)) return
    if (.not. all(abs(uc) + du < 1.0e9_dp)) return
    i0 = ceiling(v0 - 1.0_dp + o)
    i1 = floor(v1 + o)
    cap = sweep_units_per_ray * m + 256
    nunit = 0
    jlo = huge(1)
    jhi = -huge(1)
    do i = i0, i1
      call band_urange(uc, vc, i - o - dv, i + 1.0_dp - o + dv, ua, ub, anyu)
      if (.not. anyu) cycle
      if (.not. (ub - ua < 1.0e7_dp)) return
      nunit = nunit + max(0, floor(ub + du + o) - ceiling(ua - du - 1.0_dp + o) + 1)
      if (nunit > cap) return
      jlo = min(jlo, ceiling(ua - du - 1.0_dp + o))
      jhi = max(jhi, floor(ub + du + o))
    end do
    if (nunit < 1) return
    allocate(rja(i0:i1), rjb(i0:i1))
    do i = i0, i1
      rja(i) = 0
      rjb(i) = -1
      call band_urange(uc, vc, i - o - dv, i + 1.0_dp - o + dv, ua, ub, anyu)
      if (.not. anyu) cycle
      rja(i) = ceiling(ua - du - 1.0_dp + o)
      rjb(i) = floor(ub + du + o)
    end do
    ! ---- unit edges: sin, cos and prime vertical radius of the row edges, cos and sin of the column edges
    allocate(slat(i0:i1 + 1), clat(i0:i1 + 1), nrad(i0:i1 + 1), clon(jlo:jhi + 1), slon(jlo:jhi + 1))
    do i = i0, i1 + 1
      latc = dsm%lat0 + (i - o) * dsm%dlat
      slat(i) = sin(latc)
      clat(i) = cos(latc)
      nrad(i) = dsm%a / sqrt(1.0_dp - dsm%e2 * slat(i)**2)
    end do
    do j = jlo, jhi + 1
      lonc = dsm%lon0 + (j - o) * dsm%dlon
      clon(j) = cos(lonc)
      slon(j) = sin(lonc)
    end do
    ! ---- each unit's smallest progress and largest corner slope (module header), row by row. A node
    ! (edge crossing) at height h is Q(h) = Q(H_min) + (h - H_min) nrm (nrm its unit normal: the
    ! vertical edge is straight), so its distance to the plane, depth, slope numerator and progress are
    ! affine in h: their values at H_min (nv) and their rates (nw), for the row's two node rows.
    delta = dm * dm / (4.0_dp * rmin) + 1.0e-12_dp * (norm2(s) + dsm%a)
    kk = sqrt(1.0_dp + (tmax + 1.0_dp)**2)
    xfloor = 1.0e-9_dp * norm2(s)
    allocate(qmin(nunit), tcol(nunit), nv(4, jlo:jhi + 1, 2), nw(4, jlo:jhi + 1, 2))
    kc = 0
    do i = i0, i1
      if (rjb(i) < rja(i)) cycle
      do b = 1, 2
        do j = rja(i), rjb(i) + 1
          call node_values(i + b - 1, j, nv(:, j, b), nw(:, j, b))
        end do
      end do
      do j = rja(i), rjb(i)
        kc = kc + 1
        call unit_bounds(i, j, qmin(kc), tcol(kc))
      end do
    end do
    ! ---- buckets of progress (a counting sort), the running maximum of the slopes
    qlo = minval(qmin)
    qhi = maxval(qmin, mask=qmin < huge(1.0_dp))
    nb = nunit
    width = (qhi - qlo) / nb
    if (.not. (width > 0.0_dp .and. qhi >= qlo)) then
      nb = 1
      width = 1.0_dp
    end if
    allocate(bidx(nunit), bstart(nb + 1), order(nunit), bmax(nb), run(nb))
    bstart = 0
    do kc = 1, nunit
      if (qmin(kc) < huge(1.0_dp)) then
        bidx(kc) = max(1, min(nb, 1 + int((qmin(kc) - qlo) / width)))
      else
        bidx(kc) = nb                                     ! a unit off the slab: it never stops a ray
      end if
      bstart(bidx(kc) + 1) = bstart(bidx(kc) + 1) + 1
    end do
    bstart(1) = 1
    do b = 2, nb + 1
      bstart(b) = bstart(b) + bstart(b - 1)
    end do
    bmax = -huge(1.0_dp)
    do kc = 1, nunit                                      ! bstart(b) is now the next free slot of bucket b
      b = bidx(kc)
      order(bstart(b)) = kc
      bstart(b) = bstart(b) + 1
      bmax(b) = max(bmax(b), tcol(kc))
    end do
    do b = nb, 2, -1                                     ! back to the first slot of each bucket
      bstart(b) = bstart(b - 1)
    end do
    bstart(1) = 1
    run(1) = bmax(1)
    do b = 2, nb
      run(b) = max(run(b - 1), bmax(b))
    end do
    ! ---- each certified ray: the first bucket whose running maximum reaches its slope
    do k = 1, m
      if (.not. elig(k)) cycle
      tr = tk(k)
      if (.not. (run(nb) >= tr)) cycle                   ! nothing stops it: leave it to the search
      lo = 1
      hi = nb
      do while (lo < hi)
        mid = (lo + hi) / 2
        if (run(mid) >= tr) then
          hi = mid
        else
          lo = mid + 1
        end if
      end do
      qs = huge(1.0_dp)
      do kc = bstart(lo), bstart(lo + 1) - 1
        if (tcol(order(kc)) >= tr) qs = min(qs, qmin(order(kc)))
      end do
      if (.not. (qs < huge(1.0_dp))) cycle
      q = qs - 1.0e-12_dp * abs(qs)
      r = q / pk(k) * (1.0_dp - 1.0e-12_dp)
      if (r > rtop(k)) rc(k) = r
    end do

  contains

    !> Values at H_min and rates per unit height of the node at row edge ev, column edge eu:
    !> distance to the plane, depth, slope numerator, progress (relative to s).
    pure subroutine node_values(ev, eu, v, r)
      integer, intent(in) :: ev, eu
      real(dp), intent(out) :: v(4), r(4)
      real(dp) :: nrm(3), dd(3)
      nrm = [clat(ev) * clon(eu), clat(ev) * slon(eu), slat(ev)]
      dd(1) = (nrad(ev) + dsm%hmin) * nrm(1) - s(1)
      dd(2) = (nrad(ev) + dsm%hmin) * nrm(2) - s(2)
      dd(3) = (nrad(ev) * (1.0_dp - dsm%e2) + dsm%hmin) * nrm(3) - s(3)
      v = [dot_product(dd, n), dot_product(dd, nu), sg * dot_product(dd, t), dot_product(dd, p)]
      r = [dot_product(nrm, n), dot_product(nrm, nu), sg * dot_product(nrm, t), dot_product(nrm, p)]
    end subroutine node_values

    !> q_min and the largest corner slope of unit (i, j) (its nodes in nv, nw), from its
    !> column's part that can lie within w_s of the plane (-huge slope, +huge q_min: none).
    !> No data: a column up to H_max (a ray can only have an event there below H_max).
    !> Outside the grid: none when skip_out (no hit or no-data point can lie there; the
    !> grid's edge slack, 8 ulp of pi in angle, is inside the delta-widened hull of the
    !> edge units, delta >= 1e-12 a), else a column up to H_max.
    pure subroutine unit_bounds(i, j, qm, tc)
      integer, intent(in) :: i, j
      real(dp), intent(out) :: qm, tc
      real(dp) :: z, ztop, dz, db(4), dt(4), fc(10), f, flo, fhi, wp, x, y, cv(4), cr(4), eps
      integer :: ke, kf, nc, ev, eu
      logical :: blk, near, inside
      blk = .true.
      near = .false.
      inside = .false.
      z = huge(1.0_dp)
      if (dsm%interp == interp_nearest) then
        if (i >= 0 .and. i <= dsm%nrows - 1 .and. j >= 0 .and. j <= dsm%ncols - 1) then
          inside = .true.
          z = dsm%hgt(j + 1, i + 1)
          blk = .not. (z == z)
        end if
      else
        if (i >= 0 .and. i <= dsm%nrows - 2 .and. j >= 0 .and. j <= dsm%ncols - 2) then
          inside = .true.
          z = max(max(dsm%hgt(j + 1, i + 1), dsm%hgt(j + 2, i + 1)), max(dsm%hgt(j + 1, i + 2), dsm%hgt(j + 2, i + 2)))
          blk = dsm%hgt(j + 1, i + 1) /= dsm%hgt(j + 1, i + 1) .or. dsm%hgt(j + 2, i + 1) /= dsm%hgt(j + 2, i + 1) &
             .or. dsm%hgt(j + 1, i + 2) /= dsm%hgt(j + 1, i + 2) .or. dsm%hgt(j + 2, i + 2) /= dsm%hgt(j + 2, i + 2)
        end if
      end if
      qm = huge(1.0_dp)
      tc = -huge(1.0_dp)
      if (.not. inside .and. skip_out) return
      ztop = dsm%hmax
      if (.not. blk) ztop = min(z, dsm%hmax)
      dz = ztop - dsm%hmin
      ! the 4 vertical edges from H_min to the top and their distances to the plane
      do ke = 1, 4
        ev = 1 + (ke - 1) / 2
        eu = j + mod(ke - 1, 2)
        db(ke) = nv(1, eu, ev)
        dt(ke) = nv(1, eu, ev) + dz * nw(1, eu, ev)
      end do
      ! the fractions f of the height range where the column's cross-section (the hull of the edges'
      ! points, delta-widened) reaches within w_s of the plane: its ends are among 0, 1 and the
      ! edges' crossings of +-wp
      wp = w_s + delta
      nc = 2
      fc(1) = 0.0_dp
      fc(2) = 1.0_dp
      do ke = 1, 4
        if (dt(ke) /= db(ke)) then
          f = (wp - db(ke)) / (dt(ke) - db(ke))
          if (f > 0.0_dp .and. f < 1.0_dp) then
            nc = nc + 1
            fc(nc) = f
          end if
          f = (-wp - db(ke)) / (dt(ke) - db(ke))
          if (f > 0.0_dp .and. f < 1.0_dp) then
            nc = nc + 1
            fc(nc) = f
          end if
        end if
      end do
      ! a crossing's own test: db + f (dt - db) is rounded at ~1e-16 of |db| + |dt|, which is far
      ! more than wp when the rays are coplanar to rounding (w_s ~ 1e-12 m): the slack is relative
      ! to those magnitudes (without it the crossing of -wp could fail its test and the clip end
      ! where the plane passes through an edge be lost; found with a frame camera's column fans)
      eps = 1.0e-12_dp * (wp + maxval(abs(db)) + maxval(abs(dt)))
      flo = huge(1.0_dp)
      fhi = -huge(1.0_dp)
      do kf = 1, nc
        f = fc(kf)
        if (minval(db + f * (dt - db)) <= wp + eps .and. maxval(db + f * (dt - db)) >= -wp - eps) then
          flo = min(flo, f)
          fhi = max(fhi, f)
        end if
      end do
      qm = huge(1.0_dp)
      tc = -huge(1.0_dp)
      if (flo > fhi) return                               ! never within w_s of the plane: no ray meets it
      flo = max(0.0_dp, flo - 1.0e-9_dp)
      fhi = min(1.0_dp, fhi + 1.0e-9_dp)
      do ke = 1, 4
        ev = 1 + (ke - 1) / 2
        eu = j + mod(ke - 1, 2)
        cv = nv(:, eu, ev)
        cr = nw(:, eu, ev)
        do kf = 1, 2
          f = merge(flo, fhi, kf == 1) * dz
          x = cv(2) + f * cr(2)
          y = cv(3) + f * cr(3)
          qm = min(qm, cv(4) + f * cr(4))
          if (x > xfloor) then
            tc = max(tc, (y + delta * kk) / x)
          else
            near = .true.
          end if
        end do
      end do
      qm = qm - delta
      if (near) then
        tc = huge(1.0_dp)
      else
        tc = tc + 1.0e-12_dp * (1.0_dp + abs(tc))
      end if
    end subroutine unit_bounds

  end subroutine sweep_side

  !> Smallest and largest u over the convex hull of the 4 points (uc, vc)
  !> within va <= v <= vb (anyu = .false.: no point there). The hull's part in
  !> the band is a convex polygon whose vertices are hull vertices inside the
  !> band or crossings of hull edges with the band's lines; hull edges are
  !> among the 6 pairs, and the other pairs' crossings lie inside it.
  pure subroutine band_urange(uc, vc, va, vb, ua, ub, anyu)
    real(dp), intent(in) :: uc(4), vc(4), va, vb
    real(dp), intent(out) :: ua, ub
    logical, intent(out) :: anyu
    integer :: k, j, side
    real(dp) :: vv, uu
    ua = huge(1.0_dp)
    ub = -huge(1.0_dp)
    do k = 1, 4
      if (vc(k) >= va .and. vc(k) <= vb) then
        ua = min(ua, uc(k))
        ub = max(ub, uc(k))
      end if
    end do
    do k = 1, 3
      do j = k + 1, 4
        if (vc(k) == vc(j)) cycle
        do side = 1, 2
          vv = merge(va, vb, side == 1)
          if ((vc(k) - vv) * (vc(j) - vv) <= 0.0_dp) then
            uu = uc(k) + (vv - vc(k)) * (uc(j) - uc(k)) / (vc(j) - vc(k))
            ua = min(ua, uu)
            ub = max(ub, uu)
          end if
        end do
      end do
    end do
    anyu = ub >= ua
  end subroutine band_urange

end module pi_dsm_sweep
