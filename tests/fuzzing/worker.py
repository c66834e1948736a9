"""The fuzz worker: a separate process that performs cases sent by the parent.

Run as ``python worker.py READ_FD WRITE_FD``; messages are pickles preceded by
their length (8 bytes, little-endian). For each case it answers one of

* ``("ok", info)``
* ``("violation", message)``   a result broke a stated property (ops.PropertyViolation)
* ``("error", class names of the exception's MRO, message, traceback)``   the package raised
* ``("cli", message)``         the CLI exited 2 with this one-line message

A segfault, abort, ``exit`` from a Fortran run-time check or a hang kills only
this process: the parent sees the pipe close (or its timeout expire), reports
the case, and starts a new worker.
"""

from __future__ import annotations

import faulthandler
import os
import pickle
import resource
import struct
import sys
import traceback
from pathlib import Path


def _read_exact(fd: int, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = os.read(fd, n - len(buf))
        if not chunk:
            raise EOFError
        buf += chunk
    return buf


def _send(fd: int, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    os.write(fd, struct.pack("<Q", len(data)))
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def trap_invalid_in_core() -> None:
    """Trap IEEE invalid operations (SIGFPE) inside every Fortran core call, as
    -ffpe-trap=invalid would in a Fortran main program (in a library that flag
    does nothing). Only around the core: NumPy makes NaNs on purpose. A quiet
    NaN the core assigns (ieee_value) or propagates does not trap; an invalid
    operation (0/0, inf-inf, sqrt(-1), NaN compared with < or >, NaN to integer)
    does, and the worker dies with SIGFPE: a crash the parent reports."""
    import ctypes
    import functools

    from planet_intersect import _core

    libm = ctypes.CDLL("libm.so.6")
    fe_invalid = 1                                 # x86-64 <fenv.h>

    def trapped(f):
        @functools.wraps(f)
        def call(*args, **kwargs):
            libm.feenableexcept(fe_invalid)
            try:
                return f(*args, **kwargs)
            finally:
                libm.fedisableexcept(fe_invalid)
        return call

    for name in dir(_core):
        if name.startswith("core_") and callable(getattr(_core, name)):
            setattr(_core, name, trapped(getattr(_core, name)))


def main() -> int:
    rfd, wfd = int(sys.argv[1]), int(sys.argv[2])
    faulthandler.enable(file=sys.stderr)          # a segfault prints the Python stack first
    try:                                           # die with the parent, even in a hung case
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6").prctl(1, signal.SIGKILL)    # PR_SET_PDEATHSIG
        if os.getppid() == 1:
            return 0
    except OSError:
        pass
    limit = int(os.environ.get("PI_FUZZ_MEMORY_MB", "3000")) << 20
    try:                                           # a runaway allocation becomes MemoryError, not the OOM killer
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    except (ValueError, OSError):
        pass
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from fuzzing import bulk, ops                 # imports numpy and planet_intersect once

    if os.environ.get("PI_FUZZ_FPE_TRAP") == "1":
        trap_invalid_in_core()

    _send(wfd, ("ready", os.getpid()))
    while True:
        try:
            n = struct.unpack("<Q", _read_exact(rfd, 8))[0]
            case = pickle.loads(_read_exact(rfd, n))
        except EOFError:
            return 0
        try:
            reply = ("ok", bulk.run_batch(case) if case["op"] == "bulk" else ops.run_case(case))
        except ops.PropertyViolation as exc:
            reply = ("violation", str(exc))
        except ops.CLIFailure as exc:
            reply = ("cli", str(exc))
        except MemoryError as exc:
            reply = ("error", ["MemoryError"], str(exc), traceback.format_exc(limit=-8))
        except BaseException as exc:  # noqa: BLE001 - everything the package raises is judged by the parent
            if isinstance(exc, KeyboardInterrupt):
                raise
            reply = ("error", [c.__name__ for c in type(exc).__mro__], str(exc), traceback.format_exc(limit=-8))
        sys.stderr.flush()
        _send(wfd, reply)


if __name__ == "__main__":
    sys.exit(main())
