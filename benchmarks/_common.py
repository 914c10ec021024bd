"""Shared by the benchmark scripts: the machine they ran on, and their section of
docs/benchmarks.md (each script rewrites only its own ``## `` section)."""

from __future__ import annotations

import os
import platform
import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"


def middle_start(policy, rows: int | None = None):
    """A start pose in the middle of ``policy``'s normalised range, inside its demonstrations'
    span: (state_dim,), or (rows, state_dim); None for a policy that takes no start."""
    import torch

    cfg = policy.config
    if not cfg.start_conditioned:
        return None
    shape = (cfg.state_dim,) if rows is None else (rows, cfg.state_dim)
    return policy.normalizer.unnormalize(torch.zeros(shape)).numpy()


def sync(device) -> None:
    """Wait for ``device`` (a name or a torch.device) to finish its queued work: a GPU's
    kernels run after the host has moved on, so a timing must end here; nothing on a CPU."""
    import torch

    if torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


def child_env(*paths: str | Path, **extra: str) -> dict[str, str]:
    """This process's environment for a child on ``paths`` first, then the inherited
    ``PYTHONPATH`` (a GPU machine carries the packages it lacks there: design notes, 11)."""
    inherited = os.environ.get("PYTHONPATH")
    path = os.pathsep.join([*map(str, paths), *([inherited] if inherited else [])])
    return {**os.environ, "PYTHONPATH": path, **extra}


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def load_average() -> str:
    try:
        return Path("/proc/loadavg").read_text().split()[0]
    except OSError:
        return "n/a"


def parse_seeds(text: str) -> list[int]:
    """``"0-7"`` (a range, both ends included) or ``"0,2,5"`` -> the seeds."""
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def update_docs_section(heading: str, body: str, path: Path = DOCS) -> None:
    """Replace (or append) the section that starts with ``heading`` (a ``## `` line)."""
    section = f"{heading}\n\n{body.strip()}\n"
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    pat = re.compile(rf"^{re.escape(heading)}\n.*?(?=^## |\Z)", re.S | re.M)
    if pat.search(text):
        text = pat.sub(lambda _: section + "\n", text).rstrip("\n") + "\n"
    else:
        text = text.rstrip("\n") + "\n\n" + section
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
