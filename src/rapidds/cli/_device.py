"""The one ``--device`` option of every command that loads a policy (run, ablation, case-study,
play, study simulate, deploy, observe): its name, choices and help come from
:attr:`rapidds.loop.config.RunConfig.device`, so the commands cannot drift apart."""

from __future__ import annotations

from typing import Annotated, get_args

import typer

from rapidds.loop.config import DEVICE_HELP, Device


def check_device(value: str) -> str:
    """``value`` when it names a device this machine has; a usage error (one line, exit 2)
    before anything is loaded or a worker started otherwise. Torch is imported only to ask
    for a GPU, so ``--help`` stays light."""
    if value not in get_args(Device):
        raise typer.BadParameter(f"one of {', '.join(get_args(Device))}, got {value!r}")
    if value == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise typer.BadParameter("cuda requested but no CUDA GPU is available here")
    return value


def check_optional_device(value: str | None) -> str | None:
    """:func:`check_device` for the commands whose default is the checkpoint's or config's own
    device (train-policy, sample): None passes."""
    return None if value is None else check_device(value)


DeviceOption = Annotated[str, typer.Option("--device", help=DEVICE_HELP, callback=check_device)]
"""``device: DeviceOption = "auto"`` in a command's signature."""
