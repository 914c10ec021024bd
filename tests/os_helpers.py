"""Test helpers about processes: workers for tests/test_store.py (spawned, so importable by name)
and the privilege drop that makes permission bits count for root (tests run as root here)."""

from __future__ import annotations

import ctypes
import os
import traceback
from typing import Any

_PR_CAPBSET_DROP = 24
_CAP_DAC_OVERRIDE, _CAP_DAC_READ_SEARCH = 1, 2


def obey_permissions() -> None:
    """preexec_fn: root keeps its uid but loses the capabilities that bypass permission bits,
    so the exec'd child is refused a chmod'ed folder or file like any other user."""
    if os.geteuid() != 0:
        return
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (_CAP_DAC_OVERRIDE, _CAP_DAC_READ_SEARCH):
        if libc.prctl(_PR_CAPBSET_DROP, cap, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP) refused")


def can_obey_permissions() -> bool:
    """Whether obey_permissions() works here (it needs CAP_SETPCAP when run as root)."""
    import subprocess
    import sys

    try:
        subprocess.run([sys.executable, "-c", ""], preexec_fn=obey_permissions, check=True)
    except (OSError, subprocess.SubprocessError):
        return False
    return True


def open_rounds(barrier: Any, paths: list[str], worker: int, config: dict[str, Any],
                results: Any) -> None:
    """Per round: wait for every worker, then open the (new) store at once, register the run
    and store this worker's cycle. Reports (worker, round, error or None) per round."""
    import numpy as np

    from rapidds.store import RunStore

    for k, path in enumerate(paths):
        barrier.wait()
        try:
            with RunStore(path) as st:
                st.create_run("r", config)
                st.record_cycle("r", worker, {"worker": worker}, {"a": np.arange(3.0)})
            results.put((worker, k, None))
        except Exception:
            results.put((worker, k, traceback.format_exc(limit=3)))


def kill_run_after(cmd: list[str], db: Any, run_id: str, cycles: int, env: dict[str, str],
                   timeout: float = 240.0) -> int | None:
    """Start ``cmd`` (a ``rapidds run`` storing into ``db``), SIGKILL it once ``cycles`` of
    ``run_id`` are stored (or at ``timeout``); the last stored cycle then, if any."""
    import signal
    import subprocess
    import time

    from rapidds.store import RunStore

    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        if db.exists():
            with RunStore.open_readonly(db) as st:
                if (st.last_cycle(run_id) or -1) + 1 >= cycles:
                    break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with RunStore.open_readonly(db) as st:
        return st.last_cycle(run_id)
