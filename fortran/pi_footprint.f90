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
  use pi_ieee, only: nan_dp
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

  !> A cell whose direction from the sub-spacecraft point has a horizontal part
  !> rho <= rho_nadir cos(beta) (the angle from the nadir below 1e-13 rad: within a
  !> few hundred roundings of 0) is at the sub-spacecraft point: its position
  !> angle and azimuth are NaN [note 5].
  real(dp), parameter :: rho_nadir = 1.0e-13_dp

  !> Relative tightening of both thresholds (the horizon's rtop/|R| and the cone's
  !> zeta) for the cells taken without a test (scan_spectrum).
  real(dp), parameter :: in_slack = 1.0e-9_dp

  !> The square-root-free cone test (in_cone): a^2 and zeta^2 |d|^2 are compared
  !> only between sq_lo and sq_hi (normal numbers, products of normal numbers
  !> without overflow) and decided only when they differ by more than sq_band.
  real(dp), parameter :: sq_lo = 1.0e-280_dp, sq_hi = 1.0e280_dp, sq_band = 1.0e-12_dp

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
  !>
  !> Per row (docs/grs-notes.md, speed): the candidates within the row's
  !> longitude interval of certain cells are taken untested, the others tested
  !> (no square root outside a narrow band around the cone's edge, in_cone);
  !> the row's footprint pairs then go to row_pairs, whose loops over the pairs
  !> gfortran vectorises (one 1/|d| shared by every angle, each angle from its
  !> squared chords without branches).
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
    real(dp) :: rn, rhat(3), beta, lam, theta, psim, q, cmax, sb, cb, phi, sp, cp, rhs, dlam, gin, cin
    real(dp) :: east(3), north(3), dv(3), dist2, uk(3), pole, track, zeta2, a
    real(dp), allocatable :: w(:, :), cu(:, :), cr(:), cn(:, :), cs(:, :)
    integer, allocatable :: buf(:)
    integer :: ilo, ihi, i, jlo, jhi, jj, j, k, nb, b, jlc, jhc
    logical :: quick, gamma_fast
    integer(i8) :: p0
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
    if (fill) allocate(buf(ncol), w(ncol, 12), cu(3, ncol), cr(ncol), cn(3, ncol), cs(3, ncol))
    ! the cone test without its square root (in_cone) only where zeta^2 is a normal number
    zeta2 = zeta*zeta
    quick = zeta2 >= sq_lo .and. zeta2 <= 1.0_dp
    ! largest central angle of a selected cell (module header): horizon, then the cone
    theta = acos(rmin / rn)
    if (zeta > 0.0_dp) then
      psim = acos(min(zeta, 1.0_dp))
      q = rn * sin(psim) / rmin
      if (q < 1.0_dp) theta = min(theta, asin(q) - psim)
    end if
    theta = max(theta, 0.0_dp) + margin
    cmax = cos(min(theta, pi))
    ! central angle within which every cell passes both tests with room to spare
    ! (the same bounds from the highest cell radius, rtop, with the thresholds
    ! tightened by a relative 1e-9, far above the tests' rounding): those cells are
    ! taken without evaluating the tests, only the band between the two angles is
    ! tested. The candidate set is unchanged, and so is the result.
    gin = acos(min(1.0_dp, (rtop / rn) * (1.0_dp + in_slack)))
    if (zeta > 0.0_dp) then
      if (zeta + in_slack < 1.0_dp) then
        psim = acos(zeta + in_slack)
        q = rn * sin(psim) / rtop
        if (q < 1.0_dp) gin = min(gin, asin(q) - psim)
      else
        gin = 0.0_dp
      end if
    end if
    gin = gin - margin
    cin = cos(gin)
    beta = atan2(rhat(3), hypot(rhat(1), rhat(2)))
    lam = atan2(rhat(2), rhat(1))
    sb = sin(beta)
    cb = cos(beta)
    ! local east and north at the sub-spacecraft point, both scaled by cos(beta)
    ! (their common factor cancels in atan2): notes' position angle, corrected (note 5)
    east = [-rhat(2), rhat(1), 0.0_dp]
    ! (its z component x^2 + y^2, not 1 - z^2: equal for a unit rhat, but 1 - z^2 cancels near a
    ! pole: 2.3e-4 deg of position angle at 89.999999 deg, found by a review)
    north = [-rhat(3)*rhat(1), -rhat(3)*rhat(2), rhat(1)*rhat(1) + rhat(2)*rhat(2)]
    pole = hypot(rhat(1), rhat(2))
    ! every selected cell lies within theta of the sub-spacecraft point (module
    ! header): below 30 deg and away from the poles the zenith angle is psi + gamma [note 16]
    gamma_fast = theta < pi/6 - 1.0e-6_dp .and. pole > 1.0e-3_dp
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
      ! the columns jj = jlc..jhc (a part of jlo..jhi) that need no test
      jlc = 1
      jhc = 0
      if (gin > 1.0e-6_dp .and. cp * cb > 1.0e-12_dp) then
        rhs = (cin - sp*sb) / (cp*cb)
        if (rhs <= -1.0_dp) then
          jlc = jlo
          jhc = jhi
        else if (rhs < 1.0_dp) then
          dlam = acos(rhs) - margin
          if (dlam > 0.0_dp) then
            jlc = max(jlo, ceiling((lam - dlam) / cd - 0.5_dp))
            jhc = min(jhi, floor((lam + dlam) / cd - 0.5_dp))
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
        if (jj < jlc .or. jj > jhc) then
          uk = u(:, k)
          dv = r - rc(k)*uk                                 ! notes: d = R_S/C - r_C
          if (.not. dv(1)*uk(1) + dv(2)*uk(2) + dv(3)*uk(3) > 0.0_dp) cycle   ! below the horizon (note 7)
          dist2 = dv(1)*dv(1) + dv(2)*dv(2) + dv(3)*dv(3)
          a = dv(1)*rhat(1) + dv(2)*rhat(2) + dv(3)*rhat(3)
          if (.not. in_cone(a, dist2, zeta, zeta2, quick)) cycle  ! cos psi >= zeta (note 6)
        end if
        n = n + 1
        if (.not. fill .or. n > room) cycle
        nb = nb + 1
        buf(nb) = k
      end do
      if (nb == 0) cycle
      p0 = base + n - nb
      ! (1) the row's footprint cells: when they are consecutive cells of the table
      ! (the usual case) their u, |r_C| and normals are read in place, else gathered
      ! into the same layout (cu, cr, cn, cs)
      do b = 1, nb
        idx(p0 + b, 1) = s - 1
        idx(p0 + b, 2) = buf(b) - 1
      end do
      k = buf(1)
      if (buf(nb) - k == nb - 1) then
        call row_pairs(nb, r, frame, east, north, area, rhat, pole, gamma_fast, track, ascale, &
                       u(:, k:k + nb - 1), rc(k:k + nb - 1), ndet(:, k:k + nb - 1), snorm(:, k:k + nb - 1), ncol, w, &
                       d(:, p0 + 1:p0 + nb), gsh(:, p0 + 1:p0 + nb), scal(p0 + 1:p0 + nb, 1), &
                       scal(p0 + 1:p0 + nb, 2), scal(p0 + 1:p0 + nb, 3), scal(p0 + 1:p0 + nb, 4), &
                       scal(p0 + 1:p0 + nb, 5), scal(p0 + 1:p0 + nb, 6), scal(p0 + 1:p0 + nb, 7), &
                       scal(p0 + 1:p0 + nb, 8), scal(p0 + 1:p0 + nb, 9))
      else
        do b = 1, nb
          k = buf(b)
          cu(:, b) = u(:, k)
          cr(b) = rc(k)
          cn(:, b) = ndet(:, k)
          cs(:, b) = snorm(:, k)
        end do
        call row_pairs(nb, r, frame, east, north, area, rhat, pole, gamma_fast, track, ascale, cu, cr, cn, cs, ncol, w, &
                       d(:, p0 + 1:p0 + nb), gsh(:, p0 + 1:p0 + nb), scal(p0 + 1:p0 + nb, 1), &
                       scal(p0 + 1:p0 + nb, 2), scal(p0 + 1:p0 + nb, 3), scal(p0 + 1:p0 + nb, 4), &
                       scal(p0 + 1:p0 + nb, 5), scal(p0 + 1:p0 + nb, 6), scal(p0 + 1:p0 + nb, 7), &
                       scal(p0 + 1:p0 + nb, 8), scal(p0 + 1:p0 + nb, 9))
      end if
    end do
  end subroutine scan_spectrum

  !> The geometry of one row's nb footprint pairs (scan_spectrum), in loops over the
  !> pairs that gfortran vectorises: cells uc, ndc, snc (3, nb) the unit centre
  !> direction, areodetic and topographic normal, rcc(nb) the centre radius; w(ldw, 12)
  !> scratch (ldw >= nb); outputs d = R - r_C and g = r_C - R in the spacecraft
  !> frame (3, nb), and the pairs' nine scal columns s1..s9 (footprint_fill).
  subroutine row_pairs(nb, r, frame, east, north, area, rhat, pole, gamma_fast, track, ascale, uc, rcc, ndc, snc, &
                       ldw, w, d, g, s1, s2, s3, s4, s5, s6, s7, s8, s9)
    integer, intent(in) :: nb, ldw
    real(dp), intent(in) :: r(3), frame(3, 3), east(3), north(3), area, rhat(3), pole, track, ascale
    logical, intent(in) :: gamma_fast
    real(dp), intent(in) :: uc(3, nb), rcc(nb), ndc(3, nb), snc(3, nb)
    real(dp), intent(inout) :: w(ldw, 12), d(3, nb), g(3, nb), s1(nb), s2(nb), s3(nb), s4(nb), s5(nb), s6(nb), &
                               s7(nb), s8(nb), s9(nb)
    ! d, |d|, the solid angle, the frame coordinates, d_hat (w 1-3) and the position
    ! angle's 2-vector (w 4-7)
    call pair_vectors(nb, r, frame, east, north, area, uc, rcc, d, s1, s2, g, w(:, 1), w(:, 2), w(:, 3), &
                      w(:, 4), w(:, 5), w(:, 6), w(:, 7))
    ! the angles [note 15], each a branch-free loop over the row (w 8-12)
    call angles_fixed(nb, w(:, 1), w(:, 2), w(:, 3), rhat, w(:, 11))      ! notes: cos psi = d_hat . R_hat
    if (gamma_fast) then
      ! zenith angle = psi + gamma, gamma the cell's central angle from the sub-spacecraft
      ! point (the exterior angle of the triangle centre-cell-spacecraft), with
      ! sin gamma = rho / cos(beta) < 1/2 from the position angle's 2-vector [note 16]
      call zenith_sum(nb, w(:, 11), w(:, 7), 1.0_dp / pole, w(:, 8))
    else
      call angles_aos(nb, w(:, 1), w(:, 2), w(:, 3), uc, w(:, 8))         ! notes: cos z = r_C . d / (|r_C| |d|)
    end if
    call angles_aos(nb, w(:, 1), w(:, 2), w(:, 3), ndc, w(:, 9))          ! areodetic normal (note 2)
    call angles_aos(nb, w(:, 1), w(:, 2), w(:, 3), snc, w(:, 10))         ! notes: cos e = s_C . d_hat
    call angles_north(nb, w(:, 4), w(:, 5), w(:, 12))                    ! position angle (note 5)
    ! the angles written out
    call store_angles(nb, w(:, 8), w(:, 9), w(:, 10), w(:, 11), w(:, 12), w(:, 6), w(:, 7), rho_nadir * pole, &
                      pole > 1.0e-12_dp, track, ascale, g, s3, s4, s5, s6, s7, s8, s9)
  end subroutine row_pairs

  !> The cone test cos psi >= zeta, i.e. .not. (a < zeta*sqrt(dist2)) with a = d . R_hat
  !> and dist2 = |d|^2, decided without the square root when a^2 and zeta^2 dist2 are
  !> normal numbers differing by more than a relative 1e-12 (their rounding is a few
  !> 1e-16), else by that exact expression: the same cells as the expression alone.
  pure logical function in_cone(a, dist2, zeta, zeta2, quick) result(inside)
    real(dp), intent(in) :: a, dist2, zeta, zeta2
    logical, intent(in) :: quick
    real(dp) :: a2, z2
    if (zeta <= 0.0_dp) then
      if (a >= 0.0_dp) then                                 ! a >= 0 >= zeta |d|
        inside = .true.
        return
      end if
    else if (quick .and. a > 0.0_dp) then
      a2 = a*a
      z2 = zeta2*dist2
      if (a2 >= sq_lo .and. a2 <= sq_hi .and. z2 >= sq_lo .and. z2 <= sq_hi) then
        if (a2 > z2*(1.0_dp + sq_band)) then
          inside = .true.
          return
        else if (a2 < z2*(1.0_dp - sq_band)) then
          inside = .false.
          return
        end if
      end if
    end if
    inside = .not. (a < zeta * sqrt(dist2))
  end function in_cone

  !> Per pair of one row (b = 1..nb; cells u(b) |r_C|(b), spacecraft r): dd = R - r_C,
  !> dist = |d|, omega = area/|d|^2, g = r_C - R in the spacecraft frame, the unit
  !> vector d_hat = (hx, hy, hz) (one division shared by every angle) and the
  !> position angle's unit 2-vector (px, py) (east, north components of u at the
  !> sub-spacecraft point) with its unnormalised east component x and length rho
  !> (rho = 0: the cell at the sub-spacecraft point; px = x = 0, py = 0).
  subroutine pair_vectors(nb, r, frame, east, north, area, uc, rk, dd, dist, omega, g, hx, hy, hz, &
                          px, py, x, rho)
    integer, intent(in) :: nb
    real(dp), intent(in) :: r(3), frame(3, 3), east(3), north(3), area, uc(3, nb), rk(nb)
    real(dp), intent(inout) :: dd(3, nb), dist(nb), omega(nb), g(3, nb)
    real(dp), intent(inout) :: hx(nb), hy(nb), hz(nb), px(nb), py(nb), x(nb), rho(nb)
    real(dp) :: dx, dy, dz, dist2, dst, inv, xe, yn, rr
    integer :: b
    do b = 1, nb
      dx = r(1) - rk(b)*uc(1, b)                              ! notes: d = R_S/C - r_C
      dy = r(2) - rk(b)*uc(2, b)
      dz = r(3) - rk(b)*uc(3, b)
      dist2 = dx*dx + dy*dy + dz*dz
      dst = sqrt(dist2)
      inv = 1.0_dp / dst
      dd(1, b) = dx
      dd(2, b) = dy
      dd(3, b) = dz
      dist(b) = dst
      omega(b) = area * (inv*inv)                          ! notes: Omega = A / |d|^2
      ! r_C - R in the spacecraft frame (note 9)
      g(1, b) = -(frame(1, 1)*dx + frame(2, 1)*dy + frame(3, 1)*dz)
      g(2, b) = -(frame(1, 2)*dx + frame(2, 2)*dy + frame(3, 2)*dz)
      g(3, b) = -(frame(1, 3)*dx + frame(2, 3)*dy + frame(3, 3)*dz)
      hx(b) = dx*inv
      hy(b) = dy*inv
      hz(b) = dz*inv
      ! the cell's direction (east, north) at the sub-spacecraft point (note 5)
      xe = uc(1, b)*east(1) + uc(2, b)*east(2)
      yn = uc(1, b)*north(1) + uc(2, b)*north(2) + uc(3, b)*north(3)
      rr = sqrt(xe*xe + yn*yn)
      inv = 1.0_dp / max(rr, tiny(rr))
      px(b) = xe*inv
      py(b) = yn*inv
      x(b) = xe
      rho(b) = rr
    end do
  end subroutine pair_vectors

  !> The angle outputs of one row, times ascale: zenith angles (a1, a2), emission
  !> (a3), nadir angle (a4), position angle from its 0..pi magnitude a5 and the sign
  !> of the east component x (NaN where rho <= rho_min, the cell within rounding of
  !> the sub-spacecraft point, or over a pole: `polar` false), azimuth (track
  !> bearing - PA; over a pole from the frame coordinates g; NaN where rho <=
  !> rho_min: straight down) and elevation psi - pi/2. Both [0, 2 pi) wraps without branches.
  subroutine store_angles(nb, a1, a2, a3, a4, a5, x, rho, rho_min, polar, track, ascale, g, s3, s4, s5, s6, s7, &
                          s8, s9)
    integer, intent(in) :: nb
    real(dp), intent(in) :: a1(nb), a2(nb), a3(nb), a4(nb), a5(nb), x(nb), rho(nb), rho_min, track, ascale, &
                            g(3, nb)
    logical, intent(in) :: polar
    real(dp), intent(inout) :: s3(nb), s4(nb), s5(nb), s6(nb), s7(nb), s8(nb), s9(nb)
    real(dp) :: pa, az, nan
    integer :: b
    do b = 1, nb
      s3(b) = a1(b) * ascale
      s4(b) = a2(b) * ascale
      s5(b) = a3(b) * ascale
      s6(b) = a4(b) * ascale
      ! elevation: the frame's x axis is R_hat, so el = asin(-d_hat . R_hat) = psi - pi/2
      s9(b) = (a4(b) - pi/2) * ascale
    end do
    if (polar) then
      do b = 1, nb
        pa = wrap_2pi(sign(a5(b), x(b)))                   ! clockwise from north through east (note 5)
        s7(b) = pa * ascale
        ! azimuth from +y (forward) toward +z (left): the horizontal part of r_C - R
        ! is that of r_C, whose bearing is the position angle, so az = (bearing
        ! of the track) - PA (the notes' alpha: track = pi/2 - alpha); track - pa
        ! lies in (-3 pi, pi], hence a second wrap
        az = wrap_2pi(wrap_2pi(track - pa))
        s8(b) = az * ascale
      end do
      nan = nan_dp
      do b = 1, nb
        if (.not. rho(b) > rho_min) then                   ! the cell at the sub-spacecraft point: both
          s7(b) = nan                                      ! directions are rounding noise (a review found
          s8(b) = nan                                      ! PA 0 or 180 deg, azimuths 12-345 deg)
        end if
      end do
    else
      nan = nan_dp
      do b = 1, nb
        s7(b) = nan                                        ! over a pole north is undefined
        s8(b) = wrap_2pi(atan2(g(3, b), g(2, b))) * ascale
      end do
    end if
  end subroutine store_angles

  !> Angles (radians) between the unit vectors (hx, hy, hz)(b) and v(:, b), b = 1..nb.
  subroutine angles_aos(nb, hx, hy, hz, v, ang)
    integer, intent(in) :: nb
    real(dp), intent(in) :: hx(nb), hy(nb), hz(nb), v(3, nb)
    real(dp), intent(inout) :: ang(nb)
    integer :: b
    do b = 1, nb
      ang(b) = chord_angle((hx(b) - v(1, b))**2 + (hy(b) - v(2, b))**2 + (hz(b) - v(3, b))**2, &
                           (hx(b) + v(1, b))**2 + (hy(b) + v(2, b))**2 + (hz(b) + v(3, b))**2)
    end do
  end subroutine angles_aos

  !> Zenith angles z = psi + gamma (radians), b = 1..nb, from the nadir angles psi and
  !> the central angles gamma = asin(rho*icb) of the cells from the sub-spacecraft
  !> point (rho = cos(beta) sin(gamma), icb = 1/cos(beta)); for sin gamma <= 1/2 only
  !> (the caller's bound), where asin is fdlibm's kernel alone [note 16].
  subroutine zenith_sum(nb, psi, rho, icb, z)
    integer, intent(in) :: nb
    real(dp), intent(in) :: psi(nb), rho(nb), icb
    real(dp), intent(inout) :: z(nb)
    real(dp) :: sg, q2
    integer :: b
    do b = 1, nb
      sg = rho(b) * icb
      q2 = sg*sg
      z(b) = psi(b) + (sg + sg*(q2*(ps0 + q2*(ps1 + q2*(ps2 + q2*(ps3 + q2*(ps4 + q2*ps5)))))) / &
                      (1.0_dp + q2*(qs1 + q2*(qs2 + q2*(qs3 + q2*qs4)))))
    end do
  end subroutine zenith_sum

  !> Angles (radians) between the unit vectors (hx, hy, hz)(b) and the unit vector v, b = 1..nb.
  subroutine angles_fixed(nb, hx, hy, hz, v, ang)
    integer, intent(in) :: nb
    real(dp), intent(in) :: hx(nb), hy(nb), hz(nb), v(3)
    real(dp), intent(inout) :: ang(nb)
    integer :: b
    do b = 1, nb
      ang(b) = chord_angle((hx(b) - v(1))**2 + (hy(b) - v(2))**2 + (hz(b) - v(3))**2, &
                           (hx(b) + v(1))**2 + (hy(b) + v(2))**2 + (hz(b) + v(3))**2)
    end do
  end subroutine angles_fixed

  !> Angles (radians, 0..pi) of the unit 2-vectors (px, py)(b) from (0, 1), b = 1..nb.
  subroutine angles_north(nb, px, py, ang)
    integer, intent(in) :: nb
    real(dp), intent(in) :: px(nb), py(nb)
    real(dp), intent(inout) :: ang(nb)
    integer :: b
    do b = 1, nb
      ang(b) = chord_angle((py(b) - 1.0_dp)**2 + px(b)**2, (py(b) + 1.0_dp)**2 + px(b)**2)
    end do
  end subroutine angles_north

  !> [note 15] The angle (0..pi) between two unit vectors from their squared chords
  !> hm = |a - b|^2 and hp = |a + b|^2, with one square root and one division:
  !> below 60 deg 2 asin(t), t = sqrt(hm)/2 < 1/2; beyond 120 deg pi - 2 asin(sqrt(hp)/2);
  !> between them pi/2 - asin(c) with c = a . b = (hp - hm)/4, |c| <= 1/2, where
  !> the cosine is well conditioned (an error e in c moves the angle by at most
  !> 1.16 e). asin from fdlibm's rational kernel, inline instead of libm's asin
  !> and atan2. Accurate near 0 and pi where acos(a . b) is not. The three arms
  !> are computed and blended with 0/1 weights (no branches), so that the
  !> calling loops vectorise without fast-math.
  elemental real(dp) function chord_angle(hm, hp) result(ang)
    real(dp), intent(in) :: hm, hp
    real(dp) :: t, c, z, q2, rr, mid, obtuse
    t = 0.5_dp * sqrt(min(hm, hp))                         ! sin(angle/2) or cos(angle/2)
    c = 0.25_dp * (hp - hm)                                ! cos(angle)
    ! 0/1 weights from sign() rather than merge() on a comparison, which gfortran
    ! (trapping math) compiles to a branch; x*1 + y*0 = x exactly for finite x, y
    mid = 0.5_dp + sign(0.5_dp, t - 0.5_dp)                ! 1 when t >= 1/2: 60..120 deg
    obtuse = 0.5_dp + sign(0.5_dp, hm - hp)                ! 1 when hm > hp (hm - hp = +0 when equal)
    z = (1.0_dp - mid)*t + mid*c
    q2 = z*z
    rr = z + z*(q2*(ps0 + q2*(ps1 + q2*(ps2 + q2*(ps3 + q2*(ps4 + q2*ps5)))))) / &
         (1.0_dp + q2*(qs1 + q2*(qs2 + q2*(qs3 + q2*qs4))))   ! asin z, |z| <= 1/2
    ang = (1.0_dp - mid)*((1.0_dp - obtuse)*(2.0_dp*rr) + obtuse*(pi - 2.0_dp*rr)) &
          + mid*((pio2_hi - rr) + pio2_lo)
  end function chord_angle

  !> An angle in [-2 pi, 2 pi) mapped to [0, 2 pi) (2 pi added to a negative one; a
  !> result that rounds to 2 pi becomes 0), without branches: 0/1 weights from sign().
  elemental real(dp) function wrap_2pi(a) result(w)
    real(dp), intent(in) :: a
    w = a + (2.0_dp*pi)*(0.5_dp - sign(0.5_dp, a))
    w = w - (2.0_dp*pi)*(0.5_dp + sign(0.5_dp, w - 2.0_dp*pi))
  end function wrap_2pi

end module pi_footprint
