"""Properties of the built binaries that no numerical test would notice."""

import struct
from pathlib import Path

import pytest

import planet_intersect as pi
from planet_intersect import _core

PT_GNU_STACK = 0x6474E551
PF_X = 1


def stack_flags(path: Path) -> int | None:
    """p_flags of the PT_GNU_STACK program header of a 64-bit little-endian ELF
    file, or None when it has none."""
    data = path.read_bytes()
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        pytest.skip(f"{path.name} is not a 64-bit little-endian ELF file")
    e_phoff, = struct.unpack_from("<Q", data, 0x20)
    e_phentsize, e_phnum = struct.unpack_from("<HH", data, 0x36)
    for k in range(e_phnum):
        p_type, p_flags = struct.unpack_from("<II", data, e_phoff + k * e_phentsize)
        if p_type == PT_GNU_STACK:
            return p_flags
    return None


@pytest.mark.parametrize("which", ["extension", "driver"])
def test_no_executable_stack(which):
    # A nested Fortran procedure whose address is taken makes gfortran build a
    # trampoline on the stack, and the linker then marks the whole library as
    # needing an executable stack, which glibc 2.41 and later refuse to dlopen.
    path = Path(_core.__file__) if which == "extension" else pi.legacy_paths()["driver"]
    flags = stack_flags(path)
    assert flags is not None, f"{path.name} has no PT_GNU_STACK header (the stack defaults to executable)"
    assert not flags & PF_X, f"{path.name} asks for an executable stack"
