"""Which compiled core the package uses: ``_core`` or ``_core_v3``.

The Fortran core is built twice on x86_64 (meson option ``cpu_dispatch``):
``_core`` for any x86-64 CPU and ``_core_v3`` for x86-64-v3 CPUs (AVX2, FMA,
BMI1/2, F16C, LZCNT, MOVBE: most x86 CPUs since 2015). Both come from the same
sources with the same IEEE flags (no fast-math, no contraction into FMA), so
their results are identical bit for bit (tests/test_core_dispatch.py); the v3
build only runs the vectorised loops four doubles wide instead of two (the
footprint kernel, docs/grs-notes.md "Speed").

The choice is made once, at the first call into the core:

* ``PI_CORE=auto`` (or unset): ``_core_v3`` when it was built and the CPU
  reports every x86-64-v3 feature (Linux ``/proc/cpuinfo``; elsewhere the
  portable core is used), otherwise ``_core``;
* ``PI_CORE=portable``: always ``_core``;
* ``PI_CORE=v3``: ``_core_v3``, or an error saying why it cannot be used.

:func:`core_info` tells which one was chosen and why.
"""

from __future__ import annotations

import os
from pathlib import Path

#: CPU flags (as Linux's /proc/cpuinfo names them) that gcc's -march=x86-64-v3
#: may use: x86-64-v2's (cx16, lahf_lm, popcnt, sse4_1, sse4_2, ssse3) and v3's
#: (avx, avx2, bmi1, bmi2, f16c, fma, lzcnt = abm, movbe, xsave). The kernel
#: lists avx/avx2 only when the operating system saves the YMM registers.
V3_FLAGS = frozenset({"cx16", "lahf_lm", "popcnt", "sse4_1", "sse4_2", "ssse3",
                      "avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe", "xsave"})

_CHOICES = ("auto", "portable", "v3")
_chosen = None          # (module, name, reason), set at the first call


def cpu_flags(cpuinfo: str | Path = "/proc/cpuinfo") -> frozenset | None:
    """The CPU's feature flags from a Linux cpuinfo file (its first "flags"
    line), or None when the file cannot be read or has no such line."""
    try:
        text = Path(cpuinfo).read_text(errors="replace")
    except OSError:
        return None
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if sep and key.strip() == "flags":
            return frozenset(value.split())
    return None


def missing_v3(flags) -> list[str]:
    """The x86-64-v3 features absent from ``flags`` (sorted; empty: all there)."""
    return sorted(V3_FLAGS - set(flags))


def choose(env: str | None, v3_built: bool, flags) -> tuple[str, str]:
    """(module name, reason) for a PI_CORE value, whether ``_core_v3`` was built
    and the CPU flags (None: unknown). Raises ValueError for a bad PI_CORE and
    RuntimeError when PI_CORE=v3 cannot be honoured."""
    want = "auto" if env is None or env.strip() == "" else env.strip().lower()
    if want not in _CHOICES:
        raise ValueError(f"PI_CORE={env!r}: expected one of {', '.join(_CHOICES)}")
    if want == "portable":
        return "_core", "PI_CORE=portable"
    if not v3_built:
        if want == "v3":
            raise RuntimeError("PI_CORE=v3: this installation has no _core_v3 (built on a CPU family other "
                               "than x86_64, with -Dcpu_dispatch=false, or the runtime-checked build)")
        return "_core", "no x86-64-v3 build in this installation"
    if flags is None:
        if want == "v3":
            return "_core_v3", "PI_CORE=v3 (CPU features not checked: no /proc/cpuinfo)"
        return "_core", "CPU features unknown (no /proc/cpuinfo): the portable core"
    miss = missing_v3(flags)
    if miss:
        if want == "v3":
            raise RuntimeError(f"PI_CORE=v3: this CPU lacks x86-64-v3 features {', '.join(miss)}; "
                               "running _core_v3 would stop with an illegal instruction")
        return "_core", f"CPU lacks x86-64-v3 features: {', '.join(miss)}"
    return "_core_v3", ("PI_CORE=v3" if want == "v3" else "the CPU has every x86-64-v3 feature")


def _v3_built() -> bool:
    import importlib.util
    return importlib.util.find_spec(f"{__package__}._core_v3") is not None


def _select():
    global _chosen
    if _chosen is None:
        import importlib
        name, reason = choose(os.environ.get("PI_CORE"), _v3_built(), cpu_flags())
        _chosen = (importlib.import_module(f"{__package__}.{name}"), name, reason)
    return _chosen


def __getattr__(attr):
    # `from ._ext import core` loads the chosen extension on first use
    if attr == "core":
        return _select()[0]
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


def core_info() -> dict:
    """Which compiled core is in use: ``{"module": "_core" or "_core_v3",
    "reason": ..., "v3_built": bool}``."""
    mod, name, reason = _select()
    return {"module": name, "reason": reason, "v3_built": _v3_built()}
