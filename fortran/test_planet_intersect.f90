!> test_planet_intersect: the paper's driver program, in the reconstructed
!> legacy interface (docs/legacy-interface.md).
!>
!> Usage: test_planet_intersect DEM DEM_READ_MODE STEP_MODE RAYS [OUT]
!>   DEM    the DEM as NAME, NAME.hdr or NAME.dem
!>   RAYS   text file, one ray per line: sx sy sz lx ly lz (blank and # lines skipped)
!>   OUT    output file (default: standard output)
!> One line per ray: index, status, px py pz, tx ty tz, tcx tcy tcz, scx scy scz,
!> emission (degrees). NaN where a quantity does not apply.
!> Exit codes:
!>   0  success;
!>   1  bad command line (argument count, a mode that is not an integer),
!>      unreadable rays file or line, output file that exists or cannot be made;
!>   2  zcalc_planet_intersect returned a status: the DEM cannot be used
!>      (status 1-11, 13) or a mode is out of range (status 12); the message
!>      names the status ("status 12").
!> Every allocated array is freed on every exit path (valgrind-clean).
program test_planet_intersect
  use, intrinsic :: iso_fortran_env, only: real64, error_unit, output_unit, iostat_eor
  implicit none
  integer, parameter :: dp = real64
  character(len=4096) :: dem_name, rays_name, out_name, arg, line
  integer :: read_mode, step_mode, n, k, u, ios, ierr, uout, nargs
  real(dp), allocatable :: s(:, :), l(:, :), p(:, :), t(:, :), tc(:, :), sc(:, :), emission(:)
  integer, allocatable :: istat(:)
  real(dp) :: row(6)
  external :: zcalc_planet_intersect

  nargs = command_argument_count()
  if (nargs < 4 .or. nargs > 5) then
    write(error_unit, '(a)') 'usage: test_planet_intersect DEM DEM_READ_MODE STEP_MODE RAYS [OUT]'
    call exit(1)
  end if
  call get_command_argument(1, dem_name)
  ! (a mode given as "1 junk" was read as 1 by a list-directed read: a review; an integer out of
  ! range goes on to zcalc_planet_intersect, whose status 12 the driver reports)
  call get_command_argument(2, arg)
  ios = 1
  if (is_integer(arg)) read(arg, *, iostat=ios) read_mode
  if (ios /= 0) call fail('DEM_READ_MODE must be 0 or 1, got "'//trim(arg)//'"', 1)
  call get_command_argument(3, arg)
  ios = 1
  if (is_integer(arg)) read(arg, *, iostat=ios) step_mode
  if (ios /= 0) call fail('STEP_MODE must be 0 or 1, got "'//trim(arg)//'"', 1)
  call get_command_argument(4, rays_name)
  out_name = ''
  if (nargs == 5) call get_command_argument(5, out_name)

  ! count, then read the rays
  open(newunit=u, file=rays_name, status='old', action='read', iostat=ios)
  if (ios /= 0) call fail('cannot open rays file '//trim(rays_name), 1)
  n = 0
  do
    call read_line(u, line, ios)
    if (ios /= 0) exit
    if (is_data(line)) n = n + 1
  end do
  allocate(s(3, n), l(3, n), p(3, n), t(3, n), tc(3, n), sc(3, n), emission(n), istat(n))
  rewind(u)
  k = 0
  do
    call read_line(u, line, ios)
    if (ios /= 0) exit
    if (.not. is_data(line)) cycle
    k = k + 1
    ! exactly six numbers separated by spaces or tabs: a list-directed read alone took "... 0.0 /"
    ! (it stops at the slash, keeping the last line's lz), seven numbers, commas and "3*0" (a review)
    ios = 1
    if (six_tokens(line)) read(line, *, iostat=ios) row
    if (ios /= 0) call fail('rays file '//trim(rays_name)//': cannot read six numbers from: '//trim(line), 1)
    s(:, k) = row(1:3)
    l(:, k) = row(4:6)
  end do
  close(u)

  call zcalc_planet_intersect(n, s, l, trim(dem_name), read_mode, step_mode, p, t, tc, sc, &
                              emission, istat, ierr)
  if (ierr /= 0) then
    write(arg, '(i0)') ierr
    if (ierr == 12) then
      call fail('DEM_READ_MODE and STEP_MODE must be 0 or 1, got '//trim(int_text(read_mode))//' and ' &
                //trim(int_text(step_mode))//': status 12 (see docs/status-codes.md)', 2)
    end if
    call fail('cannot use DEM '//trim(dem_name)//': status '//trim(arg)//' (see docs/status-codes.md)', 2)
  end if

  if (len_trim(out_name) > 0) then
    open(newunit=uout, file=out_name, status='new', action='write', iostat=ios)
    if (ios /= 0) call fail('cannot create output '//trim(out_name)//' (it must not exist)', 1)
  else
    uout = output_unit
  end if
  write(uout, '(a)') '# index status px py pz tx ty tz tcx tcy tcz scx scy scz emission_deg'
  do k = 1, n
    write(uout, '(i0, 1x, i0, 13(1x, es25.17e3))') k, istat(k), p(:, k), t(:, k), tc(:, k), sc(:, k), emission(k)
  end do
  if (uout /= output_unit) close(uout)
  call release()

contains

  ! one line of the rays file into text; ios /= 0 at the end of the file; a
  ! line that does not fit in text is an error (never read cut short)
  subroutine read_line(unit, text, ios)
    integer, intent(in) :: unit
    character(len=*), intent(out) :: text
    integer, intent(out) :: ios
    integer :: nread
    read(unit, '(a)', advance='no', iostat=ios, size=nread) text
    if (ios == iostat_eor) then
      ios = 0                              ! the whole line was read
    else if (ios == 0) then
      call fail('rays file '//trim(rays_name)//': a line is longer than ' &
                //trim(int_text(len(text) - 1))//' characters', 1)
    end if
  end subroutine read_line

  character(len=12) function int_text(i)
    integer, intent(in) :: i
    write(int_text, '(i0)') i
  end function int_text

  ! free the arrays before the program ends (every path, so valgrind sees no leak)
  subroutine release()
    if (allocated(s)) deallocate(s)
    if (allocated(l)) deallocate(l)
    if (allocated(p)) deallocate(p)
    if (allocated(t)) deallocate(t)
    if (allocated(tc)) deallocate(tc)
    if (allocated(sc)) deallocate(sc)
    if (allocated(emission)) deallocate(emission)
    if (allocated(istat)) deallocate(istat)
  end subroutine release

  !> A line holding data: not blank, not a comment (# after spaces or tabs: a tab before the #
  !> stopped the run, a review).
  logical function is_data(text)
    character(len=*), intent(in) :: text
    integer :: i
    i = verify(text, ' '//achar(9))
    is_data = i > 0
    if (is_data) is_data = text(i:i) /= '#'
  end function is_data

  !> True when text is [+-]digits (1 to 9 digits), blanks around it allowed.
  logical function is_integer(text)
    character(len=*), intent(in) :: text
    integer :: i, j
    is_integer = .false.
    i = verify(text, ' ')
    if (i == 0) return
    j = len_trim(text)
    if (text(i:i) == '+' .or. text(i:i) == '-') i = i + 1
    if (i > j .or. j - i + 1 > 9) return
    is_integer = verify(text(i:j), '0123456789') == 0
  end function is_integer

  !> True when text holds exactly six tokens separated by spaces or tabs, none with a character
  !> that list-directed input reads specially (/ , * ; ' ").
  logical function six_tokens(text)
    character(len=*), intent(in) :: text
    integer :: i, n
    logical :: inword
    six_tokens = .false.
    if (scan(text, '/,*;''"') > 0) return
    n = 0
    inword = .false.
    do i = 1, len_trim(text)
      if (text(i:i) == ' ' .or. text(i:i) == achar(9)) then
        inword = .false.
      else if (.not. inword) then
        inword = .true.
        n = n + 1
      end if
    end do
    six_tokens = n == 6
  end function six_tokens

  subroutine fail(message, code)
    character(len=*), intent(in) :: message
    integer, intent(in) :: code
    write(error_unit, '(a)') 'test_planet_intersect: '//message
    call release()
    call exit(code)
  end subroutine fail

end program test_planet_intersect
