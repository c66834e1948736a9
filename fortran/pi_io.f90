!> Positioned, thread-safe reads of a binary file (POSIX open/pread/close via
!> the small C helper pi_io.c).
!>
!> Fortran units cannot connect one file twice, and a unit's file position is
!> shared by every thread using it; pread has neither limit, so a DEM opened
!> in dem_read_mode 1 can be read by many threads and opened by many callers.
module pi_io
  use, intrinsic :: iso_c_binding, only: c_int, c_int64_t, c_char, c_null_char, c_ptr, c_loc, c_null_ptr, &
                                         c_associated
  use pi_kinds, only: i1, i8
  implicit none
  private

  public :: io_open, io_close, io_size, io_read, io_map, io_unmap

  interface
    function c_open(path) bind(c, name='pi_io_open') result(fd)
      import :: c_int, c_char
      character(kind=c_char), intent(in) :: path(*)
      integer(c_int) :: fd
    end function c_open
    function c_close(fd) bind(c, name='pi_io_close') result(rc)
      import :: c_int
      integer(c_int), value :: fd
      integer(c_int) :: rc
    end function c_close
    function c_size(fd) bind(c, name='pi_io_size') result(n)
      import :: c_int, c_int64_t
      integer(c_int), value :: fd
      integer(c_int64_t) :: n
    end function c_size
    function c_pread(fd, buf, n, offset) bind(c, name='pi_io_pread') result(rc)
      import :: c_int, c_int64_t, c_ptr
      integer(c_int), value :: fd
      type(c_ptr), value :: buf
      integer(c_int64_t), value :: n, offset
      integer(c_int) :: rc
    end function c_pread
    function c_map(fd, n) bind(c, name='pi_io_map') result(p)
      import :: c_int, c_int64_t, c_ptr
      integer(c_int), value :: fd
      integer(c_int64_t), value :: n
      type(c_ptr) :: p
    end function c_map
    function c_unmap(p, n) bind(c, name='pi_io_unmap') result(rc)
      import :: c_int, c_int64_t, c_ptr
      type(c_ptr), value :: p
      integer(c_int64_t), value :: n
      integer(c_int) :: rc
    end function c_unmap
  end interface

contains

  !> Map the first n bytes of the open file read-only (c_null_ptr on failure).
  function io_map(fd, n) result(p)
    integer, intent(in) :: fd
    integer(i8), intent(in) :: n
    type(c_ptr) :: p
    p = c_map(int(fd, c_int), int(n, c_int64_t))
  end function io_map

  !> Unmap a mapping from io_map.
  subroutine io_unmap(p, n)
    type(c_ptr), intent(in) :: p
    integer(i8), intent(in) :: n
    integer(c_int) :: rc
    if (c_associated(p)) rc = c_unmap(p, int(n, c_int64_t))
  end subroutine io_unmap

  !> Open `path` for reading; fd >= 0 on success, negative otherwise.
  function io_open(path) result(fd)
    character(len=*), intent(in) :: path
    integer :: fd
    fd = int(c_open(trim(path)//c_null_char))
  end function io_open

  !> Close a descriptor from io_open.
  subroutine io_close(fd)
    integer, intent(in) :: fd
    integer(c_int) :: rc
    rc = c_close(int(fd, c_int))
  end subroutine io_close

  !> Size of the open file in bytes (negative on failure).
  function io_size(fd) result(n)
    integer, intent(in) :: fd
    integer(i8) :: n
    n = int(c_size(int(fd, c_int)), i8)
  end function io_size

  !> Read size(bytes) bytes at byte offset `offset` (0-based); ok = .false. on failure.
  subroutine io_read(fd, offset, bytes, ok)
    integer, intent(in) :: fd
    integer(i8), intent(in) :: offset
    integer(i1), intent(out), target :: bytes(:)
    logical, intent(out) :: ok
    ok = c_pread(int(fd, c_int), c_loc(bytes), int(size(bytes), c_int64_t), int(offset, c_int64_t)) == 0
  end subroutine io_read

end module pi_io
