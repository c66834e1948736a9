!> Working precision for planet-intersect.
!>
!> Every real in the library is `real(dp)` (IEEE binary64); DEM files may store
!> radii as binary32, which are widened exactly on read.
module pi_kinds
  use, intrinsic :: iso_fortran_env, only: real32, real64, int8, int32, int64
  implicit none
  private

  public :: dp, sp, i1, i4, i8

  !> Double precision real kind used for all geometry.
  integer, parameter :: dp = real64
  !> Single precision real kind (DEM records stored as float32).
  integer, parameter :: sp = real32
  !> One-byte integer kind (raw record bytes).
  integer, parameter :: i1 = int8
  !> Default 32-bit integer kind.
  integer, parameter :: i4 = int32
  !> 64-bit integer kind (record numbers and byte offsets of large DEMs).
  integer, parameter :: i8 = int64
end module pi_kinds
