"""``rapidds ARGS`` as a process of its own whose interpreter is already warm: the client half
of tests/forkserver.py. Started as ``python -S fork_client.py SOCKET ARGS`` (no site: the
standard library only, ~20 ms), it hands its stdin, stdout, stderr, environment and working
folder to the fork server, which forks a child that runs the CLI with them. Signals sent to
this process are passed on to that child (SIGKILL cannot be caught: the server kills the child
when this process's end of the socket closes), and this process ends as the child ended: its
exit code, or killed by the same signal."""

import contextlib
import json
import os
import signal
import socket
import struct
import sys


def main() -> None:
    path, args = sys.argv[1], sys.argv[2:]
    pid: list[int] = []  # the child's, once the server has said it
    pending: list[int] = []  # signals that came before it

    def forward(signum: int, frame: object) -> None:
        if not pid:
            pending.append(signum)
            return
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid[0], signum)

    # before connecting: a signal sent as soon as the child has printed must not find this
    # process with Python's own handlers (a KeyboardInterrupt here, exit 1)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGUSR1,
                signal.SIGUSR2):
        signal.signal(sig, forward)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.connect(path)
    request = json.dumps({"argv": args, "env": dict(os.environ), "cwd": os.getcwd()}).encode()
    fds = struct.pack("3i", 0, 1, 2)
    sock.sendmsg([struct.pack("!I", len(request)), request],
                 [(socket.SOL_SOCKET, socket.SCM_RIGHTS, fds)])
    reader = sock.makefile("r", encoding="ascii")
    pid.append(int(reader.readline().split()[1]))
    for signum in pending:
        forward(signum, None)
    line = ""
    while not line:
        try:
            line = reader.readline()
        except InterruptedError:  # a signal forwarded while waiting
            continue
        if not line:  # the server is gone: say so, as a crashed interpreter would
            sys.stderr.write("fork_client: the fork server closed the connection\n")
            os._exit(70)
    kind, value = line.split()
    if kind == "signal":
        sig = int(value)
        signal.signal(sig, signal.SIG_DFL)
        os.kill(os.getpid(), sig)
        os._exit(128 + sig)
    os._exit(int(value))


if __name__ == "__main__":
    main()
