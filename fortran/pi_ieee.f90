!> NaN and finiteness without the IEEE intrinsic modules.
!>
!> A procedure that uses ieee_arithmetic (or whose host module does) makes
!> gfortran save and restore the floating-point environment on every entry
!> and exit, as the standard requires; on the DSM's per-point lookups that was
!> ~10 % of a ray's time (docs/shin-park-notes.md, "Fast exact path"). These
!> give the same answers for IEEE binary64 without it (no fast-math anywhere
!> in the build, so x /= x is kept).
module pi_ieee
  use pi_kinds, only: dp, i8
  implicit none
  private

  public :: nan_dp, is_nan, is_finite

  !> The quiet NaN ieee_value(x, ieee_quiet_nan) gives (bits 7FF8000000000000).
  real(dp), parameter :: nan_dp = transfer(int(z'7FF8000000000000', i8), 1.0_dp)

contains

  !> True where x is a NaN.
  elemental logical function is_nan(x)
    real(dp), intent(in) :: x
    is_nan = x /= x
  end function is_nan

  !> True where x is neither a NaN nor an infinity: its exponent bits are not all ones.
  !> (An integer test: abs(x) <= huge(x), an ordered comparison, raised IEEE invalid for a NaN,
  !> and the shading kernel's check of a NaN ortho value killed the runtime-checked build's fuzz
  !> worker, which traps invalid operations in the core: CI, 2026-12-03.)
  elemental logical function is_finite(x)
    real(dp), intent(in) :: x
    is_finite = iand(ishft(transfer(x, 0_i8), -52), 2047_i8) /= 2047_i8
  end function is_finite

end module pi_ieee
