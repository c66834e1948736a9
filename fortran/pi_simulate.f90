!> Image simulation (Shin & Park section 4): what a simulated pixel shows once
!> its ray's first hit on the DSM is known — the ortho-image value there, the
!> kind of surface hit, the local incidence angle, wall texture and Lambertian
!> shading. The choices are the numbered notes of docs/simulation-notes.md
!> ([sim note N] below); python/planet_intersect/simulate.py documents the
!> same rules for the caller.
!>
!> Frames and units: hit latitudes/longitudes geodetic, radians; heights in the
!> DSM's units above its ellipsoid; ray directions unit vectors in ECR.
!> Grids: the DSM's (pi_dsm, hgt(col, row)); the ortho-image's values
!> ortho(band, col, row) on its own pixel-centre grid (olat0, olon0, odlat,
!> odlon, radians), NaN = no data; the ground grid has the DSM's shape.
module pi_simulate
  use pi_kinds, only: dp, sp, i1
  use pi_dsm, only: dsm_t, dsm_height, dsm_grid_uv, interp_nearest, pt_ok
  use pi_vector, only: pi, deg
  use pi_ieee, only: nan_dp, ieee_is_finite => is_finite, ieee_is_nan => is_nan
  !$ use omp_lib, only: omp_get_max_threads
  implicit none
  private

  public :: ortho_t, sim_options_t, sim_shade, ortho_sample
  public :: walls_interpolate, walls_ortho, shading_none, shading_lambert, sun_azel, sun_ecr
  public :: kind_none, kind_ground, kind_roof, kind_wall

  !> wall texture: interpolated in height [sim note 2], or the plain ortho value
  integer, parameter :: walls_interpolate = 0, walls_ortho = 1
  !> shading: none, Lambertian [sim note 4]; the Sun as (azimuth, elevation) at each hit, or one ECR vector
  integer, parameter :: shading_none = 0, shading_lambert = 1, sun_azel = 0, sun_ecr = 1
  !> surface kinds (DESIGN.md section 9)
  integer, parameter :: kind_none = -1, kind_ground = 0, kind_roof = 1, kind_wall = 2

  !> Points within ortho_edge_tol pixels outside the ortho-image's rectangle of
  !> pixel centres are taken on its edge: a hit on a grid shared with the DSM
  !> lands on a border pixel's centre to rounding (~3e-9 pixels), and was a
  !> value-less pixel (a review found 166 of 236 border pixels at fill).
  real(dp), parameter :: ortho_edge_tol = 1.0e-6_dp

  !> An ortho-image attached to caller-owned values (no copy, no state).
  type :: ortho_t
    !> values(band, col, row); NaN = no data
    real(dp), pointer, contiguous :: v(:, :, :) => null()
    integer :: nb = 1, ncols = 0, nrows = 0
    !> first centre latitude/longitude, spacings, centre longitude (radians)
    real(dp) :: lat0 = 0, lon0 = 0, dlat = 1, dlon = 1, lonc = 0
  end type ortho_t

  !> The options of a simulation (simulate_image's arguments).
  type :: sim_options_t
    integer :: walls = walls_interpolate, shading = shading_none, sun_mode = sun_azel
    !> sun: (azimuth, elevation) in radians in sun(1:2), or an ECR unit vector
    real(dp) :: sun(3) = 0, ambient = 0, cos_wall = 0.5_dp, roof_min = 2, fill = 0
    !> metres per DSM cell north-south and east-west (scene middle), for the wall samples
    real(dp) :: cell_y = 1, cell_x = 1
  end type sim_options_t

contains

  !> Bilinear value of the ortho-image at (lat, lon) (radians), every band, between
  !> pixel centres; over the image's outer half pixel (its pixels are areas: a raster's
  !> bounds lie half a pixel beyond its outer centres) the edge pixels' values,
  !> interpolated along the edge [sim note 8]. NaN beyond the image's bounds (widened by
  !> ortho_edge_tol) or where a needed pixel is NaN; a neighbour within ortho_edge_tol
  !> of no weight is not needed (a no-data pixel 3e-10 pixel away made a hit at a valid
  !> centre NaN, and the outer half pixel of every ortho-image was fill: a review).
  pure subroutine ortho_sample(o, lat, lon, val)
    type(ortho_t), intent(in) :: o
    real(dp), intent(in) :: lat, lon
    real(dp), intent(out) :: val(o%nb)
    real(dp) :: u, v, fu, fv, dl, e, val0(o%nb)
    integer :: i, j, i1, j1
    if (abs(lon - o%lonc) <= pi) then
      v = (lon - o%lon0) / o%dlon                   ! column; exact at the pixel centres
    else
      dl = modulo(lon - o%lonc + pi, 2.0_dp * pi) - pi
      v = (dl + (o%lonc - o%lon0)) / o%dlon
    end if
    u = (lat - o%lat0) / o%dlat                     ! row
    e = 0.5_dp + ortho_edge_tol
    if (.not. (u >= -e .and. u <= o%nrows - 1 + e .and. v >= -e .and. v <= o%ncols - 1 + e)) then
      val = nan_dp
      return
    end if
    u = min(max(u, 0.0_dp), real(o%nrows - 1, dp))
    v = min(max(v, 0.0_dp), real(o%ncols - 1, dp))
    i = min(int(u), max(o%nrows - 2, 0))
    j = min(int(v), max(o%ncols - 2, 0))
    fu = u - i
    fv = v - j
    i1 = min(i + 1, o%nrows - 1)
    j1 = min(j + 1, o%ncols - 1)
    val = (1 - fu) * ((1 - fv) * o%v(:, j + 1, i + 1) + fv * o%v(:, j1 + 1, i + 1)) &
          + fu * ((1 - fv) * o%v(:, j + 1, i1 + 1) + fv * o%v(:, j1 + 1, i1 + 1))
    if (.not. any(ieee_is_nan(val))) return
    val0 = val
    ! a no-data pixel among the four: not needed when its weight is below ortho_edge_tol (then the
    ! hit is on the other row or column to rounding; values with data are not moved by this)
    if (fu >= 1.0_dp - ortho_edge_tol) then
      i = i1
      fu = 0.0_dp
    else if (fu <= ortho_edge_tol) then
      fu = 0.0_dp
    end if
    if (fv >= 1.0_dp - ortho_edge_tol) then
      j = j1
      fv = 0.0_dp
    else if (fv <= ortho_edge_tol) then
      fv = 0.0_dp
    end if
    if (fu == 0.0_dp) i1 = i
    if (fv == 0.0_dp) j1 = j
    val = (1 - fu) * ((1 - fv) * o%v(:, j + 1, i + 1) + fv * o%v(:, j1 + 1, i + 1)) &
          + fu * ((1 - fv) * o%v(:, j + 1, i1 + 1) + fv * o%v(:, j1 + 1, i1 + 1))
    val = merge(val, val0, ieee_is_nan(val0))                ! (bands with data keep their value)
  end subroutine ortho_sample

  !> Bilinear value of a grid shaped like the DSM at grid coordinates (u col,
  !> v row); NaN outside the rectangle of centres.
  pure function grid_bilinear(g, u, v) result(val)
    real(dp), intent(in) :: g(:, :), u, v
    real(dp) :: val, fu, fv
    integer :: i, j, i1, j1, nc, nr
    nc = size(g, 1)
    nr = size(g, 2)
    if (.not. (v >= 0.0_dp .and. v <= nr - 1 .and. u >= 0.0_dp .and. u <= nc - 1)) then
      val = nan_dp
      return
    end if
    i = min(int(v), max(nr - 2, 0))
    j = min(int(u), max(nc - 2, 0))
    fv = v - i
    fu = u - j
    i1 = min(i + 1, nr - 1)
    j1 = min(j + 1, nc - 1)
    val = (1 - fv) * ((1 - fu) * g(j + 1, i + 1) + fu * g(j1 + 1, i + 1)) &
          + fv * ((1 - fu) * g(j + 1, i1 + 1) + fu * g(j1 + 1, i1 + 1))
  end function grid_bilinear

  !> The DSM's slope at a hit, (dH/d east, dH/d north) in m/m [sim note 1]:
  !> "bilinear": the gradient of the bilinear patch at the hit; "nearest": the
  !> step across the cell side the hit lies on (u or v within 1e-6 of a
  !> half-integer) per cell width, zero on a flat top [sim note 3].
  !> my, mx: metres per radian of latitude and longitude at the hit.
  pure subroutine dsm_gradient(dsm, u, v, my, mx, gx, gy)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: u, v, my, mx
    real(dp), intent(out) :: gx, gy
    real(dp) :: dhdu, dhdv, fu, fv, step
    integer :: nc, nr, i, j, i1, j1, lo, hi, ic, jc
    nc = dsm%ncols
    nr = dsm%nrows
    if (dsm%interp /= interp_nearest) then
      i = min(max(floor(v), 0), max(nr - 2, 0))
      j = min(max(floor(u), 0), max(nc - 2, 0))
      fv = min(max(v - i, 0.0_dp), 1.0_dp)
      fu = min(max(u - j, 0.0_dp), 1.0_dp)
      i1 = min(i + 1, nr - 1)
      j1 = min(j + 1, nc - 1)
      ! d/d(row) and d/d(column) of the bilinear patch
      dhdv = (1 - fu) * (dsm%hgt(j + 1, i1 + 1) - dsm%hgt(j + 1, i + 1)) &
             + fu * (dsm%hgt(j1 + 1, i1 + 1) - dsm%hgt(j1 + 1, i + 1))
      dhdu = (1 - fv) * (dsm%hgt(j1 + 1, i + 1) - dsm%hgt(j + 1, i + 1)) &
             + fv * (dsm%hgt(j1 + 1, i1 + 1) - dsm%hgt(j + 1, i1 + 1))
    else
      dhdu = 0.0_dp
      dhdv = 0.0_dp
      ic = min(max(nint(v), 0), nr - 1)
      jc = min(max(nint(u), 0), nc - 1)
      if (abs(v - floor(v) - 0.5_dp) < 1.0e-6_dp) then        ! on a north/south side
        lo = min(max(floor(v), 0), nr - 1)
        hi = min(lo + 1, nr - 1)
        step = dsm%hgt(jc + 1, hi + 1) - dsm%hgt(jc + 1, lo + 1)
        if (ieee_is_finite(step)) dhdv = step
      end if
      if (abs(u - floor(u) - 0.5_dp) < 1.0e-6_dp) then        ! on an east/west side
        lo = min(max(floor(u), 0), nc - 1)
        hi = min(lo + 1, nc - 1)
        step = dsm%hgt(hi + 1, ic + 1) - dsm%hgt(lo + 1, ic + 1)
        if (ieee_is_finite(step)) dhdu = step
      end if
    end if
    gy = dhdv / (dsm%dlat * my)          ! per metre north (the sign of dlat included)
    gx = dhdu / (dsm%dlon * mx)          ! per metre east
  end subroutine dsm_gradient

  !> Value, surface kind and local incidence of n simulated pixels from their
  !> rays' hits, and the pixels' backplanes, written into the caller's arrays
  !> (one pass, OpenMP over pixels; results identical for any thread count).
  !>
  !> Inputs: dsm, gnd (bare-earth heights on the DSM grid, NaN = unknown), o
  !> (ortho-image), opt; hits(ns, n), ns >= 6, the rays' hits as
  !> pi_dsm_exact's dsm_trace_packed returns them in scal (rows: lat, lon in
  !> radians, h the geodetic height of the hit, H the DSM height there, above
  !> h on a "nearest" cell side, the distance along the ray, the incidence
  !> angle in radians; read in place: no copy of the rows), p(3, n) the hit
  !> points (ECR), hit (1 where the ray hit), l(3, n) ray directions (ECR, any
  !> non-zero length); threads (0: all).
  !> Outputs (every element written): img(nb, n) the pixel values in single
  !> precision (opt%fill where not hit or NaN), kind(n) (kind_* codes),
  !> locinc(n) the angle between -l and the surface normal used (degrees),
  !> lat(n), lon(n) (degrees; lon as atan2 gives it, which the caller
  !> wraps into [-180, 180) where it is off by rounding), hgt(n), dist(n),
  !> inc(n) (degrees), pts(3, n) copied from hits and p, all NaN where not hit;
  !> oval(n) 1 where the ray hit and the ortho-image had a value there, else 0.
  !> (Before, Python converted and copied these from the trace's rows after
  !> the call, serially: ~20 % of a one-thread simulation; simulation note 13.)
  subroutine sim_shade(dsm, gnd, o, opt, ns, n, hits, p, hit, l, threads, img, kind, locinc, lat, lon, hgt, &
                       dist, inc, pts, oval)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: gnd(:, :)
    type(ortho_t), intent(in) :: o
    type(sim_options_t), intent(in) :: opt
    integer, intent(in) :: ns, n, hit(n), threads
    real(dp), intent(in) :: hits(ns, n), p(3, n), l(3, n)
    real(sp), intent(out) :: img(o%nb, n)
    integer(i1), intent(out) :: kind(n), oval(n)
    real(dp), intent(out) :: locinc(n), lat(n), lon(n), hgt(n), dist(n), inc(n), pts(3, n)
    integer :: k, nth, kk, noval
    real(dp) :: li
    real(dp), allocatable :: vw(:)
    nth = 1
    !$ nth = threads
    !$ if (nth <= 0) nth = omp_get_max_threads()
    ! (vw: one pixel's values, each thread's own, allocated once: an automatic array in the loop
    ! was a malloc and free per pixel)
    !$omp parallel num_threads(nth) default(shared) private(k, kk, noval, li, vw)
    allocate(vw(o%nb))
    !$omp do schedule(static, 256)
    do k = 1, n
      if (hit(k) /= 1) then
        img(:, k) = real(opt%fill, sp)
        kind(k) = int(kind_none, i1)
        oval(k) = 0_i1
        locinc(k) = nan_dp
        lat(k) = nan_dp
        lon(k) = nan_dp
        hgt(k) = nan_dp
        dist(k) = nan_dp
        inc(k) = nan_dp
        pts(:, k) = nan_dp
      else
        call shade_one(dsm, gnd, o, opt, hits(1, k), hits(2, k), hits(3, k), hits(4, k), p(:, k), l(:, k), vw, &
                       kk, li, noval)
        img(:, k) = real(vw, sp)
        kind(k) = int(kk, i1)
        oval(k) = int(1 - noval, i1)
        locinc(k) = li * deg
        lat(k) = hits(1, k) * deg
        ! (not wrapped here: a hit within ulps of the antimeridian can be a few ulps beyond +-180,
        ! and the caller wraps those with pi.intersect's own arithmetic, so that the two agree to
        ! the bit; an exact x -+ 360 here differed from it on 3 of 3,600 pixels of a review's scene)
        lon(k) = hits(2, k) * deg
        hgt(k) = hits(3, k)
        dist(k) = hits(5, k)
        inc(k) = hits(6, k) * deg
        pts(:, k) = p(:, k)
      end if
    end do
    !$omp end do
    deallocate(vw)
    !$omp end parallel
  end subroutine sim_shade

  !> One pixel of sim_shade.
  pure subroutine shade_one(dsm, gnd, o, opt, lat, lon, h, hsurf, p, l, val, kind, locinc, noval)
    type(dsm_t), intent(in) :: dsm
    real(dp), intent(in) :: gnd(:, :)
    type(ortho_t), intent(in) :: o
    type(sim_options_t), intent(in) :: opt
    real(dp), intent(in) :: lat, lon, h, hsurf, p(3), l(3)
    real(dp), intent(out) :: val(o%nb), locinc
    integer, intent(out) :: kind, noval
    real(dp) :: sl, cl, so, co, e(3), nv(3), up(3), w, my, mx, u, v, gx, gy, g2, gn, nrm(3)
    real(dp) :: cosi, ground, sun(3), fac, az, el, lu(3), rho
    logical :: wall
    lu = l / sqrt(sum(l * l))                        ! any length: the caller's directions
    sl = sin(lat)
    cl = cos(lat)
    ! cos and sin of the longitude from the hit point p, whose longitude it is (to rounding), instead
    ! of a second sincos (~2 % of a simulation's time); within ~1e-150 of the polar axis, where the
    ! squares lose precision (x/rho was 1.125 at x = 2.5e-162 m: a review) or p has no longitude,
    ! from lon
    rho = p(1) * p(1) + p(2) * p(2)
    if (rho >= 1.0e-300_dp) then
      rho = sqrt(rho)
      co = p(1) / rho
      so = p(2) / rho
    else
      so = sin(lon)
      co = cos(lon)
    end if
    e = [-so, co, 0.0_dp]
    nv = [-sl * co, -sl * so, cl]
    up = [cl * co, cl * so, sl]
    ! metres per radian of latitude (M + h) and of longitude ((N + h) cos lat)
    w = sqrt(1.0_dp - dsm%e2 * sl * sl)
    my = dsm%a * (1.0_dp - dsm%e2) / w**3 + h
    mx = (dsm%a / w + h) * cl
    call dsm_grid_uv(dsm, lat, lon, u, v)
    call dsm_gradient(dsm, u, v, my, mx, gx, gy)
    g2 = gx * gx + gy * gy
    ! steeper than wall_slope <=> cos(slope) = 1/sqrt(1 + g^2) < cos(wall_slope)  [sim note 1]
    wall = 1.0_dp / sqrt(1.0_dp + g2) < opt%cos_wall
    if (dsm%interp == interp_nearest) wall = wall .and. (hsurf - h > 1.0e-6_dp)      ! [sim note 3]
    gn = 1.0_dp
    if (wall) then
      gn = sqrt(max(g2, 1.0e-300_dp))
      nrm = -(gx / gn) * e - (gy / gn) * nv          ! outward horizontal: downhill
    else if (dsm%interp == interp_nearest) then
      nrm = up                                       ! flat tops
    else
      nrm = -gx * e - gy * nv + up
      nrm = nrm / sqrt(sum(nrm * nrm))
    end if
    cosi = min(max(-sum(lu * nrm), -1.0_dp), 1.0_dp)
    locinc = acos(cosi)
    ground = grid_bilinear(gnd, u, v)
    if (wall) then
      kind = kind_wall
    else if (ieee_is_nan(ground)) then
      ! the ground unknown: not a roof. (This was "h - ground > roof_min", false for a NaN, but an
      ! ordered comparison with a NaN raises IEEE invalid, which the runtime-checked build's fuzz
      ! worker traps: CI, 2026-12-03.)
      kind = kind_ground
    else if (h - ground > opt%roof_min) then
      kind = kind_roof
    else
      kind = kind_ground
    end if
    call ortho_sample(o, lat, lon, val)
    if (wall .and. opt%walls == walls_interpolate) call wall_value(dsm, o, opt, lat, lon, h, gx / gn, gy / gn, &
                                                                   my, mx, val)
    if (opt%shading == shading_lambert) then
      if (opt%sun_mode == sun_azel) then
        az = opt%sun(1)
        el = opt%sun(2)
        sun = cos(el) * (sin(az) * e + cos(az) * nv) + sin(el) * up
      else
        sun = opt%sun
      end if
      fac = opt%ambient + (1.0_dp - opt%ambient) * max(0.0_dp, sum(nrm * sun))
      val = val * fac
    end if
    noval = 0
    if (.not. all(ieee_is_finite(val))) noval = 1          ! no ortho value at the hit: said, not hidden
    where (.not. ieee_is_finite(val)) val = opt%fill
  end subroutine shade_one

  !> Wall texture [sim note 2]: linear in height between the ortho value at the
  !> roof edge (one sample inside the building, against the outward normal) and
  !> at the wall's foot (one sample outside); half a cell for "nearest", one
  !> cell for "bilinear". A sample off the ortho-image: the other one, then
  !> the plain value `val` (input) at the hit.
  pure subroutine wall_value(dsm, o, opt, lat, lon, h, dx, dy, my, mx, val)
    type(dsm_t), intent(in) :: dsm
    type(ortho_t), intent(in) :: o
    type(sim_options_t), intent(in) :: opt
    real(dp), intent(in) :: lat, lon, h, dx, dy, my, mx
    real(dp), intent(inout) :: val(o%nb)
    real(dp) :: step_m, cell_m, h_top, h_foot, t, v_top(o%nb), v_foot(o%nb), mix(o%nb), lat_in, lon_in
    real(dp) :: lat_out, lon_out
    integer :: code, b
    cell_m = abs(dx) * opt%cell_x + abs(dy) * opt%cell_y
    step_m = merge(0.5_dp, 1.0_dp, dsm%interp == interp_nearest) * max(cell_m, 1.0e-9_dp)
    lat_in = lat + dy * step_m / my
    lon_in = lon + dx * step_m / mx
    lat_out = lat - dy * step_m / my
    lon_out = lon - dx * step_m / mx
    call dsm_height(dsm, lat_in, lon_in, h_top, code)
    call dsm_height(dsm, lat_out, lon_out, h_foot, code)
    call ortho_sample(o, lat_in, lon_in, v_top)
    call ortho_sample(o, lat_out, lon_out, v_foot)
    t = (h - h_foot) / (h_top - h_foot)
    if (ieee_is_finite(t)) then
      t = min(max(t, 0.0_dp), 1.0_dp)
    else
      t = 0.5_dp
    end if
    mix = (1 - t) * v_foot + t * v_top
    do b = 1, o%nb
      if (ieee_is_finite(mix(b))) then
        val(b) = mix(b)
      else if (ieee_is_finite(v_top(b))) then
        val(b) = v_top(b)
      else if (ieee_is_finite(v_foot(b))) then
        val(b) = v_foot(b)
      end if
    end do
  end subroutine wall_value

end module pi_simulate
