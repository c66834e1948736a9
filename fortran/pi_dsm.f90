!> Geodetic digital surface model (Shin & Park): heights above the ellipsoid
!> (a, f) on a regular grid in geodetic latitude and east longitude,
!> pixel-centre registered, and the height lookup the contract prescribes (DESIGN.md section 8; docs/shin-park-notes.md).
!>
!> Grid: hgt(j, i) (Fortran order; Python's heights[i, j]) is the height at
!> latitude lat0 + i*dlat, longitude lon0 + j*dlon (0-based i, j; radians;
!> dlat < 0 for north-up rows, dlon > 0). NaN marks no-data (Python maps a
!> `nodata` value to NaN before the call). Longitudes are modulo 2 pi, taken
!> relative to the grid's centre longitude, so an extent may cross the
!> antimeridian.
!>
!> interp_bilinear: bilinear in (lat, lon) between the four surrounding
!> centres, defined on the closed rectangle of centres. interp_nearest: flat
!> columns over the cells, the larger height on a shared boundary (walls are
!> solid), defined on the rectangle of outer cell edges.
!>
!> The max-pyramid (built by Python, dsm.py) holds for level k >= 1 the
!> maximum of each 2^k x 2^k block of hgt with no-data as +huge; it gives a
!> bound of the surface over any index box in O(1) (pi_dsm_exact).
module pi_dsm
  use pi_kinds, only: dp, i8
  use pi_vector, only: pi
  use pi_ieee, only: nan_dp
  implicit none
  private

  public :: dsm_t, dsm_attach, dsm_height, dsm_grid_uv, dsm_cells, dsm_box_bound, dsm_box_bound_wrapped, &
            dsm_cell_metres, range_max
  public :: interp_bilinear, interp_nearest, pt_ok, pt_outside, pt_nodata
  public :: ulp

  !> interpolation codes
  integer, parameter :: interp_bilinear = 0, interp_nearest = 1
  !> classification of a point by dsm_height: over data, outside the DSM, over no-data
  integer, parameter :: pt_ok = 0, pt_outside = 1, pt_nodata = 2

  !> A DSM grid attached to caller-owned arrays (no copy, no state).
  type :: dsm_t
    !> heights (ncols, nrows), units of a; NaN = no data
    real(dp), pointer, contiguous :: hgt(:, :) => null()
    !> max-pyramid levels 1..nlev packed; meta(:, k) = rows, cols, offset (0-based)
    real(dp), pointer, contiguous :: pyr(:) => null()
    integer, pointer, contiguous :: meta(:, :) => null()
    integer :: ncols = 0, nrows = 0, nlev = 0, interp = interp_bilinear
    !> first centre latitude/longitude, spacings (radians); centre longitude of the grid
    real(dp) :: lat0 = 0, lon0 = 0, dlat = 1, dlon = 1, lonc = 0
    !> ellipsoid
    real(dp) :: a = 1, f = 0, b = 1, e2 = 0
    !> largest |dM/dpsi| of the meridian radius M over latitude, 3 e2 a / (2 (1 - e2)^(3/2))
    !> (pi_dsm_fast's lat_second_bound; a constant of the ellipsoid, here so that the bound
    !> costs no pow per piece: 2 % of a random ray's instructions, callgrind)
    real(dp) :: dmdpsi = 0
    !> largest and smallest data height (H_max may be raised by the caller)
    real(dp) :: hmax = 0, hmin = 0
    !> true when the columns cover 360 degrees (longitude boxes then wrap)
    logical :: global = .false.
    !> rounding slack of a point's grid column u and row v (cells): 8 ulp(pi)/dlon and
    !> 8 ulp(pi)/|dlat|. u comes from a longitude wrapped by a modulo over +-pi, a few ulps
    !> of pi; a point within it outside the grid's edge is on the edge (height_uv,
    !> dsm_box_bound): the DSM's own edge pixel centres came out outside by ~1e-13 cells,
    !> and rays aimed at them were LEFT_DSM (a review)
    real(dp) :: eu = 0, ev = 0
    !> the grid centre's geodetic latitude and longitude (radians, longitude in [-pi, pi)) and
    !> the ellipsoid's unit normal there (ECR): a reference for pi_geodetic's
    !> ecr_to_geodetic_near, which converts points within 0.01 rad of it exactly without
    !> atan2 (pi_dsm_fast's first conversion of a ray; docs/shin-park-notes.md, "Fast exact path")
    real(dp) :: clat = 0, clon = 0, cnx = 1, cny = 0, cnz = 0
    !> dsm_grid_uv wraps longitude into [lonc - pi, lonc + pi): u lies in [uw, uw + uturn), uw the
    !> column coordinate of lonc - pi and uturn = 2 pi/dlon columns (dsm_box_bound_wrapped)
    real(dp) :: uw = 0, uturn = 0
  end type dsm_t

contains

  !> Attach a grid and its pyramid to `dsm` (pointers, no copy).
  !>
  !> Inputs: hgt(ncols, nrows) heights; lat0, lon0, dlat, dlon (radians);
  !> a, f ellipsoid; interp; hmax, hmin; pyr, meta (may be size 1 / 1 level
  !> when the caller does not use dsm_box_max).
  subroutine dsm_attach(hgt, lat0, lon0, dlat, dlon, a, f, interp, hmax, hmin, pyr, meta, dsm)
    real(dp), intent(in), target, contiguous :: hgt(:, :), pyr(:)
    integer, intent(in), target, contiguous :: meta(:, :)
    real(dp), intent(in) :: lat0, lon0, dlat, dlon, a, f, hmax, hmin
    integer, intent(in) :: interp
    type(dsm_t), intent(out) :: dsm
    dsm%hgt => hgt
    dsm%pyr => pyr
    dsm%meta => meta
    dsm%ncols = size(hgt, 1)
    dsm%nrows = size(hgt, 2)
    dsm%nlev = size(meta, 2)
    dsm%lat0 = lat0
    dsm%lon0 = lon0
    dsm%dlat = dlat
    dsm%dlon = dlon
    dsm%lonc = lon0 + 0.5_dp * (dsm%ncols - 1) * dlon
    dsm%a = a
    dsm%f = f
    dsm%b = a * (1.0_dp - f)
    dsm%e2 = f * (2.0_dp - f)
    dsm%dmdpsi = 1.5_dp * dsm%e2 * a / (1.0_dp - dsm%e2)**1.5_dp
    dsm%interp = interp
    dsm%hmax = hmax
    dsm%hmin = hmin
    dsm%global = dsm%ncols * dlon >= 2.0_dp * pi * (1.0_dp - 1.0e-12_dp)
    dsm%eu = 8.0_dp * spacing(pi) / dlon
    dsm%ev = 8.0_dp * spacing(pi) / abs(dlat)
    dsm%clat = lat0 + 0.5_dp * (dsm%nrows - 1) * dlat
    dsm%clon = modulo(dsm%lonc + pi, 2.0_dp * pi) - pi
    dsm%cnx = cos(dsm%clat) * cos(dsm%clon)
    dsm%cny = cos(dsm%clat) * sin(dsm%clon)
    dsm%cnz = sin(dsm%clat)
    dsm%uturn = 2.0_dp * pi / dlon
    dsm%uw = (dsm%lonc - pi - lon0) / dlon
  end subroutine dsm_attach

  !> Continuous grid coordinates of (lat, lon): u = column, v = row (0-based,
  !> centre of cell j at u = j). Longitude is wrapped to within pi of the grid's
  !> centre longitude.
  pure subroutine dsm_grid_uv(dsm, lat, lon, u, v)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: lat, lon
    real(dp), intent(out) :: u, v
    real(dp) :: dl
    dl = lon - dsm%lonc + pi
    ! modulo (a libm fmod) only off [0, 2 pi), where it would return dl unchanged: the same bits
    if (.not. (dl >= 0.0_dp .and. dl < 2.0_dp * pi)) dl = modulo(dl, 2.0_dp * pi)
    dl = dl - pi
    u = (dl + (dsm%lonc - dsm%lon0)) / dsm%dlon
    v = (lat - dsm%lat0) / dsm%dlat
  end subroutine dsm_grid_uv

  !> The DSM surface height H at (lat, lon) (radians) per the contract.
  !>
  !> Output hs: H (units of a), NaN unless code = pt_ok; code: pt_ok,
  !> pt_outside (not over the defined area) or pt_nodata.
  pure subroutine dsm_height(dsm, lat, lon, hs, code)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: lat, lon
    real(dp), intent(out) :: hs
    integer, intent(out) :: code
    real(dp) :: u, v
    call dsm_grid_uv(dsm, lat, lon, u, v)
    call height_uv(dsm, u, v, hs, code)
  end subroutine dsm_height

  !> The cells whose heights decide the surface at grid coordinates (u, v): rows i0..i1, columns
  !> j0..j1 (0-based). Bilinear: the cell between nodes i, i + 1 and j, j + 1 that the interpolation
  !> uses (one). Nearest: the cell holding the point, and on a cell boundary both neighbours (walls
  !> are solid: the larger height); j0 = -1 on a global grid's seam (column ncols - 1 with column 0).
  !> ok = .false. outside the defined area (with the edge slack eu, ev).
  pure subroutine dsm_cells(dsm, u, v, i0, i1, j0, j1, ok)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: u, v
    integer, intent(out) :: i0, i1, j0, j1
    logical, intent(out) :: ok
    real(dp) :: tu, tv, eu, ev
    eu = dsm%eu
    ev = dsm%ev
    i0 = 0; i1 = 0; j0 = 0; j1 = 0
    if (dsm%interp == interp_bilinear) then
      ok = v >= -ev .and. v <= dsm%nrows - 1 + ev .and. u >= -eu .and. u <= dsm%ncols - 1 + eu
      if (.not. ok) return
      i0 = min(int(max(v, 0.0_dp)), dsm%nrows - 2)
      j0 = min(int(max(u, 0.0_dp)), dsm%ncols - 2)
      i1 = i0
      j1 = j0
      return
    end if
    tv = v + 0.5_dp
    tu = u + 0.5_dp
    if (dsm%global) tu = modulo(tu, real(dsm%ncols, dp))
    ok = tv >= -ev .and. tv <= dsm%nrows + ev .and. tu >= -eu .and. tu <= dsm%ncols + eu
    if (.not. ok) return
    tv = min(max(tv, 0.0_dp), real(dsm%nrows, dp))
    tu = min(max(tu, 0.0_dp), real(dsm%ncols, dp))
    i1 = min(int(tv), dsm%nrows - 1)
    i0 = i1
    if (real(i1, dp) == tv .and. i1 >= 1) i0 = i1 - 1          ! on a row boundary: both cells
    if (int(tv) == dsm%nrows) i0 = dsm%nrows - 1
    j1 = min(int(tu), dsm%ncols - 1)
    j0 = j1
    if (real(j1, dp) == tu .and. j1 >= 1) j0 = j1 - 1
    if (int(tu) == dsm%ncols) j0 = dsm%ncols - 1
    if (dsm%global .and. j0 == j1 .and. j0 == 0 .and. tu == 0.0_dp) j0 = -1   ! seam: cell ncols-1 too
  end subroutine dsm_cells

  !> dsm_height at grid coordinates (u, v).
  pure subroutine height_uv(dsm, u, v, hs, code)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: u, v
    real(dp), intent(out) :: hs
    integer, intent(out) :: code
    integer :: i, j, i0, i1, j0, j1, ii, jj
    real(dp) :: fu, fv, h00, h01, h10, h11, w
    logical :: ok
    hs = ieee_nan()
    code = pt_outside
    call dsm_cells(dsm, u, v, i0, i1, j0, j1, ok)
    if (.not. ok) return
    if (dsm%interp == interp_bilinear) then
      i = i0
      j = j0
      fv = min(max(v - i, 0.0_dp), 1.0_dp)
      fu = min(max(u - j, 0.0_dp), 1.0_dp)
      h00 = dsm%hgt(j + 1, i + 1)
      h01 = dsm%hgt(j + 2, i + 1)
      h10 = dsm%hgt(j + 1, i + 2)
      h11 = dsm%hgt(j + 2, i + 2)
      code = pt_nodata
      if (ieee_is_nan(h00) .or. ieee_is_nan(h01) .or. ieee_is_nan(h10) .or. ieee_is_nan(h11)) return
      hs = (1.0_dp - fv) * ((1.0_dp - fu) * h00 + fu * h01) + fv * ((1.0_dp - fu) * h10 + fu * h11)
      code = pt_ok
    else
      code = pt_nodata
      hs = -huge(1.0_dp)
      do ii = i0, i1
        do jj = j0, j1
          w = dsm%hgt(merge(dsm%ncols, jj + 1, jj < 0), ii + 1)         ! (jj = -1: the seam's last column)
          if (ieee_is_nan(w)) then
            hs = ieee_nan()
            return
          end if
          hs = max(hs, w)
        end do
      end do
      code = pt_ok
    end if
  end subroutine height_uv

  !> Upper bound hb of the surface over the part of the grid-coordinate box
  !> [u0, u1] x [v0, v1] that lies over the DSM's defined area (+huge when that
  !> part touches no-data, -huge when it is empty), and out = .true. when some
  !> of the box is outside the defined area. On a global DSM (columns covering
  !> 360 degrees) the column range wraps.
  pure subroutine dsm_box_bound(dsm, u0, u1, v0, v1, hb, out)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: u0, u1, v0, v1
    real(dp), intent(out) :: hb
    logical, intent(out) :: out
    integer :: i0, i1, j0, j1, w
    real(dp) :: e, eu, ev, pw, a0, a1
    hb = huge(1.0_dp)
    out = .true.
    if (.not. (u1 >= u0 .and. v1 >= v0)) return
    eu = dsm%eu
    ev = dsm%ev
    if (dsm%interp == interp_bilinear .and. dsm%global) then
      ! a global bilinear grid comes with its first column repeated after the last (GeodeticDSM's
      ! core grid): its nodes span one turn, u = 0 .. P, P = ncols - 1; the box wrapped into it
      out = v0 < -ev .or. v1 > dsm%nrows - 1 + ev
      hb = -huge(1.0_dp)
      if (v1 < -ev .or. v0 > dsm%nrows - 1 + ev) return
      pw = real(dsm%ncols - 1, dp)
      if (u1 - u0 >= pw) then
        hb = bilinear_part(0.0_dp, pw)
        return
      end if
      w = floor(u0 / pw)
      a0 = u0 - w * pw
      a1 = u1 - w * pw
      if (a1 <= pw) then
        hb = bilinear_part(a0, a1)
      else
        hb = max(bilinear_part(a0, pw), bilinear_part(0.0_dp, a1 - pw))
      end if
      return
    end if
    if (dsm%interp == interp_bilinear) then
      out = v0 < -ev .or. v1 > dsm%nrows - 1 + ev .or. u0 < -eu .or. u1 > dsm%ncols - 1 + eu
      hb = -huge(1.0_dp)
      if (v1 < -ev .or. v0 > dsm%nrows - 1 + ev .or. u1 < -eu .or. u0 > dsm%ncols - 1 + eu) return
      hb = bilinear_part(u0, u1)
    else
      ! cells reach half a cell past the nodes, and the edge slack beyond (a box within it takes
      ! the edge cell, as height_uv does); the cells of the box itself exactly as the callers'
      ! one-cell tests count them (ceiling(v0 - 1/2) .. floor(v1 + 1/2)), clamped to the grid
      e = 0.5_dp
      out = v0 < -e - ev .or. v1 > dsm%nrows - 1 + e + ev
      hb = -huge(1.0_dp)
      if (v1 < -e - ev .or. v0 > dsm%nrows - 1 + e + ev) return
      i0 = min(max(ceiling(v0 - e), 0), dsm%nrows - 1)
      i1 = min(max(floor(v1 + e), 0), dsm%nrows - 1)
      if (dsm%global) then
        if (u1 - u0 >= dsm%ncols - 2) then
          hb = range_max(dsm, i0, i1, 0, dsm%ncols - 1)
          return
        end if
        w = floor((u0 + e) / dsm%ncols)                        ! shift into [-0.5, ncols - 0.5)
        j0 = ceiling(u0 - w * dsm%ncols - e)
        j1 = floor(u1 - w * dsm%ncols + e)
        if (j0 < 0) then
          hb = max(range_max(dsm, i0, i1, 0, j1), range_max(dsm, i0, i1, dsm%ncols + j0, dsm%ncols - 1))
        else if (j1 > dsm%ncols - 1) then
          hb = max(range_max(dsm, i0, i1, j0, dsm%ncols - 1), range_max(dsm, i0, i1, 0, j1 - dsm%ncols))
        else
          hb = range_max(dsm, i0, i1, j0, j1)
        end if
        return
      end if
      out = out .or. u0 < -e - eu .or. u1 > dsm%ncols - 1 + e + eu
      if (u1 < -e - eu .or. u0 > dsm%ncols - 1 + e + eu) return
      j0 = min(max(ceiling(u0 - e), 0), dsm%ncols - 1)
      j1 = min(max(floor(u1 + e), 0), dsm%ncols - 1)
      hb = range_max(dsm, i0, i1, j0, j1)
    end if
  contains
    !> The bilinear surface's bound over [b0, b1] x [v0, v1] (within the grid's
    !> nodes, or beyond them by the edge slack at most: clipped to the edge line):
    !> for a few cells the surface's own maximum over the box (a bilinear
    !> function on a rectangle peaks at one of its corners), else the pyramid's.
    pure function bilinear_part(b0, b1) result(hp)
      real(dp), intent(in) :: b0, b1
      real(dp) :: hp
      integer :: k0, k1, l0, l1
      k0 = min(int(max(v0, 0.0_dp)), dsm%nrows - 1)
      k1 = min(ceiling(min(v1, real(dsm%nrows - 1, dp))), dsm%nrows - 1)
      l0 = min(int(max(b0, 0.0_dp)), dsm%ncols - 1)
      l1 = min(ceiling(min(b1, real(dsm%ncols - 1, dp))), dsm%ncols - 1)
      if (k1 - k0 <= 2 .and. l1 - l0 <= 2) then
        hp = bilinear_box_max(dsm, min(max(b0, 0.0_dp), real(dsm%ncols - 1, dp)), &
                              max(min(b1, real(dsm%ncols - 1, dp)), 0.0_dp), &
                              min(max(v0, 0.0_dp), real(dsm%nrows - 1, dp)), &
                              max(min(v1, real(dsm%nrows - 1, dp)), 0.0_dp), k0, k1, l0, l1)
      else
        hp = range_max(dsm, k0, k1, l0, l1)
      end if
    end function bilinear_part
  end subroutine dsm_box_bound

  !> dsm_box_bound for a box whose column range [u0, u1] was unwrapped from one point's u (a
  !> segment's longitudes: u0 <= u1, less than a turn wide). dsm_grid_uv wraps longitude to within
  !> pi of the grid's centre (u in [uw, uw + T), dsm_t's uw and T = uturn), so on a
  !> regional grid the part of the box past uw + T lies at u - T (and the part before uw at u + T):
  !> both parts are bounded (hb the larger, out if either is partly outside). A global grid's box
  !> wraps in dsm_box_bound itself. A segment across the wrap meridian (a regional grid spanning
  !> nearly 360 degrees: a polar cap short of a full ring) had only its first part bounded, and a
  !> ray crossing the gap into the grid's other edge was answered late or LEFT_DSM (a review:
  !> 123 m late on a 350-degree wedge; docs/shin-park-notes.md, "Sixth look").
  pure subroutine dsm_box_bound_wrapped(dsm, u0, u1, v0, v1, hb, out)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: u0, u1, v0, v1
    real(dp), intent(out) :: hb
    logical, intent(out) :: out
    real(dp) :: uw, turn, hb2
    logical :: out2
    if (dsm%global) then
      call dsm_box_bound(dsm, u0, u1, v0, v1, hb, out)
      return
    end if
    turn = dsm%uturn
    uw = dsm%uw
    if (u1 > uw + turn .and. u0 < uw + turn) then
      call dsm_box_bound(dsm, u0, uw + turn, v0, v1, hb, out)
      call dsm_box_bound(dsm, uw, u1 - turn, v0, v1, hb2, out2)
    else if (u0 < uw .and. u1 > uw) then
      call dsm_box_bound(dsm, uw, u1, v0, v1, hb, out)
      call dsm_box_bound(dsm, u0 + turn, uw + turn, v0, v1, hb2, out2)
    else if (u0 >= uw + turn) then
      call dsm_box_bound(dsm, u0 - turn, u1 - turn, v0, v1, hb, out)
      return
    else if (u1 <= uw) then
      call dsm_box_bound(dsm, u0 + turn, u1 + turn, v0, v1, hb, out)
      return
    else
      call dsm_box_bound(dsm, u0, u1, v0, v1, hb, out)
      return
    end if
    hb = max(hb, hb2)
    out = out .or. out2
  end subroutine dsm_box_bound_wrapped

  !> Maximum of the bilinear surface over [u0, u1] x [v0, v1] (inside the grid),
  !> whose node range is rows i0..i1, columns j0..j1: per cell, the largest of
  !> the surface at the corners of the box's part in that cell (+huge on no-data).
  pure function bilinear_box_max(dsm, u0, u1, v0, v1, i0, i1, j0, j1) result(hb)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: u0, u1, v0, v1
    integer, intent(in) :: i0, i1, j0, j1
    real(dp) :: hb, h00, h01, h10, h11, a0, a1, b0, b1, fu, fv
    integer :: ci, cj, ka, kb
    hb = -huge(1.0_dp)
    do ci = i0, max(i0, i1 - 1)
      do cj = j0, max(j0, j1 - 1)
        if (ci + 1 > dsm%nrows - 1 .or. cj + 1 > dsm%ncols - 1) then   ! a degenerate box on the last node line
          h00 = dsm%hgt(cj + 1, ci + 1)
          if (ieee_is_nan(h00)) then
            hb = huge(1.0_dp)
            return
          end if
          hb = max(hb, range_max(dsm, ci, min(ci + 1, dsm%nrows - 1), cj, min(cj + 1, dsm%ncols - 1)))
          cycle
        end if
        h00 = dsm%hgt(cj + 1, ci + 1)
        h01 = dsm%hgt(cj + 2, ci + 1)
        h10 = dsm%hgt(cj + 1, ci + 2)
        h11 = dsm%hgt(cj + 2, ci + 2)
        if (ieee_is_nan(h00) .or. ieee_is_nan(h01) .or. ieee_is_nan(h10) .or. ieee_is_nan(h11)) then
          hb = huge(1.0_dp)
          return
        end if
        a0 = max(v0, real(ci, dp)) - ci
        a1 = min(v1, real(ci + 1, dp)) - ci
        b0 = max(u0, real(cj, dp)) - cj
        b1 = min(u1, real(cj + 1, dp)) - cj
        if (a1 < a0 .or. b1 < b0) cycle
        do ka = 0, 1
          fv = merge(a0, a1, ka == 0)
          do kb = 0, 1
            fu = merge(b0, b1, kb == 0)
            hb = max(hb, (1.0_dp - fv) * ((1.0_dp - fu) * h00 + fu * h01) + fv * ((1.0_dp - fu) * h10 + fu * h11))
          end do
        end do
      end do
    end do
    ! rounding of the interpolation: never below the computed values by more than a few ulps
    hb = hb + 4.0_dp * ulp(max(abs(hb), 1.0_dp))
  end function bilinear_box_max

  !> Largest height over rows i0..i1, columns j0..j1 (0-based, inclusive,
  !> inside the grid), no-data as +huge: at most 2 x 2 blocks of one pyramid
  !> level, read without loops (the same values as a loop over the range: a
  !> corner read twice when the range is one block wide changes no maximum).
  pure function range_max(dsm, i0, i1, j0, j1) result(hb)
    type(dsm_t), intent(in) :: dsm
    integer, intent(in) :: i0, i1, j0, j1
    real(dp) :: hb, w1, w2, w3, w4
    integer :: span, k, bi0, bi1, bj0, bj1, off, nr, nc
    hb = -huge(1.0_dp)
    if (i1 < i0 .or. j1 < j0) return
    span = max(i1 - i0, j1 - j0)
    if (span <= 1) then                                ! at most 2 x 2 cells: read them
      w1 = dsm%hgt(j0 + 1, i0 + 1)
      w2 = dsm%hgt(j1 + 1, i0 + 1)
      w3 = dsm%hgt(j0 + 1, i1 + 1)
      w4 = dsm%hgt(j1 + 1, i1 + 1)
      if (ieee_is_nan(w1) .or. ieee_is_nan(w2) .or. ieee_is_nan(w3) .or. ieee_is_nan(w4)) then
        hb = huge(1.0_dp)
      else
        hb = max(max(w1, w2), max(w3, w4))
      end if
      return
    end if
    k = bit_size(span) - leadz(span)                   ! 2^k > span: the range touches <= 2 blocks per axis
    k = min(k, dsm%nlev)
    nr = dsm%meta(1, k)
    nc = dsm%meta(2, k)
    off = dsm%meta(3, k) + 1
    bi0 = ishft(i0, -k)
    bi1 = min(ishft(i1, -k), nr - 1)
    bj0 = ishft(j0, -k)
    bj1 = min(ishft(j1, -k), nc - 1)
    hb = max(max(dsm%pyr(off + bi0 * nc + bj0), dsm%pyr(off + bi0 * nc + bj1)), &
             max(dsm%pyr(off + bi1 * nc + bj0), dsm%pyr(off + bi1 * nc + bj1)))
  end function range_max

  !> Cell sides in metres (units of a) at geodetic latitude lat: the meridian
  !> arc of |dlat| and the parallel arc of dlon on the ellipsoid.
  pure subroutine dsm_cell_metres(dsm, lat, dy, dx)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: lat
    real(dp), intent(out) :: dy, dx
    real(dp) :: w, nn, mm
    w = 1.0_dp - dsm%e2 * sin(lat)**2
    nn = dsm%a / sqrt(w)
    mm = dsm%a * (1.0_dp - dsm%e2) / (w * sqrt(w))
    dy = mm * abs(dsm%dlat)
    dx = nn * cos(lat) * dsm%dlon
  end subroutine dsm_cell_metres

  !> spacing(x) for x >= 1, read off x's exponent bits (the same value; gfortran's spacing calls
  !> frexp and ldexp, ~70 instructions, on most bilinear box bounds: 3.7 % of a random ray's
  !> instructions, callgrind; docs/shin-park-notes.md, "Twelfth look"). Infinity and NaN:
  !> spacing's own answer.
  elemental function ulp(x) result(s)
    real(dp), intent(in) :: x
    real(dp) :: s
    integer(i8) :: e
    e = iand(ishft(transfer(x, 0_i8), -52), 2047_i8)   ! biased exponent: x in [2^(e-1023), 2^(e-1022))
    if (e > 52_i8 .and. e < 2047_i8) then
      s = transfer(ishft(e - 52_i8, 52), 1.0_dp)         ! 2^(e - 1023 - 52), a normal number
    else
      s = spacing(x)
    end if
  end function ulp

  pure function ieee_nan() result(x)
    real(dp) :: x
    x = nan_dp
  end function ieee_nan

  !> x is NaN (pi_ieee's is_nan, here so that the compiler inlines it: a call
  !> into another module goes through the shared library's PLT on every cell)
  elemental function ieee_is_nan(x) result(nan)
    real(dp), intent(in) :: x
    logical :: nan
    nan = x /= x
  end function ieee_is_nan

end module pi_dsm
