!> A speed bound for any cell-walking first-hit search on a geodetic DSM; a benchmark
!> probe, NOT part of the package and NOT sound.
!>
!> What it computes
!>   For each ray: the two distances where it crosses the ellipsoids raised by the grid's
!>   highest and lowest heights (a + H, b + H: a closed-form quadric, not the geodetic
!>   height surface), the geodetic (row, column, height) of those two points, and then a
!>   walk along the straight track between them in (row, column, height): a max over
!>   bsz x bsz cell blocks first, each block whose max is not below the track's height at
!>   its exit walked cell by cell, each such cell solved in closed form for the bilinear
!>   surface along the straight track. The first root is the answer.
!>
!> Why it is a bound and not an answer
!>   It leaves out everything that makes the package's exact mode exact: the track is not
!>   straight in (row, column, height) (its curvature is millimetres over a 600 m slab), no
!>   bound carries a rounding margin, the cell solve is not refined on the true ray, and
!>   nothing handles nadir rays, no-data, walls ("nearest") or global grids (cells outside
!>   the grid count as empty). Any sound cell walk does at least this much work per ray, so
!>   its speed bounds what such a design could reach (docs/shin-park-notes.md, "Fifteenth look").
!>
!> Conversions (argument conv)
!>   0: the exact closed form of Heikkinen (1982), with its cube root, square roots and
!>      arc tangents, about as costly as the package's exact conversion;
!>   1: a cubic polynomial in the point's offset from cen (km), 20 terms for each of row,
!>      column and height, fitted by the driver over the scene's box (the driver measures its
!>      error): the cost of a conversion a regional DSM could precompute.
module cell_walk_bound
   use, intrinsic :: iso_c_binding, only: c_int, c_double, c_float
   implicit none
   private
   public :: walk_prepare, walk_trace

   integer, parameter :: dp = c_double
   real(dp), parameter :: rad2deg = 57.295779513082320876798_dp

   interface
      !> C's cube root (Fortran has none; x**(1/3) calls pow, ~2x the time)
      pure real(c_double) function cbrt(x) bind(c, name="cbrt")
         import :: c_double
         real(c_double), value, intent(in) :: x
      end function cbrt
   end interface

contains

   !> Cell maxima (max of each cell's four nodes, rounded up to single precision), block maxima
   !> (max over bsz x bsz cells) and superblock maxima (over 4 x 4 blocks). h(0:nc-1, 0:nr-1) is a C-ordered (nr, nc) array:
   !> h(j, i) is row i, column j.
   subroutine walk_prepare(nr, nc, h, bsz, nbr, nbc, cmax, bmax, nsr, nsc, smax) bind(c, name="walk_prepare")
      integer(c_int), value, intent(in) :: nr, nc, bsz, nbr, nbc, nsr, nsc
      real(c_double), intent(in) :: h(0:nc - 1, 0:nr - 1)
      real(c_float), intent(out) :: cmax(0:nc - 2, 0:nr - 2)
      real(c_float), intent(out) :: bmax(0:nbc - 1, 0:nbr - 1)
      real(c_float), intent(out) :: smax(0:nsc - 1, 0:nsr - 1)
      integer :: i, j
      real(dp) :: m
      do i = 0, nr - 2
         do j = 0, nc - 2
            m = max(h(j, i), h(j + 1, i), h(j, i + 1), h(j + 1, i + 1))
            cmax(j, i) = real(m, c_float)
            if (real(cmax(j, i), dp) < m) cmax(j, i) = nearest(cmax(j, i), 1.0_c_float)
         end do
      end do
      bmax = -huge(1.0_c_float)
      do i = 0, nr - 2
         do j = 0, nc - 2
            bmax(j / bsz, i / bsz) = max(bmax(j / bsz, i / bsz), cmax(j, i))
         end do
      end do
      smax = -huge(1.0_c_float)
      do i = 0, nbr - 1
         do j = 0, nbc - 1
            smax(j / 4, i / 4) = max(smax(j / 4, i / 4), bmax(j, i))
         end do
      end do
   end subroutine walk_prepare

   !> Trace nray rays (s, l: (nray, 3) C-ordered, metres, body-fixed); dist(k) is the probe's
   !> distance to its hit or -1. grid = (lat_first, lon_first, dlat, dlon, a, f, hmin, hmax);
   !> coef(20, 3) and cen(3) the cubic map (conv = 1); level 0 walks cells only, 1 blocks
   !> then cells, 3 superblocks, blocks, cells; 2 only sets up (no walk); 4 as 1, then the
   !> refinement a sound answer needs at least (two exact conversions, one more root). ncount returns
   !> (cells, blocks, superblocks visited) summed over the rays.
   subroutine walk_trace(nr, nc, h, cmax, bsz, nbr, nbc, bmax, nsr, nsc, smax, grid, conv, coef, cen, level, &
                         nray, s, l, dist, ncount) bind(c, name="walk_trace")
      integer(c_int), value, intent(in) :: nr, nc, bsz, nbr, nbc, nsr, nsc, conv, level, nray
      real(c_double), intent(in) :: h(0:nc - 1, 0:nr - 1)
      real(c_float), intent(in) :: cmax(0:nc - 2, 0:nr - 2)
      real(c_float), intent(in) :: bmax(0:nbc - 1, 0:nbr - 1)
      real(c_float), intent(in) :: smax(0:nsc - 1, 0:nsr - 1)
      real(c_double), intent(in) :: grid(8), coef(20, 3), cen(3)
      real(c_double), intent(in) :: s(3, nray), l(3, nray)
      real(c_double), intent(out) :: dist(nray)
      real(c_double), intent(out) :: ncount(3)
      integer :: k
      real(dp) :: u(3), ra, rb, p0(3), p1(3), g0(3), g1(3), tr
      logical :: ok
      ncount = 0
      do k = 1, nray
         dist(k) = -1
         u = l(:, k) / norm2(l(:, k))
         if (.not. raised_hit(s(:, k), u, grid(5), grid(6), grid(8), ra)) cycle
         if (.not. raised_hit(s(:, k), u, grid(5), grid(6), grid(7), rb)) rb = ra + 2000
         p0 = s(:, k) + ra * u
         p1 = s(:, k) + rb * u
         call to_grid(p0, g0)
         call to_grid(p1, g1)
         if (level == 2) cycle                          ! set-up only: the conversions' cost
         ok = walk(merge(1, min(level, 2), level == 4), 0.0_dp, 1.0_dp, -huge(1), huge(1), -huge(1), huge(1), tr)
         if (ok) dist(k) = ra + tr * (rb - ra)
         if (ok .and. level == 4) call refine(s(:, k), u, dist(k))
      end do

   contains

      !> Level 4: the least a sound answer adds to the walk's root r (not a proof either): the exact
      !> (row, column, height) of two ray points 1 mm either side of it, a bracket from which a sound
      !> search would refine, and the closed-form root again on the straight track between them,
      !> in the cell of their midpoint. Always Heikkinen's exact conversion (a cubic map's remainder
      !> is not proven).
      subroutine refine(sk, u, r)
         real(dp), intent(in) :: sk(3), u(3)
         real(dp), intent(inout) :: r
         real(dp), parameter :: half = 1.0e-3_dp
         real(dp) :: lat, lon, t2
         integer :: ci, cj
         call heikkinen(sk + (r - half) * u, grid(5), grid(6), lat, lon, g0(3))
         g0(1) = (lat * rad2deg - grid(1)) / grid(3)
         g0(2) = (lon * rad2deg - grid(2)) / grid(4)
         call heikkinen(sk + (r + half) * u, grid(5), grid(6), lat, lon, g1(3))
         g1(1) = (lat * rad2deg - grid(1)) / grid(3)
         g1(2) = (lon * rad2deg - grid(2)) / grid(4)
         ci = min(max(floor(0.5_dp * (g0(1) + g1(1))), 0), nr - 2)
         cj = min(max(floor(0.5_dp * (g0(2) + g1(2))), 0), nc - 2)
         if (cell_root(ci, cj, 0.0_dp, 1.0_dp, t2)) r = r - half + 2 * half * t2
      end subroutine refine

      subroutine to_grid(p, g)
         real(dp), intent(in) :: p(3)
         real(dp), intent(out) :: g(3)
         real(dp) :: lat, lon, x(3), m(20)
         integer :: a1, b1, c1, q
         if (conv == 0) then
            call heikkinen(p, grid(5), grid(6), lat, lon, g(3))
            g(1) = (lat * rad2deg - grid(1)) / grid(3)
            g(2) = (lon * rad2deg - grid(2)) / grid(4)
         else
            x = (p - cen) * 1.0e-3_dp
            q = 0
            do a1 = 0, 3
               do b1 = 0, 3 - a1
                  do c1 = 0, 3 - a1 - b1
                     q = q + 1
                     m(q) = x(1)**a1 * x(2)**b1 * x(3)**c1
                  end do
               end do
            end do
            g = matmul(m, coef)
         end if
      end subroutine to_grid

      !> Walk the straight track g0 -> g1 for t in [ta, tb]: superblocks (lv = 2), blocks (1)
      !> or cells (0); a unit not cleared is walked one level down, within its index range
      !> [i0, i1] x [j0, j1] at that level (a track entering it on an edge starts inside).
      recursive logical function walk(lv, ta, tb, i0, i1, j0, j1, tr) result(hit)
         integer, intent(in) :: lv, i0, i1, j0, j1
         real(dp), intent(in) :: ta, tb
         real(dp), intent(out) :: tr
         real(dp) :: di, dj, dh, ti, tj, dti, dtj, t, tn, sz
         integer :: ci, cj, si, sj, nbi, nbj
         real(c_float) :: m
         hit = .false.
         tr = 0
         select case (lv)
         case (2)
            sz = 4 * bsz
            nbi = nsr
            nbj = nsc
         case (1)
            sz = bsz
            nbi = nbr
            nbj = nbc
         case default
            sz = 1
            nbi = nr - 1
            nbj = nc - 1
         end select
         di = g1(1) - g0(1)
         dj = g1(2) - g0(2)
         dh = g1(3) - g0(3)
         ci = min(max(floor((g0(1) + di * ta) / sz), i0), i1)
         cj = min(max(floor((g0(2) + dj * ta) / sz), j0), j1)
         si = merge(1, -1, di > 0)
         sj = merge(1, -1, dj > 0)
         dti = huge(1.0_dp)
         dtj = huge(1.0_dp)
         if (di /= 0) dti = abs(sz / di)
         if (dj /= 0) dtj = abs(sz / dj)
         ti = huge(1.0_dp)
         tj = huge(1.0_dp)
         if (di > 0) ti = ((ci + 1) * sz - g0(1)) / di
         if (di < 0) ti = (ci * sz - g0(1)) / di
         if (dj > 0) tj = ((cj + 1) * sz - g0(2)) / dj
         if (dj < 0) tj = (cj * sz - g0(2)) / dj
         t = ta
         do while (t < tb)
            tn = min(ti, tj, tb)
            if (ci < 0 .or. cj < 0 .or. ci >= nbi .or. cj >= nbj) then
               m = -huge(1.0_c_float)                    ! outside the grid: no surface
            else
               ncount(lv + 1) = ncount(lv + 1) + 1
               select case (lv)
               case (2)
                  m = smax(cj, ci)
               case (1)
                  m = bmax(cj, ci)
               case default
                  m = cmax(cj, ci)
               end select
            end if
            if (m >= g0(3) + dh * tn) then               ! a descending track is lowest at its exit
               if (lv == 2) then
                  hit = walk(1, t, tn, 4 * ci, 4 * ci + 3, 4 * cj, 4 * cj + 3, tr)
               else if (lv == 1) then
                  hit = walk(0, t, tn, bsz * ci, bsz * ci + bsz - 1, bsz * cj, bsz * cj + bsz - 1, tr)
               else
                  hit = cell_root(ci, cj, t, tn, tr)
               end if
               if (hit) return
            end if
            t = tn
            if (ti < tj) then
               ci = ci + si
               ti = ti + dti
            else
               cj = cj + sj
               tj = tj + dtj
            end if
         end do
      end function walk

      !> First t in [ta, tb] where the track's height is at or below the cell's bilinear surface.
      logical function cell_root(ci, cj, ta, tb, tr) result(hit)
         integer, intent(in) :: ci, cj
         real(dp), intent(in) :: ta, tb
         real(dp), intent(out) :: tr
         real(dp) :: z00, z01, z10, z11, u0, v0, a1, a2, a3, di, dj, q0, q1, q2, fa, d, sq, t1, t2, tt
         hit = .false.
         tr = 0
         z00 = h(cj, ci)
         z01 = h(cj + 1, ci)
         z10 = h(cj, ci + 1)
         z11 = h(cj + 1, ci + 1)
         di = g1(1) - g0(1)
         dj = g1(2) - g0(2)
         u0 = g0(1) - ci
         v0 = g0(2) - cj
         a1 = z10 - z00
         a2 = z01 - z00
         a3 = z11 - z10 - z01 + z00
         q0 = g0(3) - (z00 + a1 * u0 + a2 * v0 + a3 * u0 * v0)
         q1 = (g1(3) - g0(3)) - (a1 * di + a2 * dj + a3 * (u0 * dj + v0 * di))
         q2 = -a3 * di * dj
         fa = q0 + ta * (q1 + q2 * ta)
         if (fa <= 0) then
            tr = ta
            hit = .true.
            return
         end if
         if (abs(q2) < tiny(1.0_dp)) then
            if (q1 < 0) then
               tt = -q0 / q1
               if (tt <= tb) then
                  tr = tt
                  hit = .true.
               end if
            end if
            return
         end if
         d = q1 * q1 - 4 * q2 * q0
         if (d < 0) return
         sq = sqrt(d)
         t1 = (-q1 - sq) / (2 * q2)
         t2 = (-q1 + sq) / (2 * q2)
         if (t1 > t2) then
            tt = t1
            t1 = t2
            t2 = tt
         end if
         if (t1 >= ta .and. t1 <= tb) then
            tr = t1
            hit = .true.
         else if (t2 >= ta .and. t2 <= tb) then
            tr = t2
            hit = .true.
         end if
      end function cell_root

   end subroutine walk_trace

   !> Nearer crossing of the ray s + r u (|u| = 1) with the ellipsoid of semi-axes a + hh, b + hh.
   logical function raised_hit(s, u, a, f, hh, r) result(ok)
      real(dp), intent(in) :: s(3), u(3), a, f, hh
      real(dp), intent(out) :: r
      real(dp) :: ia, ib, qa, qb, qc, d
      ia = 1 / (a + hh)**2
      ib = 1 / (a * (1 - f) + hh)**2
      qa = (u(1)**2 + u(2)**2) * ia + u(3)**2 * ib
      qb = 2 * ((s(1) * u(1) + s(2) * u(2)) * ia + s(3) * u(3) * ib)
      qc = (s(1)**2 + s(2)**2) * ia + s(3)**2 * ib - 1
      d = qb * qb - 4 * qa * qc
      ok = d >= 0
      r = 0
      if (ok) r = (-qb - sqrt(d)) / (2 * qa)
   end function raised_hit

   !> Geodetic latitude and longitude (rad) and height of p: Heikkinen's closed form.
   subroutine heikkinen(p, a, f, lat, lon, hh)
      real(dp), intent(in) :: p(3), a, f
      real(dp), intent(out) :: lat, lon, hh
      real(dp) :: b, e2, ep2, r, ee, ff, g, c, sc, pp, q, r0, uu, vv, z0
      b = a * (1 - f)
      e2 = f * (2 - f)
      ep2 = (a * a - b * b) / (b * b)
      r = sqrt(p(1)**2 + p(2)**2)
      ee = a * a - b * b
      ff = 54 * b * b * p(3)**2
      g = r * r + (1 - e2) * p(3)**2 - e2 * ee
      c = e2 * e2 * ff * r * r / g**3
      sc = cbrt(1 + c + sqrt(c * c + 2 * c))
      pp = ff / (3 * (sc + 1 / sc + 1)**2 * g * g)
      q = sqrt(1 + 2 * e2 * e2 * pp)
      r0 = -(pp * e2 * r) / (1 + q) + sqrt(0.5_dp * a * a * (1 + 1 / q) - pp * (1 - e2) * p(3)**2 / (q * (1 + q)) &
                                           - 0.5_dp * pp * r * r)
      uu = sqrt((r - e2 * r0)**2 + p(3)**2)
      vv = sqrt((r - e2 * r0)**2 + (1 - e2) * p(3)**2)
      z0 = b * b * p(3) / (a * vv)
      hh = uu * (1 - b * b / (a * vv))
      lat = atan((p(3) + ep2 * z0) / r)
      lon = atan2(p(2), p(1))
   end subroutine heikkinen

end module cell_walk_bound
