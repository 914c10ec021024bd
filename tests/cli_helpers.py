"""Running the CLI inside the test process, as the tests of its answers need it."""

from __future__ import annotations

import sys
from typing import Any


def run_main(capsys: Any, *args: str) -> tuple[int, str, str]:
    """Run ``rapidds ARGS`` in this process: (exit code, stdout, stderr)."""
    from rapidds.cli import main

    old = sys.argv
    sys.argv = ["rapidds", *args]
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    finally:
        sys.argv = old
    out, err = capsys.readouterr()
    return code, out, err
