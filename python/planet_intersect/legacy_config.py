"""Link flags of the installed legacy FORTRAN77 library (a pkg-config query in Python).

The legacy library ``libplanet_intersect_legacy.a`` is static and its ray loop
uses OpenMP, so a program that links it also needs the OpenMP runtime, the
Fortran runtime and the maths library. The build writes them into a
pkg-config file installed beside the library,
``planet_intersect/lib/pkgconfig/planet-intersect-legacy.pc``; this module
reads that file, so the flags it returns are the ones ``pkg-config --libs``
prints (with the ``-L`` folder made absolute and normalised):

>>> from planet_intersect import legacy_config
>>> legacy_config.link_flags()          # doctest: +SKIP
'-L/.../planet_intersect/lib -lplanet_intersect_legacy -lgomp -lgfortran -lm'

Link an old program with ``gfortran old.f $(planet-intersect config --libs)``
(the program's sources first: the library is static). No ``-fopenmp`` is
needed on the user's line. See docs/legacy-interface.md.
"""

from __future__ import annotations

import os
import re
import shlex
from pathlib import Path

__all__ = ["pc_file", "pkg_config_path", "link_args", "link_flags", "compile_args", "compile_flags"]

PC_NAME = "planet-intersect-legacy"


def pkg_config_path() -> Path:
    """Folder holding ``planet-intersect-legacy.pc``: add it to ``PKG_CONFIG_PATH``."""
    return Path(__file__).resolve().parent / "lib" / "pkgconfig"


def pc_file() -> Path:
    """Path of the installed ``planet-intersect-legacy.pc``.

    Raises
    ------
    FileNotFoundError
        When the file is not installed (the package was not built by meson).
    """
    path = pkg_config_path() / f"{PC_NAME}.pc"
    if not path.is_file():
        raise FileNotFoundError(f"the legacy library's pkg-config file is not installed: {path} is missing "
                                "(reinstall planet-intersect with pip)")
    return path


def _fields(path: Path) -> dict:
    """Variables and keywords of a .pc file, ``${var}`` expanded as pkg-config does.

    ``${pcfiledir}`` is the folder of the file, shell-quoted so that a folder
    with spaces stays one argument when the fields are split. Raises
    ValueError naming the file for an undefined variable or a line that is
    neither ``name=value`` nor ``Keyword: value``.
    """
    variables = {"pcfiledir": shlex.quote(str(path.parent))}
    fields = {}

    def expand(value: str) -> str:
        # variables are stored expanded, so one pass suffices (and a variable
        # can only use those defined above it, as in pkg-config)
        def one(m):
            if m.group(1) not in variables:
                raise ValueError(f"{path}: undefined variable ${{{m.group(1)}}}")
            return variables[m.group(1)]
        return re.sub(r"\$\{([A-Za-z0-9_.]+)\}", one, value)

    for line in path.read_text(encoding="utf-8").splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        m = re.match(r"([A-Za-z0-9_.]+)\s*([=:])\s*(.*)$", line)
        if m is None:
            raise ValueError(f"{path}: cannot read the line {line!r}")
        name, kind, value = m.groups()
        if kind == "=":
            variables[name] = expand(value)
        else:
            fields[name] = expand(value)
    return fields


def _normalise(args: list) -> list:
    """Make -L folders absolute and normalised (…/lib/pkgconfig/.. -> …/lib)."""
    return ["-L" + os.path.normpath(os.path.abspath(a[2:])) if a.startswith("-L") else a for a in args]


def link_args() -> list:
    """The link flags of the legacy library as a list of arguments.

    Returns
    -------
    list of str
        ``-L<folder> -lplanet_intersect_legacy`` followed by the runtime
        libraries the library needs (OpenMP, Fortran runtime, maths), the
        ``Libs`` of ``planet-intersect-legacy.pc``; put them after the
        program's own sources or objects on the link line.

    Raises
    ------
    FileNotFoundError
        The pkg-config file is not installed.
    ValueError
        The pkg-config file has no ``Libs`` line or cannot be read.
    """
    path = pc_file()
    fields = _fields(path)
    if "Libs" not in fields:
        raise ValueError(f"{path}: no Libs line")
    return _normalise(shlex.split(fields["Libs"]))


def link_flags() -> str:
    """The link line of the legacy library, as ``planet-intersect config --libs`` prints it.

    ``shlex.join(link_args())``: quoted for a POSIX shell, so it can be pasted
    after ``gfortran old.f`` (e.g. ``gfortran old.f $(planet-intersect config
    --libs) -o old``; when the install folder has spaces, ``$(...)`` splits
    it whatever the quoting, as it does pkg-config's output: use
    ``eval gfortran old.f $(planet-intersect config --libs)`` or
    :func:`link_args`). Raises as :func:`link_args`.
    """
    return shlex.join(link_args())


def compile_args() -> list:
    """Compile flags of the legacy library (``Cflags``): empty, since its
    routines are external procedures called through implicit interfaces (no
    module or include files). Raises as :func:`link_args`."""
    path = pc_file()
    return _normalise(shlex.split(_fields(path).get("Cflags", "")))


def compile_flags() -> str:
    """:func:`compile_args` as one shell-quoted line (empty)."""
    return shlex.join(compile_args())
