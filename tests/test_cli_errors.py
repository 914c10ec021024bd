"""The CLI's error path: every bad input, refused file or closed pipe ends in one line (or none)
and exit code 2 (1 for a closed pipe), never a traceback; a policy producing NaN is an error,
not a result."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch
from cli_helpers import PLAIN, cli_cmd
from cli_helpers import run_main as _main

from rapidds.errors import CheckpointError
from rapidds.motion.config import DiffusionConfig
from rapidds.motion.normalizer import MinMaxNormalizer
from rapidds.motion.policy import DiffusionPolicy
from rapidds.motion.steering import SteerRequest, steer


def _one_line_error(code: int, err: str, *needles: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert err.startswith("rapidds: error: ")
    for n in needles:
        assert n in err, err


# -- pipes ------------------------------------------------------------------------------------
def test_help_into_a_closed_pipe_ends_quietly():
    """The reader is gone before the first byte (deterministic EPIPE): no traceback, no
    message, exit 1 (as Python does); and the user's own ``| head -1`` shows one clean line."""
    proc = subprocess.Popen([*PLAIN, "run", "--help"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # type: ignore[union-attr]
    err = proc.stderr.read()  # type: ignore[union-attr]
    assert proc.wait(timeout=120) == 1
    assert err == ""
    res = subprocess.run(["bash", "-c", 'exec "$@" run --help | head -1', "bash", *PLAIN],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert len(res.stdout.splitlines()) == 1


# -- files the system refuses -----------------------------------------------------------------
def test_out_that_is_a_file_or_below_one(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("mine")
    code, _, err = _main(capsys, "run", "--cycles", "1", "--out", str(afile))
    _one_line_error(code, err, f"{afile} exists and is not a folder")
    code, _, err = _main(capsys, "run", "--cycles", "1", "--out", str(afile / "sub"))
    _one_line_error(code, err, "part of that path is a file")
    assert afile.read_text() == "mine"


def test_corrupt_run_store_is_refused_untouched(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    store = out / "run.sqlite"
    store.write_bytes(np.random.default_rng(0).bytes(3000))
    before = hashlib.sha256(store.read_bytes()).digest()
    code, _, err = _main(capsys, "run", "--cycles", "1", "--out", str(out), "--resume")
    _one_line_error(code, err, f"{store}: not a rapidds run store")
    assert hashlib.sha256(store.read_bytes()).digest() == before


_TWO_RUNS = """
import sys
from rapidds.cli import main
for out in sys.argv[1:]:
    sys.argv = ["rapidds", "run", "--cycles", "1", "--out", out]
    try:
        main()
    except SystemExit as exc:
        print(exc.code)
"""


def test_read_only_out_is_one_line(tmp_path):
    """``--out`` on read-only media (a folder nobody may write; the child cannot override the
    permission bits even as root): exit 2 with the path and the system's reason."""
    import os_helpers

    if not os_helpers.can_obey_permissions():
        pytest.skip("cannot drop CAP_DAC_OVERRIDE here, so permission bits are not enforced")
    media = tmp_path / "media"
    media.mkdir()
    media.chmod(0o555)
    try:  # both in one child: a CLI process takes seconds to start
        res = subprocess.run([sys.executable, "-c", _TWO_RUNS, str(media / "run"), str(media)],
                             capture_output=True, text=True, timeout=120,
                             preexec_fn=os_helpers.obey_permissions)
    finally:
        media.chmod(0o755)
    assert res.stdout.split() == ["2", "2"], res.stderr
    first, second = res.stderr.splitlines(keepends=True)
    _one_line_error(2, first, str(media / "run"), "Permission denied")
    _one_line_error(2, second, str(media / ".lock"), "Permission denied")
    assert list(media.iterdir()) == []


@pytest.mark.parametrize("address", ["bogus://x", "tcp://", "tcp://[::1", "tcp://host",
                                     "tcp://127.0.0.1:99999"])
def test_bad_scheduler_address_is_one_line_and_writes_nothing(tmp_path, capsys, address):
    out = tmp_path / "study"
    code, _, err = _main(capsys, "ablation", "--out", str(out), "--trials", "1", "--cycles", "1",
                         "--humans", "fast-middle", "--adapt", "none", "--scheduler", address)
    _one_line_error(code, err, f"--scheduler {address!r}")
    assert not out.exists()


def test_typer_exceptions_found_in_the_installed_layout():
    from rapidds.cli import _typer_errors

    for name in ("Abort", "UsageError", "ClickException", "NoArgsIsHelpError"):
        assert _typer_errors(name), name
    import typer

    assert typer.Abort in _typer_errors("Abort")


# -- non-finite policies ----------------------------------------------------------------------
def _policy(nan: bool) -> DiffusionPolicy:
    cfg = DiffusionConfig(horizon=8, state_dim=2, task_names=("a", "b"), down_dims=(8, 16),
                          step_embed_dim=8, num_train_timesteps=20, num_inference_steps=4,
                          device="cpu")
    policy = DiffusionPolicy.from_config(cfg, MinMaxNormalizer(np.zeros(2), np.ones(2)))
    if nan:
        with torch.no_grad():
            for p in policy.model.parameters():
                p.fill_(float("nan"))
    return policy


def test_nan_policy_is_an_error_not_a_result(tmp_path, capsys):
    torch.set_num_threads(1)
    with pytest.raises(CheckpointError, match="non-finite trajectories"):
        steer(_policy(nan=True), SteerRequest("a", 4), lambda x: np.zeros(len(x)), num_candidates=2,
              generator=0)
    good, bad = tmp_path / "good", tmp_path / "bad"
    _policy(nan=False).save(good)
    _policy(nan=True).save(bad)
    for steering in ([], ["--steer-cost", "0.5,0.5"]):
        code, out, err = _main(capsys, "sample", "--policy", str(good), "--task", "a", "-n",
                               "2", "--json", *steering)
        assert code == 0, err  # the same network with finite weights samples fine
        code, out, err = _main(capsys, "sample", "--policy", str(bad), "--task", "a", "-n",
                               "2", "--json", *steering)
        _one_line_error(code, err, "policy produced non-finite trajectories; the checkpoint "
                        "is corrupt or diverged")
        assert out == ""


def test_loop_with_a_nan_policy_stops_with_one_line(tmp_path, fetch_world):
    """``rapidds run`` with a diverged policy: no 'completion 0.0' cycle is stored or printed."""
    bad = tmp_path / "bad"
    shutil.copytree(fetch_world.bundled_policy(), bad)
    policy = DiffusionPolicy.load(bad, device="cpu")
    with torch.no_grad():
        next(iter(policy.model.parameters())).fill_(float("nan"))
    policy.save(bad)
    out = tmp_path / "run"
    res = subprocess.run(cli_cmd("run", "--cycles", "1", "--policy", str(bad), "--out",
                          str(out), "--json", "--population", "4", "--generations", "1",
                          "--samples", "2", "--particles", "1", "--candidates", "2"),
                         capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONUNBUFFERED": "1"})
    _one_line_error(res.returncode, res.stderr, "non-finite trajectories")
    assert res.stdout == ""
    from rapidds.store import RunStore

    with RunStore.open_readonly(out / "run.sqlite") as st:
        assert st.records() == []
