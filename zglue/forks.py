"""A fork server: start many processes of one program without an interpreter and its imports each (issue 29).

Started one `python` at a time, 100 agents on two cores spent about 16 CPU-seconds on their interpreters and
imports alone (150-170 ms each: numpy, the core, zenoh, logging; bench/loop.py's start-up figures,
docs/benchmarks.md). A fork server imports a program's modules once and forks each child from that process. Each
child is still its own process running the same program with the same arguments (its own zenoh session, log
file, process group and exit code), and shows the command line an exec'd child would have (``ps``; set_cmdline);
it only skips the interpreter's start and the imports. The server never opens a zenoh session (zenoh's runtime
does not survive a fork) and runs no thread of its own (numpy's OpenBLAS pool at most, which OpenBLAS stops and
restarts around a fork). Which modules it imports and runs is its caller's to say (fleetctl.run.Children names
them); this module imports none of vsfleet's.
"""

from __future__ import annotations

import importlib
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

#: room left in the server's own command line for a child's (set_cmdline writes there): its -c code ends with a
#: comment of this many spaces
CMDLINE_ROOM = 2048


def set_cmdline(args: list[str]) -> bool:
    """Show ``args`` as this process's command line (/proc/self/cmdline, ``ps``), written over the one it started
    with, NUL-padded; True if it fitted and was written. Linux only; anything else leaves the old one."""
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        start, end = int(fields[45]), int(fields[46])   # arg_start, arg_end (fields 48 and 49 of stat)
        data = b"\0".join(a.encode() for a in args) + b"\0"
        if len(data) > end - start:
            return False
        with open("/proc/self/mem", "r+b", buffering=0) as mem:
            mem.seek(start)
            mem.write(data + b"\0" * (end - start - len(data)))
        return True
    except (OSError, ValueError, IndexError):
        return False


def serve_forks(modules: list[str]) -> int:
    """The fork server's process (ForkServer starts it): import ``modules``, then for each request on stdin
    (a JSON line ``{"module", "argv", "log", "cwd"}``) fork a child that runs ``module.main(argv)`` with its
    output appended to ``log``, in a session of its own, and answer ``started PID``; report each child's end as
    ``exit PID CODE`` (CODE as Popen.returncode: -N for signal N). Ends once stdin closes and every child ended.
    A request may also carry ``title``, the command line the child shows (set_cmdline)."""
    import gc  # noqa: PLC0415
    import select  # noqa: PLC0415
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # as fleetctl/cli.py: no BLAS thread pool (before numpy)
    for name in modules:
        importlib.import_module(name)
    gc.freeze()  # what was imported stays out of the children's collections: fewer pages copied
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C is the parent's to handle; it closes our stdin
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # wakes the select through wake_w
    live: set[int] = set()
    buf, open_in = b"", True

    def say(line: str) -> None:
        os.write(1, line.encode() + b"\n")

    def reap() -> None:
        while live:
            pid, status = os.waitpid(-1, os.WNOHANG)
            if pid == 0:
                return
            live.discard(pid)
            say(f"exit {pid} {os.waitstatus_to_exitcode(status)}")

    say("ready")
    while open_in or live:
        ready, _, _ = select.select([0, wake_r] if open_in else [wake_r], [], [])
        if wake_r in ready:
            os.read(wake_r, 4096)
        reap()
        if 0 not in ready:
            continue
        chunk = os.read(0, 65536)
        if not chunk:
            open_in = False
            continue
        buf += chunk
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            req = json.loads(line)
            ready_r, ready_w = os.pipe()  # the child says when it has become itself (its session, title, log)
            pid = os.fork()
            if pid == 0:
                os.close(ready_r)
                _forked_child(req, (wake_r, wake_w), ready_w)
            os.close(ready_w)
            os.read(ready_r, 1)  # b"" if it ended first
            os.close(ready_r)
            live.add(pid)
            say(f"started {pid}")
    return 0


def _forked_child(req: dict, close_fds: tuple[int, ...], ready: int) -> None:
    """In a forked child: become the program ``req`` names and exit with its code (never returns). Once its
    session, command line and output are its own, it writes a byte on ``ready`` (so the process a caller is told
    of already shows the command line it was started with, as an exec'd child does)."""
    code = 1
    try:
        signal.set_wakeup_fd(-1)
        for fd in close_fds:
            os.close(fd)
        for sig in (signal.SIGCHLD, signal.SIGTERM):
            signal.signal(sig, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        os.setsid()
        out = os.open(req["log"], os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        nul = os.open(os.devnull, os.O_RDONLY)
        os.dup2(nul, 0)
        os.dup2(out, 1)
        os.dup2(out, 2)
        os.close(out)
        os.close(nul)
        if req.get("cwd"):
            os.chdir(req["cwd"])
        sys.argv = [req["module"], *req["argv"]]
        if req.get("title"):
            set_cmdline(req["title"])
        os.write(ready, b"1")
        os.close(ready)
        code = int(importlib.import_module(req["module"]).main(req["argv"]) or 0)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # noqa: BLE001 - said in the child's log, as an exec'd child's traceback would be
        import traceback  # noqa: PLC0415
        traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)


class ForkedChild:
    """A child of the fork server, with the part of subprocess.Popen's interface Children uses."""

    def __init__(self, server: "ForkServer", pid: int) -> None:
        self.server, self.pid = server, pid

    @property
    def returncode(self) -> int | None:
        return self.poll()

    def poll(self) -> int | None:
        return self.server.exit_code(self.pid)

    def wait(self, timeout: float | None = None) -> int:
        code = self.server.wait_exit(self.pid, timeout)
        if code is None:
            raise subprocess.TimeoutExpired(f"pid {self.pid}", timeout)
        return code

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:
                pass

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class ForkServer:
    """A `python` that imported ``modules`` once and forks children that run one of them (serve_forks)."""

    def __init__(self, modules: list[str], log_path: Path, cwd: Path | None = None) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        code = ("import sys; from vsfleet.zglue.forks import serve_forks; raise SystemExit(serve_forks(sys.argv[1:]))"
                " #" + " " * CMDLINE_ROOM)
        with log_path.open("ab") as err:
            self.proc = subprocess.Popen([sys.executable, "-c", code, *modules], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=err, env=env, cwd=cwd,
                                         start_new_session=True)
        self.cwd = cwd
        self._started: queue.Queue = queue.Queue()
        self._codes: dict[int, int] = {}
        self._cond = threading.Condition()
        self._lock = threading.Lock()
        self._gone = False
        self._reader = threading.Thread(target=self._read, name="fork-server", daemon=True)
        self._reader.start()
        first = self._started.get(timeout=120)
        if first != "ready":
            raise RuntimeError(f"the fork server did not start ({first}); see {log_path}")

    def _read(self) -> None:
        for raw in self.proc.stdout:
            word, *rest = raw.decode().split()
            if word == "exit":
                with self._cond:
                    self._codes[int(rest[0])] = int(rest[1])
                    self._cond.notify_all()
            else:
                self._started.put(raw.decode().strip())
        with self._cond:
            self._gone = True
            self._cond.notify_all()
        self._started.put("gone")

    def start(self, module: str, argv: list[str], log: Path, cwd: Path | None = None,
              title: list[str] | None = None) -> ForkedChild:
        """Fork a child running ``module.main(argv)``, its output appended to ``log``; ``title``: the command line
        it shows (set_cmdline), e.g. the one that would have started it as its own python."""
        req = {"module": module, "argv": list(argv), "log": str(log), "cwd": str(cwd or self.cwd or ""),
               "title": list(title or ())}
        with self._lock:
            self.proc.stdin.write(json.dumps(req).encode() + b"\n")
            self.proc.stdin.flush()
            answer = self._started.get(timeout=60)
        if not answer.startswith("started "):
            raise RuntimeError(f"the fork server could not start {module} {argv}: {answer}")
        return ForkedChild(self, int(answer.split()[1]))

    def exit_code(self, pid: int) -> int | None:
        with self._cond:
            if pid in self._codes:
                return self._codes[pid]
            if self._gone and not os.path.exists(f"/proc/{pid}"):
                return -signal.SIGKILL  # the server died first: the child's own code is lost
            return None

    def wait_exit(self, pid: int, timeout: float | None) -> int | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while pid not in self._codes and not self._gone:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return None
                self._cond.wait(left)
        return self.exit_code(pid)

    def close(self, timeout_s: float = 10.0) -> None:
        """Close the server's stdin: it ends once its children have ended (stop them first)."""
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
