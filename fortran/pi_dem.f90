!> DEM storage and interpolation: the paper's section 2.1-2.2 (eqs. 1-12).
!>
!> A DEM is a global grid of planetocentric radii at pixel centres,
!> `nlon = 360*ppd` columns by `nlat = 180*ppd` rows, row 1 in the south
!> (centre latitude -90 + 1/(2 ppd) deg), column 1 centred at east longitude
!> 1/(2 ppd) deg; record k = (j-1)*nlon + i (eq. 1). See DESIGN section 3 for
!> the `.hdr`/`.dem` file pair.
!>
!> Two storage modes, as the paper's `dem_read_mode`:
!>   0  the whole grid in memory (read from the file, or attached to a caller's
!>      array without copying);
!>   1  the `.dem` file is kept open and single records are read on demand by
!>      direct (stream) access; only the two polar-row means are held.
!> Both give bit-identical radii.
!>
!> Reentrant: a `dem_t` holds no hidden global state; several may be open at
!> once, and one may be shared by threads (mode 0 only reads memory; mode 1
!> reads records with POSIX pread through its own descriptor, see pi_io).
module pi_dem
  use pi_kinds, only: dp, sp, i1, i4, i8
  use pi_status
  use pi_vector, only: pi, rad, deg, lon_diff
  use pi_io, only: io_open, io_close, io_size, io_read, io_map, io_unmap
  use, intrinsic :: iso_c_binding, only: c_ptr, c_null_ptr, c_associated, c_f_pointer
  use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
  implicit none
  private

  public :: dem_t, dem_header_t, dem_read_header, dem_open, dem_attach, dem_attach_map, dem_close, dem_radius, &
            dem_cell_nodes, dem_polar_mean, dem_paths

  !> An open DEM (either storage mode).
  type :: dem_t
    !> Pixels per degree, m_pix of Table 1.
    integer :: ppd = 0
    !> Number of longitude columns (360*ppd) and latitude rows (180*ppd).
    integer :: nlon = 0, nlat = 0
    !> Maximum radius (Table 1), flattening and equatorial radius of the spheroid.
    real(dp) :: rmax = 0.0_dp, f = 0.0_dp, re = 1.0_dp
    !> 0: grid in memory; 1: records read from the open file.
    integer :: read_mode = 0
    !> Mode 0: the grid, radii(i, j) = radius of column i, row j.
    real(dp), pointer, contiguous :: radii(:, :) => null()
    !> True when `radii` was allocated here (and is freed by dem_close).
    logical :: owns_radii = .false.
    !> Mode 1: descriptor of the open `.dem` file (pi_io), bytes per record, byte swap needed.
    integer :: fd = -1
    integer :: itemsize = 4
    logical :: swap = .false.
    !> Mean radius of the southernmost and northernmost rows (section 2.2,
    !> the radius assigned to the poles).
    real(dp) :: pole_south = 0.0_dp, pole_north = 0.0_dp
    !> Mode 1 with a memory map: the mapping and its float32 or float64 view.
    type(c_ptr) :: map = c_null_ptr
    integer(i8) :: map_bytes = 0
    real(sp), pointer, contiguous :: map_sp(:, :) => null()
    real(dp), pointer, contiguous :: map_dp(:, :) => null()
  end type dem_t

  !> Largest ppd accepted: 360*ppd columns must index in default integers
  !> (the file would hold 6.5e16 records).
  integer, parameter, public :: max_ppd = 1000000
  !> The range of radii (and of rmax) accepted, in any unit: squares and
  !> products of lengths, and far spacecraft up to 1e15 rmax, then stay far
  !> from overflow and underflow (docs/paper-notes.md, note 19).
  real(dp), parameter, public :: radius_min = 1.0e-100_dp, radius_max = 1.0e100_dp
  !> Largest |latitude| (radians) dem_radius accepts: pi/2 and a few ulps.
  real(dp), parameter :: lat_limit = 0.5_dp*pi*(1.0_dp + 4.0_dp*epsilon(1.0_dp))

  !> The header values of a DEM file pair (Table 1 plus the extensions), as a
  !> caller that has parsed and checked the `.hdr` itself hands them to
  !> dem_open (the Python layer: one parser for both storage modes).
  type :: dem_header_t
    !> Pixels per degree; bytes per record (4 or 8).
    integer :: ppd = 0, itemsize = 4
    !> Maximum radius, flattening, equatorial radius (Table 1).
    real(dp) :: rmax = 0.0_dp, f = 0.0_dp, re = 1.0_dp
    !> True when the file's byte order is not the machine's.
    logical :: swap = .false.
  end type dem_header_t

contains

  !> Names of the `.hdr` and `.dem` files of a DEM given as `NAME`, `NAME.hdr`
  !> or `NAME.dem`.
  pure subroutine dem_paths(name, hdr, dem)
    character(len=*), intent(in) :: name
    character(len=:), allocatable, intent(out) :: hdr, dem
    integer :: n
    n = len_trim(name)
    if (n >= 4) then
      if (name(n-3:n) == '.hdr' .or. name(n-3:n) == '.dem') n = n - 4
    end if
    hdr = name(1:n) // '.hdr'
    dem = name(1:n) // '.dem'
  end subroutine dem_paths

  !> Read and check a `.hdr` file (Table 1 plus optional `key = value` lines).
  !>
  !> The grammar is the one `planet_intersect.dem.read_header` implements, and
  !> tests feed both the same headers (docs/dem-format.md):
  !>   * the file is bytes, at most 1,000,000 of them; lines end at LF, CR or
  !>     CRLF; space and tab are the only white space, stripped at both ends;
  !>   * blank lines and lines starting `#` or `!` are skipped;
  !>   * the first four other lines hold ppd, rmax, f, re: the first token (up to
  !>     a space or tab) is the value, the rest of the line a comment; ppd is
  !>     `[+-]digits` (at most 9 digits), the reals `[+-]` then digits with an
  !>     optional point (or a point and digits) and an optional `e`/`E` exponent
  !>     of one to three digits;
  !>   * later lines are `key = value` (key compared without case):
  !>     `dtype = float32|float64`, `byteorder = little|big`; anything else is
  !>     an error.
  !>
  !> stat: stat_hdr_open, stat_hdr_value, stat_hdr_key, stat_bad_ppd,
  !> stat_bad_rmax, stat_bad_f, stat_bad_re.
  subroutine dem_read_header(hdr, ppd, rmax, f, re, itemsize, swap, stat)
    character(len=*), intent(in) :: hdr
    integer, intent(out) :: ppd, itemsize
    real(dp), intent(out) :: rmax, f, re
    logical, intent(out) :: swap
    integer, intent(out) :: stat
    character(len=:), allocatable :: text, line, key, val, tok
    integer :: fd, ios, nval, k, pos, eol, n, i, j
    integer(i8) :: nbytes
    integer(i1), allocatable :: raw(:)
    logical :: big, ok

    ppd = 0; rmax = 0.0_dp; f = 0.0_dp; re = 1.0_dp; itemsize = 4; big = .false.
    swap = .false.
    stat = stat_ok
    ! read the whole header with pread (no Fortran unit: safe in threads, see pi_io)
    fd = io_open(hdr)
    if (fd < 0) then
      stat = stat_hdr_open
      return
    end if
    nbytes = io_size(fd)
    ok = nbytes >= 0 .and. nbytes < 1000000_i8
    if (ok) then
      allocate(raw(nbytes))
      call io_read(fd, 0_i8, raw, ok)
    end if
    call io_close(fd)
    if (.not. ok) then
      stat = stat_hdr_open
      return
    end if
    n = size(raw)
    allocate(character(len=n) :: text)
    if (n > 0) text = transfer(raw, text)
    nval = 0
    pos = 1
    do while (pos <= n)
      ! one line: up to the next LF or CR (a CRLF leaves an empty line, skipped)
      eol = scan(text(pos:), achar(10)//achar(13))
      if (eol == 0) eol = n - pos + 2
      ! (spans and substrings, no functions returning strings: gfortran kept the lengths of such
      ! results in static variables, and headers read in threads came back with wrong values,
      ! re = 3 for 3396.19 with stat 0, a review of the legacy interface)
      call strip_span(text(pos:pos + eol - 2), i, j)
      line = text(pos + i - 1:pos + j - 1)
      pos = pos + eol
      if (len(line) == 0) cycle
      if (line(1:1) == '#' .or. line(1:1) == '!') cycle
      if (nval < 4) then
        nval = nval + 1
        call word_span(line, i, j)
        tok = line(i:j)
        ios = 1
        select case (nval)
        case (1)
          if (is_int_token(tok)) read(tok, *, iostat=ios) ppd
        case (2)
          if (is_real_token(tok)) read(tok, *, iostat=ios) rmax
        case (3)
          if (is_real_token(tok)) read(tok, *, iostat=ios) f
        case (4)
          if (is_real_token(tok)) read(tok, *, iostat=ios) re
        end select
        if (ios /= 0) then
          stat = stat_hdr_value
          exit
        end if
      else
        k = index(line, '=')
        if (k == 0) then
          stat = stat_hdr_key
          exit
        end if
        call strip_span(line(1:k-1), i, j)
        key = line(i:j)
        call to_lower(key)
        call word_span(line(k+1:), i, j)
        val = line(k + i:k + j)
        call to_lower(val)
        if (key == 'dtype' .and. val == 'float32') then
          itemsize = 4
        else if (key == 'dtype' .and. val == 'float64') then
          itemsize = 8
        else if (key == 'byteorder' .and. val == 'little') then
          big = .false.
        else if (key == 'byteorder' .and. val == 'big') then
          big = .true.
        else
          stat = stat_hdr_key
          exit
        end if
      end if
    end do
    if (stat /= stat_ok) return
    if (nval < 4) then
      stat = stat_hdr_value
    else
      stat = header_stat(ppd, rmax, f, re)
    end if
    swap = big .neqv. native_big_endian()
  end subroutine dem_read_header

  !> Open a DEM from its file pair (the paper's zdem_open, plus zdem_read for
  !> read_mode 0).
  !>
  !> name: `NAME`, `NAME.hdr` or `NAME.dem`. read_mode 0 reads the whole grid
  !> and checks every radius (finite, positive, <= rmax); read_mode 1 keeps the
  !> file open and reads only the two polar rows, to form their means; its
  !> records are checked as they are read.
  !>
  !> stat: any code of dem_read_header, stat_dem_open, stat_dem_size,
  !> stat_dem_read, stat_bad_radii, stat_bad_rmax, stat_bad_mode.
  subroutine dem_open(name, read_mode, dem, stat, use_map, header)
    character(len=*), intent(in) :: name
    integer, intent(in) :: read_mode
    type(dem_t), intent(out) :: dem
    integer, intent(out) :: stat
    !> read_mode 1 only: read records from a memory map instead of pread
    !> (ignored when the file's byte order is not the machine's).
    logical, intent(in), optional :: use_map
    !> The header's values, parsed and checked by the caller: given, the `.hdr`
    !> is not read again (they are checked with header_stat all the same).
    type(dem_header_t), intent(in), optional :: header
    character(len=:), allocatable :: hdr, demfile
    integer(i8) :: fsize
    integer :: j
    real(dp), allocatable :: row(:)

    if (read_mode /= 0 .and. read_mode /= 1) then
      stat = stat_bad_mode
      return
    end if
    call dem_paths(name, hdr, demfile)
    if (present(header)) then
      stat = header_stat(header%ppd, header%rmax, header%f, header%re)
      if (stat == stat_ok .and. header%itemsize /= 4 .and. header%itemsize /= 8) stat = stat_hdr_key
      dem%ppd = header%ppd; dem%rmax = header%rmax; dem%f = header%f; dem%re = header%re
      dem%itemsize = header%itemsize; dem%swap = header%swap
    else
      call dem_read_header(hdr, dem%ppd, dem%rmax, dem%f, dem%re, dem%itemsize, dem%swap, stat)
    end if
    if (stat /= stat_ok) return
    dem%nlon = 360*dem%ppd
    dem%nlat = 180*dem%ppd
    dem%read_mode = read_mode

    dem%fd = io_open(demfile)
    if (dem%fd < 0) then
      dem%fd = -1
      stat = stat_dem_open
      return
    end if
    fsize = io_size(dem%fd)
    if (fsize /= int(dem%nlon, i8)*int(dem%nlat, i8)*int(dem%itemsize, i8)) then
      stat = stat_dem_size
      call dem_close(dem)
      return
    end if

    if (read_mode == 0) then
      allocate(dem%radii(dem%nlon, dem%nlat))
      dem%owns_radii = .true.
      do j = 1, dem%nlat
        call read_records(dem, int(j-1, i8)*dem%nlon + 1, dem%nlon, dem%radii(:, j), stat)
        if (stat /= stat_ok) exit
      end do
      call io_close(dem%fd)
      dem%fd = -1
      if (stat /= stat_ok) then
        call dem_close(dem)
        return
      end if
      dem%pole_south = dem_polar_mean(dem%radii(:, 1))
      dem%pole_north = dem_polar_mean(dem%radii(:, dem%nlat))
    else
      if (present(use_map)) then
        if (use_map .and. .not. dem%swap) then
          dem%map = io_map(dem%fd, fsize)
          if (c_associated(dem%map)) then
            dem%map_bytes = fsize
            if (dem%itemsize == 4) then
              call c_f_pointer(dem%map, dem%map_sp, [dem%nlon, dem%nlat])
            else
              call c_f_pointer(dem%map, dem%map_dp, [dem%nlon, dem%nlat])
            end if
          end if
        end if
      end if
      allocate(row(dem%nlon))
      call read_records(dem, 1_i8, dem%nlon, row, stat)
      if (stat == stat_ok) dem%pole_south = dem_polar_mean(row)
      if (stat == stat_ok) call read_records(dem, int(dem%nlat-1, i8)*dem%nlon + 1, dem%nlon, row, stat)
      if (stat == stat_ok) dem%pole_north = dem_polar_mean(row)
      if (stat /= stat_ok) call dem_close(dem)
    end if
  end subroutine dem_open

  !> Attach a caller's grid as a read_mode-0 DEM without copying it.
  !>
  !> radii(nlon, nlat) must stay alive and unchanged while `dem` is used. The
  !> caller is responsible for having validated the radii (the Python layer
  !> does so once, when the DEM is made); this routine checks the shape and
  !> the header values only.
  !>
  !> stat: stat_bad_ppd, stat_bad_shape, stat_bad_rmax, stat_bad_f, stat_bad_re.
  subroutine dem_attach(radii, ppd, rmax, f, re, dem, stat)
    real(dp), intent(in), target, contiguous :: radii(:, :)
    integer, intent(in) :: ppd
    real(dp), intent(in) :: rmax, f, re
    type(dem_t), intent(out) :: dem
    integer, intent(out) :: stat
    call set_grid(ppd, rmax, f, re, dem, stat)
    if (stat == stat_ok .and. (size(radii, 1) /= dem%nlon .or. size(radii, 2) /= dem%nlat)) stat = stat_bad_shape
    if (stat /= stat_ok) return
    dem%read_mode = 0
    dem%radii => radii
    dem%owns_radii = .false.
    dem%pole_south = dem_polar_mean(radii(:, 1))
    dem%pole_north = dem_polar_mean(radii(:, dem%nlat))
  end subroutine dem_attach

  !> Attach a caller's read-only memory map of a `.dem` file (native byte order)
  !> as a read_mode-1 DEM, without copying: records are read from the map and
  !> checked as they are read, exactly as dem_open(..., use_map=.true.) does,
  !> but the map is the caller's and stays open between calls, so pages the
  !> kernel has brought in are not faulted in again.
  !>
  !> map: address of nlon*nlat records of itemsize 4 (real32) or 8 (real64),
  !> which must stay mapped while `dem` is used; nbytes: the map's length.
  !>
  !> poles (optional): the polar means (south, north) that an earlier attach of
  !> the same map set in dem%pole_south and dem%pole_north; given, the two
  !> polar rows (2 x 46,080 records at 128 ppd) are not read again.
  !>
  !> stat: stat_dem_size when nbytes is not 180 ppd x 360 ppd records of
  !> itemsize (or ppd < 1), else as dem_attach, stat_bad_mode for another
  !> itemsize, stat_bad_radii when a polar row holds an invalid radius.
  subroutine dem_attach_map(map, nbytes, itemsize, ppd, rmax, f, re, dem, stat, poles)
    type(c_ptr), intent(in) :: map
    integer(i8), intent(in) :: nbytes
    integer, intent(in) :: itemsize, ppd
    real(dp), intent(in) :: rmax, f, re
    type(dem_t), intent(out) :: dem
    integer, intent(out) :: stat
    real(dp), intent(in), optional :: poles(2)
    if (ppd < 1 .or. nbytes /= 64800_i8*ppd*ppd*itemsize) then
      stat = stat_dem_size
      return
    end if
    call set_grid(ppd, rmax, f, re, dem, stat)
    if (stat == stat_ok .and. itemsize /= 4 .and. itemsize /= 8) stat = stat_bad_mode
    if (stat /= stat_ok) return
    dem%read_mode = 1
    dem%itemsize = itemsize
    if (itemsize == 4) then
      call c_f_pointer(map, dem%map_sp, [dem%nlon, dem%nlat])
    else
      call c_f_pointer(map, dem%map_dp, [dem%nlon, dem%nlat])
    end if
    if (present(poles)) then
      dem%pole_south = poles(1)
      dem%pole_north = poles(2)
      return
    end if
    call row_mean(dem, 1, dem%pole_south, stat)
    if (stat == stat_ok) call row_mean(dem, dem%nlat, dem%pole_north, stat)
  end subroutine dem_attach_map

  !> Mean radius of row j (dem_polar_mean), its records read and checked by
  !> node_value in whichever storage the DEM has.
  subroutine row_mean(dem, j, r, stat)
    type(dem_t), intent(in) :: dem
    integer, intent(in) :: j
    real(dp), intent(out) :: r
    integer, intent(out) :: stat
    real(dp), allocatable :: row(:)
    integer :: i
    stat = stat_ok
    allocate(row(dem%nlon))                           ! 46,080 values at 128 ppd: not on the stack
    do i = 1, dem%nlon
      call node_value(dem, i, j, row(i), stat)
    end do
    r = dem_polar_mean(row)
  end subroutine row_mean

  !> The status of a grid's header values (Table 1): stat_ok when 1 <= ppd <= max_ppd,
  !> rmax and re are in [radius_min, radius_max] and 0 <= f < 1; else the first
  !> failing one's code (stat_bad_ppd, stat_bad_rmax, stat_bad_f, stat_bad_re).
  pure integer function header_stat(ppd, rmax, f, re) result(stat)
    integer, intent(in) :: ppd
    real(dp), intent(in) :: rmax, f, re
    stat = stat_ok
    if (ppd < 1 .or. ppd > max_ppd) then
      stat = stat_bad_ppd
    else if (.not. (rmax >= radius_min .and. rmax <= radius_max)) then
      stat = stat_bad_rmax
    else if (.not. ieee_is_finite(f) .or. f < 0.0_dp .or. f >= 1.0_dp) then
      stat = stat_bad_f
    else if (.not. (re >= radius_min .and. re <= radius_max)) then
      stat = stat_bad_re
    end if
  end function header_stat

  !> Check the header values of a grid that a caller hands over (header_stat)
  !> and set them and the grid's size in dem.
  subroutine set_grid(ppd, rmax, f, re, dem, stat)
    integer, intent(in) :: ppd
    real(dp), intent(in) :: rmax, f, re
    type(dem_t), intent(inout) :: dem
    integer, intent(out) :: stat
    stat = header_stat(ppd, rmax, f, re)
    if (stat /= stat_ok) return
    dem%ppd = ppd
    dem%nlon = 360*ppd
    dem%nlat = 180*ppd
    dem%rmax = rmax
    dem%f = f
    dem%re = re
  end subroutine set_grid

  !> Release a DEM: close its file, free a grid it owns.
  subroutine dem_close(dem)
    type(dem_t), intent(inout) :: dem
    if (c_associated(dem%map)) call io_unmap(dem%map, dem%map_bytes)
    dem%map = c_null_ptr
    dem%map_sp => null()
    dem%map_dp => null()
    if (dem%fd /= -1) call io_close(dem%fd)
    dem%fd = -1
    if (dem%owns_radii .and. associated(dem%radii)) deallocate(dem%radii)
    dem%radii => null()
    dem%owns_radii = .false.
  end subroutine dem_close

  !> Mean of one polar row: the radius assigned to a pole (section 2.2).
  pure function dem_polar_mean(row) result(r)
    real(dp), intent(in) :: row(:)
    real(dp) :: r
    r = sum(row) / real(size(row), dp)
  end function dem_polar_mean

  !> Bilinearly interpolated DEM radius at planetocentric (lat, lon), radians:
  !> the paper's zdem_radius (read_mode 0) and zdem_radius_increment
  !> (read_mode 1), eqs. 2-12.
  !>
  !> Particulars. Column i1 = floor(Delta(phi1, lon) ppd) + 1 (eq. 6), with
  !> phi1 = 1/(2 ppd) deg the first column centre and i2 = i1 + 1 wrapping
  !> to 1 past nlon (eq. 7). Row j1 = floor((lat - theta1) ppd) + 1 (eq. 8),
  !> j2 = j1 + 1 (eq. 9). Within half a pixel of a pole (j1 = 0 or
  !> j1 = nlat) the missing row is the pole itself, at latitude -90 or +90
  !> deg, carrying the mean radius of the adjacent row; the latitude fraction
  !> is then measured over that half-pixel gap, so the surface is continuous
  !> and single-valued at the pole (docs/paper-notes.md). Eqs. 10-12 blend.
  !>
  !> stat: stat_ok; stat_bad_coord (r = 0) when lon is not finite or |lat|
  !> exceeds pi/2 (by more than rounding); in read_mode 1 stat_dem_read,
  !> stat_bad_radii or stat_bad_rmax when a record cannot be read or is
  !> invalid (r is then 0).
  subroutine dem_radius(dem, lat, lon, r, stat)
    type(dem_t), intent(in) :: dem
    real(dp), intent(in) :: lat, lon
    real(dp), intent(out) :: r
    integer, intent(out) :: stat
    real(dp) :: x, y, fx, fy, r1, r2, r3, r4, ra, rb, theta1_deg, lat_deg
    integer :: i1, i2, j1

    stat = stat_ok
    ! a non-finite coordinate (from a ray that overflowed, say) is a status, never an index
    if (.not. (ieee_is_finite(lon) .and. abs(lat) <= lat_limit)) then
      r = 0.0_dp
      stat = stat_bad_coord
      return
    end if
    ! eq. 6: fractional column offset from the first column centre, in pixels
    x = lon_diff(rad*0.5_dp/dem%ppd, lon) * deg * dem%ppd
    i1 = int(min(max(x, 0.0_dp), real(dem%nlon, dp))) + 1     ! x >= 0, so int() is floor()
    if (i1 > dem%nlon) i1 = dem%nlon      ! x rounded up to nlon: stay on the last column
    fx = x - real(i1 - 1, dp)             ! m_pix * delta-phi of eqs. 10-11
    i2 = i1 + 1                           ! eq. 7
    if (i2 > dem%nlon) i2 = 1             ! longitude cyclicity

    ! eq. 8: fractional row offset from the first row centre
    lat_deg = lat*deg
    theta1_deg = -90.0_dp + 0.5_dp/dem%ppd
    y = (lat_deg - theta1_deg) * dem%ppd
    j1 = floor(y) + 1
    if (j1 <= 0) then
      ! south polar cap: the pole (r1 = r2 = mean of row 1) at -90 deg, row 1 half a pixel north
      fy = min(max((lat_deg + 90.0_dp) * 2.0_dp * dem%ppd, 0.0_dp), 1.0_dp)
      r1 = dem%pole_south
      r2 = dem%pole_south
      call node_value(dem, i1, 1, r3, stat)
      call node_value(dem, i2, 1, r4, stat)
    else if (j1 >= dem%nlat) then
      ! north polar cap: row nlat, then the pole (r3 = r4 = mean of row nlat) at +90 deg
      fy = min(max((lat_deg - (90.0_dp - 0.5_dp/dem%ppd)) * 2.0_dp * dem%ppd, 0.0_dp), 1.0_dp)
      call node_value(dem, i1, dem%nlat, r1, stat)
      call node_value(dem, i2, dem%nlat, r2, stat)
      r3 = dem%pole_north
      r4 = dem%pole_north
    else
      fy = y - real(j1 - 1, dp)           ! m_pix * delta-theta of eq. 12
      call node_value(dem, i1, j1, r1, stat)           ! eq. 2
      call node_value(dem, i2, j1, r2, stat)           ! eq. 3
      call node_value(dem, i1, j1 + 1, r3, stat)       ! eq. 4
      call node_value(dem, i2, j1 + 1, r4, stat)       ! eq. 5
    end if
    ra = r1 + fx*(r2 - r1)                ! eq. 10
    rb = r3 + fx*(r4 - r3)                ! eq. 11
    r = ra + fy*(rb - ra)                 ! eq. 12
    if (stat /= stat_ok) r = 0.0_dp
  end subroutine dem_radius

  !> The corners r1..r4 of eqs. 2-5 of the cell between DEM columns i + 1 and
  !> i + 2 (i = 0..nlon-1; column nlon + 1 is column 1) and DEM rows c and c + 1
  !> (c = 0..nlat; rows 0 and nlat + 1 are the poles): r(1:2) on row c, r(3:4)
  !> on row c + 1, west first. The poles carry the mean radius of the adjacent
  !> row (section 2.2).
  !>
  !> stat: stat_ok; stat_bad_coord for i or c outside those ranges; in
  !> read_mode 1 as dem_radius (r is then 0).
  subroutine dem_cell_nodes(dem, i, c, r, stat)
    type(dem_t), intent(in) :: dem
    integer, intent(in) :: i, c
    real(dp), intent(out) :: r(4)
    integer, intent(out) :: stat
    integer :: i1, i2
    stat = stat_ok
    if (i < 0 .or. i >= dem%nlon .or. c < 0 .or. c > dem%nlat) then
      r = 0.0_dp                          ! never an index outside the grid
      stat = stat_bad_coord
      return
    end if
    i1 = i + 1
    i2 = i + 2
    if (i2 > dem%nlon) i2 = i2 - dem%nlon
    if (c <= 0) then
      r(1:2) = dem%pole_south
    else
      call node_value(dem, i1, c, r(1), stat)
      call node_value(dem, i2, c, r(2), stat)
    end if
    if (c >= dem%nlat) then
      r(3:4) = dem%pole_north
    else
      call node_value(dem, i1, c + 1, r(3), stat)
      call node_value(dem, i2, c + 1, r(4), stat)
    end if
    if (stat /= stat_ok) r = 0.0_dp
  end subroutine dem_cell_nodes

  !> Record (i, j) of the grid (eq. 1) in either storage mode; stat is set only
  !> when the record cannot be read or is invalid.
  subroutine node_value(dem, i, j, value, stat)
    type(dem_t), intent(in) :: dem
    integer, intent(in) :: i, j
    real(dp), intent(out) :: value
    integer, intent(inout) :: stat
    real(dp) :: buf(1)
    integer :: st
    if (dem%read_mode == 0) then
      value = dem%radii(i, j)
    else if (associated(dem%map_sp)) then
      value = real(dem%map_sp(i, j), dp)
      if (.not. (value >= radius_min .and. value <= dem%rmax)) stat = stat_bad_radii
    else if (associated(dem%map_dp)) then
      value = dem%map_dp(i, j)
      if (.not. (value >= radius_min .and. value <= dem%rmax)) stat = stat_bad_radii
    else
      call read_records(dem, int(j - 1, i8)*dem%nlon + i, 1, buf, st)   ! eq. 1
      value = buf(1)
      if (st /= stat_ok) stat = st
    end if
  end subroutine node_value

  !> Read `n` consecutive records starting at record `first` (1-based, eq. 1)
  !> from the open `.dem` file, widen to real(dp) and check them.
  subroutine read_records(dem, first, n, values, stat)
    type(dem_t), intent(in) :: dem
    integer(i8), intent(in) :: first
    integer, intent(in) :: n
    real(dp), intent(out) :: values(n)
    integer, intent(out) :: stat
    integer(i1) :: bytes(dem%itemsize*n)
    integer :: k, m
    logical :: ok

    stat = stat_ok
    m = dem%itemsize
    call io_read(dem%fd, (first - 1)*m, bytes, ok)
    if (.not. ok) then
      values = 0.0_dp
      stat = stat_dem_read
      return
    end if
    if (dem%swap) then
      do k = 0, n - 1
        bytes(k*m + 1:k*m + m) = bytes(k*m + m:k*m + 1:-1)
      end do
    end if
    if (m == 4) then
      values = real(transfer(bytes, 0.0_sp, n), dp)
    else
      values = transfer(bytes, 0.0_dp, n)
    end if
    do k = 1, n
      if (.not. (values(k) >= radius_min .and. values(k) <= radius_max)) then
        stat = stat_bad_radii
      else if (values(k) > dem%rmax) then
        stat = stat_bad_rmax
      end if
    end do
  end subroutine read_records

  pure function native_big_endian() result(big)
    logical :: big
    big = transfer(1_i4, 0_i1) == 0_i1
  end function native_big_endian

  !> s with its letters A-Z made lower case, in place.
  pure subroutine to_lower(s)
    character(len=*), intent(inout) :: s
    integer :: k, c
    do k = 1, len(s)
      c = iachar(s(k:k))
      if (c >= iachar('A') .and. c <= iachar('Z')) s(k:k) = achar(c + 32)
    end do
  end subroutine to_lower

  !> s(i:j) is s without leading and trailing spaces and tabs (the header's only white space);
  !> i = 1, j = 0 when nothing is left.
  pure subroutine strip_span(s, i, j)
    character(len=*), intent(in) :: s
    integer, intent(out) :: i, j
    i = verify(s, ' '//achar(9))
    if (i == 0) then
      i = 1
      j = 0
      return
    end if
    j = verify(s, ' '//achar(9), back=.true.)
  end subroutine strip_span

  !> s(i:j) is the first token of s: after leading white space, up to a space or tab
  !> (i = 1, j = 0 when there is none).
  pure subroutine word_span(s, i, j)
    character(len=*), intent(in) :: s
    integer, intent(out) :: i, j
    integer :: k
    call strip_span(s, i, j)
    if (j < i) return
    k = scan(s(i:j), ' '//achar(9))
    if (k > 0) j = i + k - 2
  end subroutine word_span

  !> True when tok is `[+-]digits` with 1 to 9 digits.
  pure logical function is_int_token(tok) result(ok)
    character(len=*), intent(in) :: tok
    integer :: i0
    i0 = 1
    if (len(tok) > 0) then
      if (tok(1:1) == '+' .or. tok(1:1) == '-') i0 = 2
    end if
    ok = len(tok) - i0 + 1 >= 1 .and. len(tok) - i0 + 1 <= 9
    if (ok) ok = verify(tok(i0:), '0123456789') == 0
  end function is_int_token

  !> True when tok is a decimal real: `[+-]`, then digits with an optional
  !> point and digits, or a point and digits, then an optional exponent
  !> `e`/`E`, `[+-]`, one to three digits.
  pure logical function is_real_token(tok) result(ok)
    character(len=*), intent(in) :: tok
    integer :: i, n, nd
    n = len(tok)
    i = 1
    ok = .false.
    if (n == 0) return
    if (tok(1:1) == '+' .or. tok(1:1) == '-') i = 2
    nd = 0
    do while (i <= n)
      if (verify(tok(i:i), '0123456789') /= 0) exit
      i = i + 1; nd = nd + 1
    end do
    if (i <= n) then
      if (tok(i:i) == '.') then
        i = i + 1
        do while (i <= n)
          if (verify(tok(i:i), '0123456789') /= 0) exit
          i = i + 1; nd = nd + 1
        end do
      end if
    end if
    if (nd == 0) return
    if (i <= n) then
      if (tok(i:i) /= 'e' .and. tok(i:i) /= 'E') return
      i = i + 1
      if (i <= n) then
        if (tok(i:i) == '+' .or. tok(i:i) == '-') i = i + 1
      end if
      if (i > n .or. n - i + 1 > 3) return
      if (verify(tok(i:), '0123456789') /= 0) return
    end if
    ok = .true.
  end function is_real_token

end module pi_dem
