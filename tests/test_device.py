"""The device option: one definition shared by every command that loads a policy, checked
before anything loads; the device is a run setting that is never stored, so records, stored
settings and ``--resume`` do not depend on it."""

from __future__ import annotations

import pytest
import torch
from cli_helpers import run_main

from rapidds.loop.config import DEVICE_HELP, RunConfig
from rapidds.loop.run import AdaptiveRun, load_policy
from rapidds.store import RunStore
from rapidds.worlds.registry import make_world

# every command that loads a policy, with the arguments it needs to get as far as its options
COMMANDS = [
    ["run", "fetch", "--cycles", "1"],
    ["ablation", "--out", "{tmp}/ab", "--trials", "1", "--workers", "1"],
    ["case-study", "painting", "--out", "{tmp}/cs"],
    ["play"],
    ["study", "simulate", "--out", "{tmp}/st"],
    ["deploy", "painting", "--out", "{tmp}/dp"],
    ["observe", "{tmp}/ob", "--bag", "{tmp}/bag"],
]


def _one_line(code: int, err: str, *needles: str) -> None:
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("rapidds: error: "), err
    assert "Traceback" not in err
    for n in needles:
        assert n in err, err


@pytest.mark.parametrize("args", COMMANDS, ids=lambda a: a[0] + (a[1] if a[0] == "study" else ""))
def test_an_unknown_device_is_one_line_exit_2(capsys, tmp_path, args):
    code, _, err = run_main(capsys, *[a.format(tmp=tmp_path) for a in args], "--device", "tpu")
    _one_line(code, err, "--device", "one of auto, cpu, cuda")
    assert not any(tmp_path.iterdir())  # refused before any folder was made


@pytest.mark.parametrize("args", COMMANDS, ids=lambda a: a[0] + (a[1] if a[0] == "study" else ""))
def test_cuda_without_a_gpu_is_one_line_exit_2(capsys, tmp_path, args):
    from rapidds.cli._device import check_device

    if torch.cuda.is_available():  # a machine with a GPU: the option is accepted
        assert check_device("cuda") == "cuda"
        return
    code, _, err = run_main(capsys, *[a.format(tmp=tmp_path) for a in args], "--device", "cuda")
    _one_line(code, err, "--device", "no CUDA GPU")
    assert not any(tmp_path.iterdir())


def test_the_device_is_a_setting_never_stored():
    cfg = RunConfig(world="fetch", device="cpu")
    assert cfg.device == "cpu" and "device" not in cfg.model_dump()
    resolved = cfg.resolved(make_world("fetch"))
    assert resolved.device == "cpu"  # replace() keeps a field the dumps leave out
    assert RunConfig(**resolved.model_dump()).device == "auto"
    assert RunConfig.model_fields["device"].description == DEVICE_HELP  # the CLI's help too


def test_a_run_resumes_on_another_device(tmp_path):
    """Stored on one device, continued on another: the stored settings hold no device, so the
    resume is not refused and the cycle count carries on."""
    world = make_world("fetch")
    policy = load_policy(world, device="cpu")
    assert policy.device.type == "cpu"
    base = dict(world="fetch", cycles=2, population=4, generations=2, samples=4, particles=1,
                candidates=2)
    with RunStore(tmp_path / "run.sqlite") as store:
        run = AdaptiveRun(RunConfig(**base, device="auto"), policy, store, world=world)
        run.step()
        stored = store.run_config(run.config.run_id)
        assert stored is not None and "device" not in stored
    with RunStore(tmp_path / "run.sqlite") as store:
        again = AdaptiveRun(RunConfig(**base, device="cpu"), policy, store, world=world)
        assert again.next_cycle == 1 and again.config.device == "cpu"
