!> The order in which a batch of DSM rays is traced: rays whose lines of sight
!> meet the surface near one another are traced one after the other, so that
!> the grid nodes and pyramid blocks one ray reads are still in cache for the
!> next (docs/shin-park-notes.md, "Ray order").
!>
!> Only speed depends on the order: every ray's answer is computed from its own
!> s and l alone (pi_dsm_exact's dsm_trace_packed writes it into the ray's own
!> column), so the results are the same bit for bit in any order.
!>
!> A batch that is already coherent (the pixels of image lines in turn, a
!> pushbroom scan: most of ray_order_pairs evenly spaced pairs of consecutive
!> rays land within ray_order_near cells of each other) keeps its order; otherwise the rays are sorted by the Morton
!> (Z-order) code of the point where each line of sight meets the ellipsoid
!> raised to the DSM's middle height, quantised at about one grid cell (rays
!> that miss it, and bad rays, go last in their given order).
module pi_ray_order
  use pi_kinds, only: dp, i8
  use pi_dsm, only: dsm_t
  use pi_ieee, only: ieee_is_finite => is_finite
  implicit none
  private

  public :: ray_order, ray_order_min, ray_order_near

  !> smallest batch that is sorted (fewer rays gain nothing worth the pass)
  integer, parameter :: ray_order_min = 256
  !> consecutive rays landing within this many grid cells of each other count as coherent
  real(dp), parameter :: ray_order_near = 16.0_dp
  !> pairs of consecutive rays sampled for the coherence test
  integer, parameter :: ray_order_pairs = 256
  !> bits per axis of the Morton code (3 x 21 = 63)
  integer, parameter :: nbits = 21

contains

  !> The order in which to trace the rays s(:, k) + r l(:, k), k = 1..n, over
  !> the DSM: order(1..n) a permutation of 1..n; sorted = .false. when the
  !> batch keeps its given order (order(k) = k: fewer than ray_order_min rays,
  !> or a coherent batch). Inputs ECR, in the DSM's length unit; l need not be
  !> unit; non-finite or zero rays are allowed (they go last).
  pure subroutine ray_order(dsm, n, s, l, order, sorted)
    type(dsm_t), intent(in) :: dsm
    integer, intent(in) :: n
    real(dp), intent(in) :: s(3, n), l(3, n)
    integer, intent(out) :: order(n)
    logical, intent(out) :: sorted
    real(dp), allocatable :: pt(:, :)
    logical, allocatable :: ok(:)
    integer(i8), allocatable :: key(:)
    real(dp) :: ra, rb, cell, lo(3), hi(3), q, d2, near2, p1(3), p2(3)
    integer :: k, m, nok, nnear, npair, axis
    logical :: ok1, ok2
    integer(i8) :: c(3)
    sorted = .false.
    do k = 1, n
      order(k) = k
    end do
    if (n < ray_order_min) return
    ra = dsm%a + 0.5_dp * (dsm%hmax + dsm%hmin)
    rb = dsm%b + 0.5_dp * (dsm%hmax + dsm%hmin)
    if (.not. (ra > 0.0_dp .and. rb > 0.0_dp .and. ieee_is_finite(ra) .and. ieee_is_finite(rb))) return
    ! a grid cell in length units (its north-south side; the east-west one is no longer)
    cell = abs(dsm%dlat) * dsm%a
    if (.not. (cell > 0.0_dp .and. ieee_is_finite(cell))) return
    ! coherent already? (most of ray_order_pairs evenly spaced pairs of consecutive rays land
    ! within ray_order_near cells of each other: a coherent batch costs ~2 ray_order_pairs landings)
    near2 = (ray_order_near * cell)**2
    nnear = 0
    npair = 0
    do m = 1, min(ray_order_pairs, n - 1)
      k = 1 + int((int(m - 1, i8) * (n - 1)) / min(ray_order_pairs, n - 1))   ! 1 <= k <= n - 1
      call landing(s(:, k), l(:, k), ra, rb, p1, ok1)
      call landing(s(:, k + 1), l(:, k + 1), ra, rb, p2, ok2)
      if (ok1 .and. ok2) then
        npair = npair + 1
        d2 = sum((p2 - p1)**2)
        if (d2 <= near2) nnear = nnear + 1
      end if
    end do
    if (npair == 0 .or. 2 * nnear >= npair) return
    allocate(pt(3, n), ok(n))
    do k = 1, n
      call landing(s(:, k), l(:, k), ra, rb, pt(:, k), ok(k))
    end do
    nok = count(ok)
    if (nok < ray_order_min) return
    lo = huge(1.0_dp)
    hi = -huge(1.0_dp)
    do k = 1, n
      if (ok(k)) then
        lo = min(lo, pt(:, k))
        hi = max(hi, pt(:, k))
      end if
    end do
    ! quantum: one cell, or coarser when the landings spread over more than 2^21 cells
    q = max(cell, maxval(hi - lo) / (2.0_dp**nbits - 2.0_dp))
    allocate(key(n))
    do k = 1, n
      if (ok(k)) then
        do axis = 1, 3
          c(axis) = min(int((pt(axis, k) - lo(axis)) / q, i8), 2_i8**nbits - 1_i8)
        end do
        key(k) = ior(spread_bits(c(1)), ior(ishft(spread_bits(c(2)), 1), ishft(spread_bits(c(3)), 2)))
      else
        key(k) = huge(1_i8)                               ! after every landing (63-bit codes), in given order
      end if
    end do
    call radix_order(n, key, order)
    sorted = .true.
  end subroutine ray_order

  !> Where the line s + r l first meets the ellipsoid of semi-axes (ra, ra, rb)
  !> for r >= 0 (s itself when s is inside it); ok = .false. when it misses,
  !> l is zero or the ray is not finite.
  pure subroutine landing(s, l, ra, rb, p, ok)
    real(dp), intent(in) :: s(3), l(3), ra, rb
    real(dp), intent(out) :: p(3)
    logical, intent(out) :: ok
    real(dp) :: w(3), sw(3), lw(3), lu(3), qa, qb, qc, disc, r, lm
    p = s
    ok = .false.
    if (.not. (all(ieee_is_finite(s)) .and. all(ieee_is_finite(l)))) return
    ! l scaled to its largest component: |l| up to huge(1.0) without overflow in qa or disc
    ! (a review: |l| >= 1e161 made qb*qb - qa*qc an inf - inf)
    lm = maxval(abs(l))
    if (.not. (lm > 0.0_dp)) return
    lu = l / lm
    w = [1.0_dp / ra, 1.0_dp / ra, 1.0_dp / rb]
    sw = s * w
    lw = lu * w
    qa = dot_product(lw, lw)
    qb = dot_product(sw, lw)
    qc = dot_product(sw, sw) - 1.0_dp
    if (.not. (qa > 0.0_dp)) return
    if (qc <= 0.0_dp) then                                ! inside: the ray starts at its landing
      ok = .true.
      return
    end if
    disc = qb * qb - qa * qc
    if (.not. (disc >= 0.0_dp .and. qb < 0.0_dp)) return  ! misses, or points away
    r = qc / (-qb + sqrt(disc))                           ! the nearer root, without cancellation
    p = s + r * lu
    ok = all(ieee_is_finite(p))
  end subroutine landing

  !> The 21 low bits of x spread to every third bit (bit i to bit 3 i).
  pure function spread_bits(x) result(y)
    integer(i8), intent(in) :: x
    integer(i8) :: y
    y = iand(x, int(z'1FFFFF', i8))
    y = iand(ior(y, ishft(y, 32)), int(z'1F00000000FFFF', i8))
    y = iand(ior(y, ishft(y, 16)), int(z'1F0000FF0000FF', i8))
    y = iand(ior(y, ishft(y, 8)), int(z'100F00F00F00F00F', i8))
    y = iand(ior(y, ishft(y, 4)), int(z'10C30C30C30C30C3', i8))
    y = iand(ior(y, ishft(y, 2)), int(z'1249249249249249', i8))
  end function spread_bits

  !> order(1..n) = 1..n stably sorted by key (non-negative): a least significant
  !> digit radix sort, 8 bits a pass, passes whose digit is the same for every
  !> key skipped.
  pure subroutine radix_order(n, key, order)
    integer, intent(in) :: n
    integer(i8), intent(in) :: key(n)
    integer, intent(inout) :: order(n)
    integer, allocatable :: tmp(:)
    integer :: cnt(0:255), pass, k, d, tot, c
    integer(i8) :: kor, kand
    allocate(tmp(n))
    kor = 0_i8
    kand = not(0_i8)
    do k = 1, n
      kor = ior(kor, key(k))
      kand = iand(kand, key(k))
    end do
    do pass = 0, 7
      if (iand(ishft(ieor(kor, kand), -8 * pass), 255_i8) == 0_i8) cycle   ! the same digit in every key
      cnt = 0
      do k = 1, n
        d = int(iand(ishft(key(order(k)), -8 * pass), 255_i8))
        cnt(d) = cnt(d) + 1
      end do
      tot = 0
      do d = 0, 255
        c = cnt(d)
        cnt(d) = tot
        tot = tot + c
      end do
      do k = 1, n
        d = int(iand(ishft(key(order(k)), -8 * pass), 255_i8))
        cnt(d) = cnt(d) + 1
        tmp(cnt(d)) = order(k)
      end do
      order = tmp
    end do
  end subroutine radix_order

end module pi_ray_order
