"""Crash-safe execution of fuzz cases and the judgement of their outcomes.

:class:`Worker` keeps one worker process (tests/fuzzing/worker.py) that has
imported the package once; :meth:`Worker.call` sends it a case and waits at
most ``timeout`` seconds. A worker that dies (segfault, abort, SIGBUS, a
Fortran run-time check stopping the program) or does not answer in time is
reported as a ``crash`` or ``hang`` outcome and replaced by a fresh one, so the
fuzzing goes on and the failing input is printed.

:func:`judge` turns an outcome into ``None`` (acceptable) or a failure text:

* crash, hang: always a failure;
* a property violation (ops.py): a failure;
* an exception: acceptable only if it is a ValueError (DEMError included),
  TypeError or, for operations on files, an OSError, and its message names one
  of the case's arguments or files (``case["names"]``): anything else is an
  *unclear error*.
"""

from __future__ import annotations

import os
import pickle
import re
import select
import signal
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

WORKER = Path(__file__).with_name("worker.py")

#: exception classes a bad input may raise (by name, anywhere in the MRO)
CLEAR_TYPES = {"ValueError", "TypeError"}
FILE_TYPES = {"OSError"}          # FileNotFoundError, IsADirectoryError, ... for file operations


@dataclass
class Outcome:
    kind: str                      # ok, violation, error, cli, crash, hang
    detail: object = None
    seconds: float = 0.0


class Worker:
    """One worker process; restarted after a crash or a hang."""

    def __init__(self, timeout: float = 20.0, env: dict | None = None):
        self.timeout = timeout
        self.env = dict(os.environ, **(env or {}))
        self.proc = None
        self.calls = 0
        self.restarts = 0
        self._err = tempfile.TemporaryFile()
        self._scratch = None

    def start(self) -> None:
        r_parent, w_child = os.pipe()
        r_child, w_parent = os.pipe()
        self._err.seek(0)
        self._err.truncate()
        # the worker's temporary files go to a directory of the parent's, removed
        # when the process ends: a worker killed in a case (a crash, a hang, the
        # self-tests' segfault) cannot clean up after itself
        self._scratch = tempfile.mkdtemp(prefix="pifuzz-worker-")
        self.proc = subprocess.Popen([sys.executable, str(WORKER), str(r_child), str(w_child)],
                                     pass_fds=(r_child, w_child), stdin=subprocess.DEVNULL,
                                     stdout=self._err, stderr=self._err,
                                     env=dict(self.env, TMPDIR=self._scratch),
                                     start_new_session=True)
        os.close(r_child)
        os.close(w_child)
        self._r, self._w = r_parent, w_parent
        hello = self._receive(max(self.timeout, 60.0))
        if hello is None or hello == "timeout" or hello[0] != "ready":
            self._kill()
            self._ended()
            raise RuntimeError(f"fuzz worker did not start: {self._stderr_tail()}")

    def close(self) -> None:
        if self.proc is None:
            return
        for fd in (self._r, self._w):
            try:
                os.close(fd)
            except OSError:
                pass
        self._r = self._w = None
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self._kill()
        self._ended()

    def _kill(self) -> None:
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)   # the worker's own session: it and its threads only
        except ProcessLookupError:
            pass
        self.proc.wait()

    def _ended(self) -> None:
        """The worker process has ended: close the parent's ends of its pipes (a crashed or hung
        worker's were left open, two descriptors per restart), forget it, remove its scratch
        directory."""
        import shutil

        for fd in (getattr(self, "_r", None), getattr(self, "_w", None)):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._r = self._w = None
        self.proc = None
        if self._scratch is not None:
            shutil.rmtree(self._scratch, ignore_errors=True)
            self._scratch = None

    def _stderr_tail(self, n: int = 1500) -> str:
        self._err.flush()
        self._err.seek(0)
        text = self._err.read().decode("utf-8", "replace")
        return text[-n:]

    def _receive(self, timeout: float):
        deadline = time.monotonic() + timeout
        buf = b""
        need = 8
        size = None
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return "timeout"
            # poll, not select: select() refuses descriptors >= 1024 ("filedescriptor out of range",
            # seen in CI's runtime-checked subset, whose pytest process had that many open by then)
            poller = select.poll()
            poller.register(self._r, select.POLLIN | select.POLLHUP | select.POLLERR)
            if not poller.poll(max(1, int(left * 1000))):
                continue
            chunk = os.read(self._r, max(need - len(buf), 1 << 16) if size is not None else need - len(buf))
            if not chunk:
                return None                         # the worker died
            buf += chunk
            if size is None and len(buf) >= 8:
                size = struct.unpack("<Q", buf[:8])[0]
                buf = buf[8:]
                need = size
            if size is not None and len(buf) >= size:
                return pickle.loads(buf[:size])

    def call(self, case: dict, timeout: float | None = None) -> Outcome:
        if self.proc is None:
            self.start()
        self.calls += 1
        self._err.seek(0, 2)
        mark = self._err.tell()
        data = pickle.dumps(case, protocol=pickle.HIGHEST_PROTOCOL)
        t0 = time.monotonic()
        try:
            os.write(self._w, struct.pack("<Q", len(data)))
            view = memoryview(data)
            while view:
                view = view[os.write(self._w, view):]
            reply = self._receive(timeout or self.timeout)
        except (BrokenPipeError, OSError):
            reply = None
        dt = time.monotonic() - t0
        if reply == "timeout":
            self._kill()
            self._ended()
            self.restarts += 1
            return Outcome("hang", f"no answer within {timeout or self.timeout:.0f} s", dt)
        if reply is None:
            rc = self.proc.wait()
            self._err.seek(mark)
            err = self._err.read().decode("utf-8", "replace")
            self._ended()
            self.restarts += 1
            how = f"killed by signal {-rc} ({signal.Signals(-rc).name})" if rc < 0 else f"exit status {rc}"
            return Outcome("crash", f"worker {how}; stderr:\n{err[-2000:]}", dt)
        return Outcome(reply[0], reply[1:] if len(reply) > 2 else reply[1], dt)


# ---------------------------------------------------------------------------- judgement
def _names_any(message: str, names) -> bool:
    for name in names:
        name = str(name)
        if len(name) <= 3 and name.isidentifier():
            # a short argument name (s, l, lat, nh...) must stand as a word, not inside one
            if re.search(rf"(^|[\s\"`(,/]){re.escape(name)}([\[\s:=,)\"`./]|$)", message):
                return True
        elif name in message:
            return True
    return False


def judge(case: dict, out: Outcome) -> str | None:
    """None when the outcome is acceptable, else a one-paragraph failure description."""
    if out.kind == "ok":
        return None
    if out.kind in ("crash", "hang"):
        return f"{out.kind.upper()}: {out.detail}"
    if out.kind == "violation":
        return f"PROPERTY: {out.detail}"
    names = list(case.get("names", ()))
    if "dem" in case and case["op"] != "cli_run":
        names += ["radii", "f", "re", "rmax"]      # the DEM.from_array arguments of the case's DEM
    if out.kind == "cli":
        msg = out.detail
        if not _names_any(msg, names):
            return f"UNCLEAR CLI ERROR (names none of {list(names)}): {msg}"
        line = case.get("bad_line")
        if line is not None and not re.search(rf"\bline {line}\b", msg):
            return f"CLI ERROR WITHOUT THE LINE NUMBER (line {line} expected): {msg}"
        return None
    mro, msg, tb = out.detail
    allowed = CLEAR_TYPES | (FILE_TYPES if case.get("files") else set())
    if not allowed & set(mro):
        return f"UNEXPECTED EXCEPTION {mro[0]}: {msg}\n{tb}"
    if not _names_any(msg, names):
        return f"UNCLEAR ERROR {mro[0]} (names none of {list(names)}): {msg}\n{tb}"
    if case.get("must_succeed"):
        return f"VALID INPUT REFUSED {mro[0]}: {msg}\n{tb}"
    return None


def signature(case: dict, failure: str) -> str:
    """A short key grouping failures that are the same defect (op + kind + message shape)."""
    first = failure.splitlines()[0]
    first = re.sub(r"/tmp/\S+", "<tmp>", first)
    first = re.sub(r"[-+]?\d[\d.e+-]*", "#", first)
    first = re.sub(r"\[[^\]]*\]", "[...]", first)
    return f"{case['op']}: {first[:160]}"


# ---------------------------------------------------------------------------- reproducers
def _r(x) -> str:
    import numpy as np

    if isinstance(x, np.ndarray):
        return f"np.array({x.tolist()!r}, dtype={str(x.dtype)!r})"
    return repr(x)


def _dem_code(spec: dict) -> list[str]:
    ppd = spec.get("ppd", 1)
    shape = spec.get("shape") or (180 * ppd, 360 * ppd)
    lines = []
    if spec.get("rough"):
        lines.append(f"radii = np.random.default_rng({spec.get('seed', 0)}).normal({spec.get('base', 3390.0)!r}, "
                     f"{spec['rough']!r}, {tuple(shape)!r})")
    else:
        lines.append(f"radii = np.full({tuple(shape)!r}, {spec.get('base', 3390.0)!r})")
    if spec.get("dtype", "float64") != "float64":
        lines.append(f"radii = radii.astype({spec['dtype']!r})")
    for j, i, v in spec.get("spikes", ()):
        lines.append(f"radii[{j} % radii.shape[0], {i} % radii.shape[1]] = {v!r}")
    kw = ", ".join(f"{k}={spec[k]!r}" for k in ("f", "re", "rmax") if k in spec)
    lines.append(f"dem = pi.DEM.from_array(radii{', ' + kw if kw else ''})")
    return lines


def reproducer(case: dict) -> str:
    """Python source that performs the case with plain package calls."""
    op = case["op"]
    head = ["import numpy as np", "import planet_intersect as pi"]
    if op in ("from_array", "radius", "intersect", "mutate"):
        body = _dem_code(case["dem"])
    else:
        body = []
    if op == "from_array":
        body.append("# (then: the DEM must not change when `radii` is overwritten)")
    elif op == "radius":
        body.append(f"dem.radius({_r(case['lat'])}, {_r(case['lon'])})")
        if case.get("per_ray"):
            body.append("# then each (lat, lon) alone must give its element")
    elif op == "intersect":
        kw = dict(case.get("kwargs", {}))
        if kw.get("dem_read_mode") == 1 or case.get("all_configs"):
            body += [f"dem.write('dem', dtype={case['dem'].get('file_dtype', 'float64')!r}, "
                     f"byteorder={case['dem'].get('byteorder', 'little')!r}, overwrite=True)",
                     "dem = pi.DEM.read('dem.hdr')"]
        kws = "".join(f", {k}={_r(v)}" for k, v in kw.items())
        body.append(f"res = pi.intersect(dem, {_r(case['s'])}, {_r(case['l'])}{kws})")
        if case.get("all_configs"):
            body.append("# then the same rays with method stepping/exact x dem_read_mode 0/1 x io x threads 1/2 "
                        "(tests/fuzzing/ops.py CONFIGS)")
        if case.get("per_ray"):
            body.append("# then each ray alone: pi.intersect(dem, s[k], l[k], ...) must give row k")
    elif op == "mutate":
        body.append(f"s, l = {_r(case['s'])}, {_r(case['l'])}")
        body.append("before = pi.intersect(dem, s, l, method='exact')")
        for j, i, v in case["mutations"]:
            body.append(f"radii[{j} % radii.shape[0], {i} % radii.shape[1]] = {v!r}")
        body.append("after = pi.intersect(dem, s, l, method='stepping'); after = pi.intersect(dem, s, l, method='exact')")
    elif op == "detector":
        a = case["args"]
        body.append(f"pi.detector_los({_r(a['l0'])}, {_r(a['q'])}, {_r(a['nh'])}, {_r(a['nv'])}, "
                    f"{_r(a['dh'])}, {_r(a['dv'])})")
    elif op == "read":
        name = case.get("name", "d")
        body += [f"open({name + '.hdr'!r}, 'wb').write({case['header']!r})"]
        if case.get("special"):
            target = f"{name}.{case['special_which']}"
            make = {"dir": f"os.mkdir({target!r})", "fifo": f"os.mkfifo({target!r})",
                    "loop": f"os.symlink({target!r}, {target!r})",
                    "dangling": f"os.symlink({target + '.missing'!r}, {target!r})"}[case["special"]]
            return "\n".join(head + ["import os"] + body[:-1] + [
                f"open({name + '.hdr'!r}, 'wb').write({case['header'][:200]!r})" if case["special_which"] == "dem"
                else "open('d.dem', 'wb').write(b'')", make, f"pi.DEM.read({name + '.hdr'!r})"])
        data = case["data"]
        body.append(f"open({name + '.dem'!r}, 'wb').write({_data_code(data)})")
        target = {"hdr": name + ".hdr", "dem": name + ".dem", "stem": name}[case.get("open", "hdr")]
        body.append(f"dem = pi.DEM.read({target!r})")
        if case.get("rays") is not None:
            s, l = case["rays"]
            body.append(f"s, l = {_r(s)}, {_r(l)}")
            body.append("r0 = pi.intersect(dem, s, l); r1 = pi.intersect(dem, s, l, dem_read_mode=1); "
                        "r2 = pi.intersect(dem, s, l, dem_read_mode=1, io='mmap')")
            if case.get("shrink"):
                body.append(f"open({name + '.dem'!r}, 'r+b').truncate({case['shrink']}); "
                            f"pi.intersect(dem, s, l, dem_read_mode=1)")
    elif op == "cli_run":
        body = _dem_code(case["dem"]) + ["dem.write('cli', overwrite=True)",
                                         f"open('rays.txt', 'wb').write({case['rays']!r})"
                                         if not case.get("special") else f"# rays.txt: a {case['special']}",
                                         "import subprocess",
                                         f"subprocess.run(['planet-intersect', 'run', 'cli.hdr', 'rays.txt', "
                                         f"'--out', 'out'] + {list(case.get('options', []))!r})"]
    if op in _family_ops():
        # the other systems' families (geo.py, grs.py, sim.py): the case dict replayed by its own operation
        head.append("import sys; sys.path.insert(0, 'tests')   # from the repository's root")
        body.append(f"from fuzzing import ops; ops.OPS[{op!r}](case, __import__('pathlib').Path('.'))"
                    "   # case: printed below")
    return "\n".join(head + body)


def _family_ops() -> set:
    from .geo import OPS as geo_ops
    from .grs import OPS as grs_ops
    from .sim import OPS as sim_ops

    return set(geo_ops) | set(grs_ops) | set(sim_ops)


def _data_code(data: bytes) -> str:
    """Short source for a .dem payload: repeated values are written as such."""
    import numpy as np

    for dt in ("<f4", ">f4", "<f8", ">f8"):
        if len(data) % np.dtype(dt).itemsize:
            continue
        a = np.frombuffer(data, dtype=dt)
        vals, first = np.unique(a.view(f"V{a.itemsize}"), return_index=True)
        if 0 < len(vals) <= 6:
            base = a[0]
            extra = [(int(k), a[k]) for k in np.flatnonzero(a.view(f"V{a.itemsize}") != a[:1].view(f"V{a.itemsize}"))]
            if len(extra) <= 6:
                code = f"np.full({a.size}, {float(base)!r}, {dt!r})"
                if extra:
                    sets = "; ".join(f"a[{k}] = {float(v)!r}" for k, v in extra)
                    return f"(lambda a: ({sets}, a.tobytes())[-1])({code})"
                return f"{code}.tobytes()"
    return f"bytes.fromhex({data.hex()!r})" if len(data) < 200 else f"<{len(data)} bytes>"


@dataclass
class Session:
    """A fuzzing session: one worker, counters and the failures found (grouped)."""

    timeout: float = 20.0
    worker: Worker = None
    calls: int = 0
    api_calls: int = 0
    failures: dict = field(default_factory=dict)   # signature -> (case, failure text)
    reported: dict = field(default_factory=dict)   # signatures shrunk and printed by the long mode

    def __post_init__(self):
        if self.worker is None:
            self.worker = Worker(timeout=self.timeout)

    expand: bool = False                            # long mode: more calls per case (per_ray, all_configs)

    def run(self, case: dict) -> str | None:
        if self.expand and case["op"] in ("intersect", "radius"):
            case = dict(case, per_ray=True)
            if case["op"] == "intersect" and not case.get("kwargs"):
                case["all_configs"] = True
        self.last_case = case
        out = self.worker.call(case)
        self.calls += 1
        if out.kind == "ok" and isinstance(out.detail, dict):
            self.api_calls += int(out.detail.get("calls", 1))
        else:
            self.api_calls += 1
        failure = judge(case, out)
        if failure:
            self.failures.setdefault(signature(case, failure), (case, failure))
        return failure

    def close(self):
        self.worker.close()


def describe(case: dict, failure: str) -> str:
    return f"{failure}\n--- reproducer ---\n{reproducer(case)}\n--- case ---\n{_short(case)}"


def _short(case: dict) -> str:
    text = repr({k: v for k, v in case.items() if k not in ("header", "data", "rays")})
    return text if len(text) < 3000 else text[:3000] + " ..."
