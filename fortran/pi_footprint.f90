!> Footprint geometry of an orbiting nadir instrument (Mars Odyssey GRS notes,
!> source document 003): for every spectrum (spacecraft position R) and every
!> cell of a regular latitude/longitude cell table, the cell-to-spacecraft
!> vector d, its length, the detector's solid angle, the zenith angles with
!> the areocentric and the areodetic normal, the emission angle against the
!> cell's topographic normal, the nadir angle, the position angle and the
!> cell's coordinates in the spacecraft-local frame, for the cells in the
!> footprint only.
!>
!> Frame: planet-fixed, x to (0 N, 0 E), z north. Lengths in the DEM's units,
!> angles in radians. Cells: row-major from the south-west, `nrow = pi/cd`
!> rows of `ncol = 2 pi/cd` columns; cell k = i*ncol + j (0-based) has its
!> centre at areocentric latitude -pi/2 + (i + 1/2) cd and east longitude
!> (j + 1/2) cd. The caller supplies per cell the unit centre direction u,
!> the centre radius |r_C| (r_C = |r_C| u), the unit areodetic normal and the
!> unit topographic normal.
!>
!> Selection (docs/grs-notes.md, notes 6 and 7): a cell is in the footprint of
!> spectrum s when it is above its horizon, d . u > 0 (the areocentric normal
!> defines the horizon), and cos psi = d_hat . R_hat >= zeta(s). Only the
!> candidate cells are evaluated: those whose centre lies within the largest
!> central angle theta_max that any selected cell can have (a latitude band
!> and, per row, a longitude interval), computed from the lowest cell radius:
!> both the horizon limit acos(r/|R|) and the cone limit
!> asin(|R| sin psi_max / r) - psi_max decrease with r, so the lowest cell
!> bounds them all. The prefilter only removes cells that fail the exact test.
!>
!> No state is kept between calls; spectra are independent and computed by
!> the same code whichever OpenMP thread runs them, so results are
!> bit-identical for any thread count. No STOP, no I/O.
module pi_footprint
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
  use pi_kinds, only: dp, i8
  use pi_vector, only: pi
  !$ use omp_lib, only: omp_get_max_threads
  implicit none
  private

  public :: footprint_count, footprint_fill
  public :: fp_ok, fp_bad_position, fp_inside, fp_bad_cells, fp_bad_offsets

  !> Success (routine and per-spectrum code).
  integer, parameter :: fp_ok = 0
  !> Per spectrum: the spacecraft position is NaN/Inf or zero.
  integer, parameter :: fp_bad_position = 1
  !> Per spectrum: the spacecraft is not above the highest cell centre.
  integer, parameter :: fp_inside = 2
  !> Routine: the cell arrays disagree with nrow x ncol or a radius is not positive.
  integer, parameter :: fp_bad_cells = 3
  !> Routine: the pair offsets disagree with the counts of the spectra.
  integer, parameter :: fp_bad_offsets = 4

  !> asin x for 0 <= x < 0.5 is fdlibm's rational kernel x + x P(x^2)/Q(x^2)
  !> (__ieee754_asin, Sun Microsystems 1993: "Permission to use, copy, modify,
  !> and distribute this software is freely granted, provided that this notice
  !> is preserved"); these are its coefficients, and pi/2 in two parts.
  real(dp), parameter :: ps0 = 1.66666666666666657415e-01_dp, ps1 = -3.25565818622400915405e-01_dp, &
    ps2 = 2.01212532134862925881e-01_dp, ps3 = -4.00555345006794114027e-02_dp, &
    ps4 = 7.91534994289814532176e-04_dp, ps5 = 3.47933107596021167570e-05_dp, &
    qs1 = -2.40339491173441421878e+00_dp, qs2 = 2.02094576023350569471e+00_dp, &
    qs3 = -6.88283971605453293030e-01_dp, qs4 = 7.70381505559019352791e-02_dp, &
    pio2_hi = 1.57079632679489655800e+00_dp, pio2_lo = 6.12323399573676603587e-17_dp

  !> Angular margin (radians) added to the prefilter's central angle and
  !> longitude half-width, far above the rounding of the bounds.
  real(dp), parameter :: margin = 1.0e-7_dp

contains

  !> Number of footprint cells of each spectrum (the first of the two passes).
  !>
  !> Inputs: R(3, ns) spacecraft positions (planet-fixed, DEM units); zeta(ns)
  !> the cone's cos psi threshold per spectrum (<= 0: the horizon alone);
  !> nrow, ncol, cd (radians) the cell grid; u(3, nc) unit centre directions,
  !> rc(nc) centre radii, rmin and rtop their least and largest value (the
  !> prefilter's bound and the inside test); threads (0: all).
  !> Outputs: counts(ns) cells in each footprint; status(ns) fp_ok,
  !> fp_bad_position or fp_inside (count 0); stat fp_ok or fp_bad_cells.
  subroutine footprint_count(ns, r, zeta, nrow, ncol, cd, nc, u, rc, rmin, rtop, threads, counts, status, stat)
    integer, intent(in) :: ns, nrow, ncol, nc, threads
    real(dp), intent(in) :: r(3, ns), zeta(ns), cd, u(3, nc), rc(nc), rmin, rtop
    integer(i8), intent(out) :: counts(ns)
    integer, intent(out) :: status(ns), stat
    real(dp) :: dummy(1, 1), dummy3(3, 1), frames(3, 3, 1)
    integer :: s, nt
    integer(i8) :: n
    integer :: idummy(1, 1)
    counts = 0
    status = fp_ok
    call check_cells(nrow, ncol, nc, rmin, rtop, stat)
    if (stat /= fp_ok) return
    frames = 0.0_dp
    nt = thread_count(threads)
    !$omp parallel do schedule(dynamic, 1) num_threads(nt) default(shared) private(s, n, dummy, dummy3, idummy)
    do s = 1, ns
      call scan_spectrum(.false., s, r(:, s), frames(:, :, 1), zeta(s), nrow, ncol, cd, nc, u, rc, u, u, &
                         rmin, rtop, 0.0_dp, 1.0_dp, 0_i8, 1_i8, idummy, dummy3, dummy3, dummy, n, status(s))
      counts(s) = n
    end do
    !$omp end parallel do
  end subroutine footprint_count

  !> The footprint pairs of every spectrum with their geometry (second pass).
  !>
  !> Inputs as footprint_count, plus: frames(3, 3, ns), frames(:, i, s) the
  !> i-th unit axis of spectrum s's spacecraft frame in the planet frame (x up,
  !> y along the ground track, z = x cross y); ndet(3, nc) unit areodetic
  !> normals; snorm(3, nc) unit topographic normals; area the detector's
  !> projected area (DEM units squared); ascale the factor applied to every
  !> angle as the last operation (1: radians; 180/pi: degrees, the same
  !> rounding as multiplying the radians afterwards, without another pass over
  !> the outputs); offsets(ns) the 0-based index of each
  !> spectrum's first pair (the running sum of footprint_count's counts); m the
  !> total number of pairs.
  !> Outputs (pair p, 1-based): idx(p, 1) spectrum, idx(p, 2) cell (0-based);
  !> d(:, p) = R - r_C; gsh(:, p) = r_C - R in the spacecraft frame; scal(p, :) =
  !> 1 |d|, 2 solid angle area/|d|^2 (sr), 3 zenith angle against u,
  !> 4 zenith angle against the areodetic normal, 5 emission angle against the
  !> topographic normal, 6 nadir angle psi, 7 position angle clockwise from
  !> north through east in [0, 2 pi) (NaN when the spacecraft is over a pole or
  !> the cell is at the sub-spacecraft point), 8 azimuth in the spacecraft
  !> frame from +y toward +z in [0, 2 pi), 9 elevation above the frame's y-z
  !> plane (columns 3-9 in radians times ascale). The outputs are only
  !> written (pairs beyond m are never touched), so the caller may pass
  !> uninitialised or reused memory. status(ns), stat as footprint_count, stat fp_bad_offsets
  !> when a spectrum's pairs would not fit its slot (nothing is then trusted).
  subroutine footprint_fill(ns, r, frames, zeta, nrow, ncol, cd, nc, u, rc, rmin, rtop, ndet, snorm, area, &
                            ascale, offsets, m, threads, idx, d, gsh, scal, status, stat)
    integer, intent(in) :: ns, nrow, ncol, nc, threads
    integer(i8), intent(in) :: m, offsets(ns)
    real(dp), intent(in) :: r(3, ns), frames(3, 3, ns), zeta(ns), cd, u(3, nc), rc(nc), rmin, rtop, &
                            ndet(3, nc), snorm(3, nc), area, ascale
    integer, intent(out) :: idx(m, 2), status(ns), stat
    real(dp), intent(out) :: d(3, m), gsh(3, m), scal(m, 9)
    integer :: s, nt, bad
    integer(i8) :: n, room
    status = fp_ok
    call check_cells(nrow, ncol, nc, rmin, rtop, stat)
    if (stat /= fp_ok) return
    do s = 1, ns
      if (offsets(s) < 0 .or. offsets(s) > m) then
        stat = fp_bad_offsets
        return
      end if
    end do
    nt = thread_count(threads)
    bad = 0
    !$omp parallel do schedule(dynamic, 1) num_threads(nt) default(shared) private(s, n, room) reduction(max:bad)
    do s = 1, ns
      if (s < ns) then
        room = offsets(s + 1) - offsets(s)
      else
        room = m - offsets(s)
      end if
      call scan_spectrum(.true., s, r(:, s), frames(:, :, s), zeta(s), nrow, ncol, cd, nc, u, rc, ndet, snorm, &
                         rmin, rtop, area, ascale, offsets(s), room, idx, d, gsh, scal, n, status(s))
      if (n > room) bad = 1
    end do
    !$omp end parallel do
    if (bad /= 0) stat = fp_bad_offsets
  end subroutine footprint_fill

  !> Check the cell grid's shape and the radius bounds (rmin, rtop: the least
  !> and largest of rc, computed once per table by the caller rather than
  !> scanned on every call).
  subroutine check_cells(nrow, ncol, nc, rmin, rtop, stat)
    integer, intent(in) :: nrow, ncol, nc
    real(dp), intent(in) :: rmin, rtop
    integer, intent(out) :: stat
    stat = fp_ok
    if (nrow < 1 .or. ncol /= 2*nrow .or. int(nrow, i8)*int(ncol, i8) /= int(nc, i8)) then
      stat = fp_bad_cells
      return
    end if
    if (.not. (rmin > 0.0_dp .and. rtop >= rmin .and. rtop < huge(rtop))) stat = fp_bad_cells
  end subroutine check_cells

  !> OpenMP thread count: `threads` when positive, else all available.
  integer function thread_count(threads) result(nt)
    integer, intent(in) :: threads
    nt = 1
    !$ nt = omp_get_max_threads()
    if (threads > 0) nt = threads
  end function thread_count

  !> Visit the candidate cells of one spectrum; count those in the footprint
  !> and, when `fill`, write their geometry from pair index base + 1 on (at
  !> most `room` pairs). n returns the number of footprint cells.
  subroutine scan_spectrum(fill, s, r, frame, zeta, nrow, ncol, cd, nc, u, rc, ndet, snorm, rmin, rtop, area, &
                           ascale, base, room, idx, d, gsh, scal, n, status)
    logical, intent(in) :: fill
    integer, intent(in) :: s, nrow, ncol, nc
    real(dp), intent(in) :: r(3), frame(3, 3), zeta, cd, u(3, nc), rc(nc), ndet(3, nc), snorm(3, nc), &
                            rmin, rtop, area, ascale
    integer(i8), intent(in) :: base, room
    integer, intent(inout) :: idx(:, :)
    real(dp), intent(inout) :: d(:, :), gsh(:, :), scal(:, :)
    integer(i8), intent(out) :: n
    integer, intent(out) :: status
    real(dp) :: rn, rhat(3), beta, lam, theta, psim, q, cmax, sb, cb, phi, sp, cp, rhs, dlam
    real(dp) :: east(3), north(3), dv(3), dist2, dist, dh(3), uk(3), x, y, nan, pole, track, rho, pa
    real(dp), allocatable :: hm(:, :), hp(:, :), ang(:, :), px(:)
    integer, allocatable :: buf(:)
    integer :: ilo, ihi, i, jlo, jhi, jj, j, k, nb, b, c5
    real(dp) :: t, z, q2, rr, aa
    logical :: low
    integer(i8) :: p, p0
    n = 0
    status = fp_ok
    if (.not. all(abs(r) < huge(r))) then
      status = fp_bad_position
      return
    end if
    rn = norm2(r)
    if (.not. rn > 0.0_dp) then
      status = fp_bad_position
      return
    end if
    if (.not. rn > rtop) then
      status = fp_inside
      return
    end if
    rhat = r / rn
    nan = ieee_value(nan, ieee_quiet_nan)
    if (fill) allocate(buf(ncol), hm(ncol, 5), hp(ncol, 5), ang(ncol, 5), px(ncol))
    ! largest central angle of a selected cell (module header): horizon, then the cone
    theta = acos(rmin / rn)
    if (zeta > 0.0_dp) then
      psim = acos(min(zeta, 1.0_dp))
      q = rn * sin(psim) / rmin
      if (q < 1.0_dp) theta = min(theta, asin(q) - psim)
    end if
    theta = max(theta, 0.0_dp) + margin
    cmax = cos(min(theta, pi))
    beta = atan2(rhat(3), hypot(rhat(1), rhat(2)))
    lam = atan2(rhat(2), rhat(1))
    sb = sin(beta)
    cb = cos(beta)
    ! local east and north at the sub-spacecraft point, both scaled by cos(beta)
    ! (their common factor cancels in atan2): notes' position angle, corrected (note 5)
    east = [-rhat(2), rhat(1), 0.0_dp]
    north = [-rhat(3)*rhat(1), -rhat(3)*rhat(2), 1.0_dp - rhat(3)*rhat(3)]
    pole = hypot(rhat(1), rhat(2))
    ! bearing of the frame's +y axis (the ground track, clockwise from north), for the azimuth
    if (fill .and. pole > 1.0e-12_dp) then
      track = atan2(dot_product(frame(:, 2), east), dot_product(frame(:, 2), north))
    else
      track = 0.0_dp
    end if
    ilo = max(0, ceiling((beta - theta + pi/2) / cd - 0.5_dp))
    ihi = min(nrow - 1, floor((beta + theta + pi/2) / cd - 0.5_dp))
    do i = ilo, ihi
      phi = -pi/2 + (real(i, dp) + 0.5_dp) * cd
      sp = sin(phi)
      cp = cos(phi)
      if (cp * cb <= 1.0e-12_dp) then
        jlo = 0
        jhi = ncol - 1
      else
        rhs = (cmax - sp*sb) / (cp*cb)
        if (rhs > 1.0_dp) cycle
        if (rhs <= -1.0_dp) then
          jlo = 0
          jhi = ncol - 1
        else
          dlam = acos(rhs) + margin
          jlo = ceiling((lam - dlam) / cd - 0.5_dp)
          jhi = floor((lam + dlam) / cd - 0.5_dp)
          if (jhi - jlo + 1 >= ncol) then
            jlo = 0
            jhi = ncol - 1
          end if
        end if
      end if
      nb = 0
      ! column j = modulo(jj, ncol), stepped rather than divided per cell (an integer
      ! division per candidate cell cost more than the test itself); the range
      ! spans fewer than ncol columns, so j wraps at most once
      j = modulo(jlo, ncol) - 1
      do jj = jlo, jhi
        j = j + 1
        if (j == ncol) j = 0
        k = i*ncol + j + 1
        uk = u(:, k)
        dv = r - rc(k)*uk                                   ! notes: d = R_S/C - r_C
        if (.not. dot_product(dv, uk) > 0.0_dp) cycle       ! below the horizon (note 7)
        dist2 = dot_product(dv, dv)
        dist = sqrt(dist2)
        if (dot_product(dv, rhat) < zeta * dist) cycle      ! cos psi >= zeta (note 6)
        n = n + 1
        if (.not. fill .or. n > room) cycle
        nb = nb + 1
        buf(nb) = k
      end do
      if (nb == 0) cycle
      ! the row's footprint cells in three passes that the compiler can vectorise:
      ! (1) vectors and the squared chords |a -+ b|^2 of every angle, (2) the
      ! angles from the chords, (3) the angles written out
      p0 = base + n - nb
      do b = 1, nb
        k = buf(b)
        p = p0 + b
        dv = r - rc(k)*u(:, k)
        dist2 = dv(1)*dv(1) + dv(2)*dv(2) + dv(3)*dv(3)
        dist = sqrt(dist2)
        dh = dv / dist
        idx(p, 1) = s - 1
        idx(p, 2) = k - 1
        d(:, p) = dv
        scal(p, 1) = dist
        scal(p, 2) = area / dist2                           ! notes: Omega = A / |d|^2
        call chords(dh, u(:, k), hm(b, 1), hp(b, 1))       ! notes: cos z = r_C . d / (|r_C| |d|)
        call chords(dh, ndet(:, k), hm(b, 2), hp(b, 2))     ! areodetic normal (note 2)
        call chords(dh, snorm(:, k), hm(b, 3), hp(b, 3))    ! notes: cos e = s_C . d_hat
        call chords(dh, rhat, hm(b, 4), hp(b, 4))           ! notes: cos psi = d_hat . R_hat
        ! position angle: the cell's direction (east, north) at the sub-spacecraft
        ! point as a unit 2-vector (c, s) = (north, east); its angle from north (note 5)
        x = u(1, k)*east(1) + u(2, k)*east(2)
        y = u(1, k)*north(1) + u(2, k)*north(2) + u(3, k)*north(3)
        px(b) = x
        rho = sqrt(x*x + y*y)
        if (rho > 0.0_dp) then
          hm(b, 5) = (y/rho - 1.0_dp)**2 + (x/rho)**2
          hp(b, 5) = (y/rho + 1.0_dp)**2 + (x/rho)**2
        else
          hm(b, 5) = 0.0_dp
          hp(b, 5) = 4.0_dp
          px(b) = nan                                       ! the cell at the sub-spacecraft point
        end if
        gsh(1, p) = -dot_product(frame(:, 1), dv)           ! r_C - R in the spacecraft frame (note 9)
        gsh(2, p) = -dot_product(frame(:, 2), dv)
        gsh(3, p) = -dot_product(frame(:, 3), dv)
      end do
      ! [note 15] angle (0..pi) between unit vectors from their squared chords hm = |a - b|^2,
      ! hp = |a + b|^2: 2 asin(sqrt(hm)/2) up to 90 deg, pi - 2 asin(sqrt(hp)/2)
      ! beyond, so that asin's argument t stays below 0.7072; asin t from fdlibm's
      ! kernel, for t >= 1/2 as pi/2 - 2 asin(sqrt((1 - t)/2)). Accurate near 0 and
      ! pi where acos(a . b) is not; within 2 ulp of libm (tested). Inline
      ! arithmetic instead of libm's asin and atan2, which took half of the
      ! kernel's time. The merges do not make the loop vectorise: without
      ! fast-math (-ftrapping-math) gfortran 12 may not speculate the sqrt and
      ! compiles them to branches ("control flow in loop"); a branch-free variant
      ! (both arms computed, 0/1-weight blends, bit-identical) does vectorise but
      ! was not measurably faster with 2-wide SSE2 (docs/grs-notes.md, speed).
      do c5 = 1, 5
        do b = 1, nb
          t = 0.5_dp * sqrt(min(hm(b, c5), hp(b, c5)))
          low = t < 0.5_dp
          z = merge(t, sqrt(0.5_dp*(1.0_dp - t)), low)
          q2 = z*z
          rr = z + z*(q2*(ps0 + q2*(ps1 + q2*(ps2 + q2*(ps3 + q2*(ps4 + q2*ps5)))))) / &
               (1.0_dp + q2*(qs1 + q2*(qs2 + q2*(qs3 + q2*qs4))))
          aa = merge(rr, (pio2_hi - 2.0_dp*rr) + pio2_lo, low)
          ang(b, c5) = merge(2.0_dp*aa, pi - 2.0_dp*aa, hm(b, c5) <= hp(b, c5))
        end do
      end do
      do b = 1, nb
        p = p0 + b
        scal(p, 3) = ang(b, 1) * ascale
        scal(p, 4) = ang(b, 2) * ascale
        scal(p, 5) = ang(b, 3) * ascale
        scal(p, 6) = ang(b, 4) * ascale
        if (pole > 1.0e-12_dp .and. px(b) == px(b)) then
          pa = wrap_2pi(sign(ang(b, 5), px(b)))             ! clockwise from north through east (note 5)
          scal(p, 7) = pa * ascale
          ! azimuth from +y (forward) toward +z (left): the horizontal part of r_C - R
          ! is that of r_C, whose bearing is the position angle, so az = (bearing
          ! of the track) - PA (the notes' alpha: track = pi/2 - alpha)
          scal(p, 8) = wrap_2pi(track - pa) * ascale
        else
          scal(p, 7) = nan                                  ! over a pole north is undefined
          scal(p, 8) = wrap_2pi(atan2(gsh(3, p), gsh(2, p))) * ascale
        end if
        ! elevation: the frame's x axis is R_hat, so el = asin(-d_hat . R_hat) = psi - pi/2
        scal(p, 9) = (ang(b, 4) - pi/2) * ascale
      end do
    end do
  end subroutine scan_spectrum

  !> Squared chords |a - b|^2 and |a + b|^2 of two unit vectors (the angle's input in scan_spectrum).
  pure subroutine chords(a, b, hm, hp)
    real(dp), intent(in) :: a(3), b(3)
    real(dp), intent(out) :: hm, hp
    hm = (a(1) - b(1))**2 + (a(2) - b(2))**2 + (a(3) - b(3))**2
    hp = (a(1) + b(1))**2 + (a(2) + b(2))**2 + (a(3) + b(3))**2
  end subroutine chords

  !> An angle mapped to [0, 2 pi).
  pure real(dp) function wrap_2pi(a) result(w)
    real(dp), intent(in) :: a
    w = a
    if (w < 0.0_dp) w = w + 2.0_dp*pi
    if (w >= 2.0_dp*pi) w = 0.0_dp
  end function wrap_2pi

end module pi_footprint
