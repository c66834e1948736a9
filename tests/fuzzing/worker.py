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


def main() -> int:
    rfd, wfd = int(sys.argv[1]), int(sys.argv[2])
    faulthandler.enable(file=sys.stderr)          # a segfault prints the Python stack first
    limit = int(os.environ.get("PI_FUZZ_MEMORY_MB", "3000")) << 20
    try:                                           # a runaway allocation becomes MemoryError, not the OOM killer
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    except (ValueError, OSError):
        pass
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from fuzzing import ops                       # imports numpy and planet_intersect once

    _send(wfd, ("ready", os.getpid()))
    while True:
        try:
            n = struct.unpack("<Q", _read_exact(rfd, 8))[0]
            case = pickle.loads(_read_exact(rfd, n))
        except EOFError:
            return 0
        try:
            reply = ("ok", ops.run_case(case))
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
