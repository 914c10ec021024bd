"""How a world's tensor terms read a steering batch: its rows in one equal block per request,
each block with its request's task (:class:`~rapidds.motion.diffusion_motion.DeviceTerms`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

__all__ = ["task_rows"]


def task_rows(per_task: Mapping[str, Tensor], tasks: Sequence[str], n: int) -> Tensor:
    """(n, *shape): ``per_task[tasks[k]]`` for every row of block k, the n rows being
    ``len(tasks)`` equal blocks; a view when every block has one task (one kernel less on a
    GPU), else one concatenation. ValueError when the rows do not split so."""
    if not tasks or n % len(tasks):
        raise ValueError(f"{n} rows do not split into blocks for {len(tasks)} tasks")
    shape = per_task[tasks[0]].shape
    if len(set(tasks)) == 1:
        return per_task[tasks[0]].expand(n, *shape)
    return torch.cat([per_task[task].expand(n // len(tasks), *shape) for task in tasks])
