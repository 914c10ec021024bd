"""A fork server for the CLI processes the tests start: ``rapidds`` with its heavy imports
(torch, diffusers, scipy, pandas, matplotlib: ~4-5 CPU s a process on this machine) done once.

``python forkserver.py SOCKET`` imports them, then listens on the Unix socket ``SOCKET``. Each
connection (tests/fork_client.py) sends its argv, environment, working folder and its stdin,
stdout and stderr (SCM_RIGHTS); the server forks a child that takes them and runs
``rapidds.cli.main`` as ``python -c "from rapidds.cli import main; main()" ARGS`` would, and
sends the child's pid, then how it ended. The child is a real process running the real CLI
with what a fresh interpreter would have: the environment, the folder, its own ``__main__``,
standard streams built from ``PYTHONUNBUFFERED`` as the interpreter builds them, default signal
handlers, the interpreter's exit (non-daemon threads joined, atexit handlers, flushed streams).
What it shares with the server is the modules already imported, so a setting read at import
time is the server's: it imports nothing that reads one (mujoco reads ``MUJOCO_GL``, zenoh
starts threads: neither is imported here), and the server is started with no threads, so
forking is safe. A test of start-up itself (what a command imports, a fresh interpreter's
behaviour) starts a plain process; ``RAPIDDS_TEST_FORK=off`` makes every test do so."""

from __future__ import annotations

import atexit
import builtins
import contextlib
import io
import json
import os
import selectors
import signal
import socket
import struct
import sys
import threading
import traceback
import types

WARM = ("rapidds.cli", "rapidds.cli.run", "rapidds.loop.run", "rapidds.motion.policy",
        "rapidds.plots.gantt", "scipy.stats", "pandas", "ortools.sat.python.cp_model")


def _recv_request(conn: socket.socket) -> tuple[dict, list[int]]:
    size = struct.calcsize("3i")
    head, anc, _, _ = conn.recvmsg(4, socket.CMSG_SPACE(size))
    fds: list[int] = []
    for level, kind, data in anc:
        if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
            fds.extend(struct.unpack(f"{len(data) // 4}i", data[:len(data) - len(data) % 4]))
    (n,) = struct.unpack("!I", head)
    body = b""
    while len(body) < n:
        chunk = conn.recv(n - len(body))
        if not chunk:
            raise ConnectionError("the client left mid-request")
        body += chunk
    return json.loads(body), fds


def _streams(unbuffered: bool) -> None:
    """sys.stdin/stdout/stderr on fds 0-2, as the interpreter makes them at start-up."""
    def out(fd: int, err: bool) -> io.TextIOWrapper:
        tty = os.isatty(fd)
        raw = io.FileIO(fd, "w", closefd=False)
        binary = raw if unbuffered else io.BufferedWriter(raw)
        return io.TextIOWrapper(binary, encoding="utf-8",  # type: ignore[arg-type]
                                errors="backslashreplace" if err else "strict",
                                line_buffering=tty or err, write_through=unbuffered)

    sys.stdin = sys.__stdin__ = io.TextIOWrapper(
        io.BufferedReader(io.FileIO(0, "r", closefd=False)), encoding="utf-8")
    sys.stdout = sys.__stdout__ = out(1, False)
    sys.stderr = sys.__stderr__ = out(2, True)


def _die_by(sig: int) -> None:
    signal.signal(sig, signal.SIG_DFL)
    os.kill(os.getpid(), sig)
    os._exit(128 + sig)


def _child(request: dict, fds: list[int], close: list[socket.socket]) -> None:
    """Become ``python -c 'from rapidds.cli import main; main()' ARGS``; never returns."""
    code = 1
    try:
        for s in close:
            s.close()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGCHLD):
            signal.signal(sig, signal.SIG_DFL)
        for target, fd in enumerate(fds):
            os.dup2(fd, target)
            os.close(fd)
        os.chdir(request["cwd"])
        os.environ.clear()
        os.environ.update(request["env"])
        extra = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
        sys.path[:] = ["", *extra, *(p for p in sys.path[1:] if p not in extra)]
        _streams(bool(os.environ.get("PYTHONUNBUFFERED")))
        import numpy as np

        np.random.seed()  # a fresh interpreter's legacy global stream is seeded from the OS
        main = types.ModuleType("__main__")
        main.__builtins__ = builtins  # type: ignore[attr-defined]
        sys.modules["__main__"] = main
        sys.argv = ["-c", *request["argv"]]
        try:
            exec("from rapidds.cli import main; main()", main.__dict__)
            code = 0
        except SystemExit as exc:
            if exc.code is None:
                code = 0
            elif isinstance(exc.code, int):
                code = exc.code & 0xFF
            else:
                print(exc.code, file=sys.stderr)
                code = 1
        except KeyboardInterrupt:
            traceback.print_exc()
            _finish()
            _die_by(signal.SIGINT)
        except BaseException:
            sys.excepthook(*sys.exc_info())
            code = 1
        _finish()
    except BaseException:
        traceback.print_exc()
    finally:
        os._exit(code)


def _finish() -> None:
    """The interpreter's own exit: join non-daemon threads, run atexit, flush the streams."""
    try:
        threading._shutdown()  # type: ignore[attr-defined]
    except BaseException:
        traceback.print_exc()
    atexit._run_exitfuncs()
    for s in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            s.flush()


def _threads() -> int:
    return len(os.listdir(f"/proc/{os.getpid()}/task"))


def serve(path: str) -> None:
    import importlib

    import numpy  # noqa: F401  (OpenBLAS starts its pools here and is fork-safe:
    import scipy.linalg  # noqa: F401  it shuts them down at a fork and starts them again)

    pools = _threads()
    for name in WARM:
        importlib.import_module(name)
    if _threads() != pools or threading.active_count() != 1:
        raise SystemExit(f"forkserver: {_threads() - pools} threads started by the imports; "
                         "forking would not be safe")
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C of the test run is the tests'
    signal.signal(signal.SIGTERM, _stop)
    parent = os.getppid()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path + ".tmp")
    listener.listen(64)
    os.rename(path + ".tmp", path)  # ready: the socket appears once it accepts
    try:
        _loop(listener, parent)
    except SystemExit:  # stopped (SIGTERM)
        pass
    finally:  # the test run is gone or stops the server: nothing it started outlives it
        for pid in _children:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)  # skips torch's ~2 s of interpreter teardown at every session's end


def _stop(signum: int, frame: object) -> None:
    raise SystemExit(0)


_children: dict[int, socket.socket | None] = {}
"""The forked children not yet reaped, each with its client's connection (None once the client
has gone)."""


def _loop(listener: socket.socket, parent: int) -> None:
    sel = selectors.DefaultSelector()
    sel.register(listener, selectors.EVENT_READ)
    children = _children
    while os.getppid() == parent:
        for key, _ in sel.select(timeout=0.02):
            if key.fileobj is listener:
                conn, _ = listener.accept()
                try:
                    request, fds = _recv_request(conn)
                except (OSError, ValueError, struct.error):
                    conn.close()
                    continue
                sys.stdout.flush()
                sys.stderr.flush()
                pid = os.fork()
                if pid == 0:
                    _child(request, fds, [listener, conn, *filter(None, children.values())])
                for fd in fds:
                    os.close(fd)
                conn.sendall(f"pid {pid}\n".encode())
                children[pid] = conn
                sel.register(conn, selectors.EVENT_READ, pid)
            else:  # the client's end closed: it was killed, so is its child
                pid, conn = key.data, key.fileobj
                sel.unregister(conn)
                if children.get(pid) is not None:
                    children[pid] = None
                    os.kill(pid, signal.SIGKILL)
                conn.close()  # type: ignore[union-attr]
        while children:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                break
            if pid == 0:
                break
            conn = children.pop(pid, None)
            if conn is not None:
                sel.unregister(conn)
                said = (f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status)
                        else f"exit {os.waitstatus_to_exitcode(status)}")
                with contextlib.suppress(OSError):
                    conn.sendall(f"{said}\n".encode())
                conn.close()


if __name__ == "__main__":
    serve(sys.argv[1])
