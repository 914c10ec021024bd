"""Calls replayed from CUDA graphs: on a GPU, sampling's network passes and the steering's
on-device value are each a few hundred small kernels, each launched by the host, and the host
is what a cycle there waits for (docs/benchmarks.md, "The GPU measured"). A captured call
launches them all at once. The same kernels on the same inputs give the same outputs."""

from __future__ import annotations

import threading
from collections.abc import Callable

import torch
from torch import Tensor

Layout = tuple[tuple[torch.Size, torch.dtype, torch.device], ...]


class _Graph:
    """One captured call: its graph and the static tensors it reads and writes."""

    def __init__(self, graph: torch.cuda.CUDAGraph, inputs: tuple[Tensor, ...], out: Tensor):
        self.graph, self.inputs, self.out = graph, inputs, out

    def __call__(self, *args: Tensor) -> Tensor:
        for static, given in zip(self.inputs, args, strict=True):
            static.copy_(given)
        self.graph.replay()
        # a copy: the next replay overwrites ``out``, and callers keep what they were given
        return self.out.clone()


class Replayed:
    """``fn`` (tensors in, a tensor out, nothing read back to the host), its calls on a GPU
    replayed from CUDA graphs, one per layout (shapes, dtypes, device) of its inputs.

    A layout is captured the ``capture_at``-th time it comes (calls seen once cost no
    capture), at most ``max_graphs`` of them; the capture's warm-up call, on a side stream as
    capture requires, answers that call. Everything else ``fn`` reads (weights, tables) is
    read where it lay at capture, so it must stay there, unchanged in value unless changed in
    place: wrap a new ``fn`` when it changes. Off a GPU, calls run as they are. When a capture
    fails, every later call runs as it is and ``note`` says why. Calls from several threads
    take turns: a replay's static inputs are shared, and one thread's copy into them must not
    land before another's replay has read them (threads on one stream, as PyTorch's default).
    """

    def __init__(self, fn: Callable[..., Tensor], capture_at: int = 2, max_graphs: int = 64):
        self.fn, self.capture_at, self.max_graphs = fn, capture_at, max_graphs
        self.graphs: dict[Layout, _Graph] = {}
        self.seen: dict[Layout, int] = {}
        self.note = ""
        self._side: torch.cuda.Stream | None = None  # where warm-up and capture run
        self._turn = threading.Lock()

    def __call__(self, *args: Tensor) -> Tensor:
        with self._turn:
            return self._call(args)

    def _call(self, args: tuple[Tensor, ...]) -> Tensor:
        layout = tuple((a.shape, a.dtype, a.device) for a in args)
        graph = self.graphs.get(layout)
        if graph is not None:
            return graph(*args)
        self.seen[layout] = seen = self.seen.get(layout, 0) + 1
        if (self.note or seen < self.capture_at or len(self.graphs) >= self.max_graphs
                or any(a.device.type != "cuda" for a in args)
                or torch.cuda.is_current_stream_capturing()):
            return self.fn(*args)
        return self._capture(layout, args)

    def _capture(self, layout: Layout, args: tuple[Tensor, ...]) -> Tensor:
        # normal tensors, not inference tensors: a replay outside inference mode (``sample``
        # after ``steer``) may then still copy into them
        with torch.inference_mode(False):
            inputs = tuple(a.clone() for a in args)
        device = args[0].device
        here = torch.cuda.current_stream(device)
        if self._side is None:
            self._side = torch.cuda.Stream(device)
        side = self._side
        side.wait_stream(here)
        for a in inputs:  # made on this stream, used on the side one too
            a.record_stream(side)
        with torch.cuda.stream(side):
            out = self.fn(*inputs)
        here.wait_stream(side)
        out.record_stream(here)  # made on the side stream, used on this one
        # capture_begin/end rather than ``torch.cuda.graph``, whose entry synchronises the
        # device and empties the allocator's cache, a cost every later eager call would pay
        graph = torch.cuda.CUDAGraph()
        try:
            with torch.cuda.stream(side):
                # thread_local: another thread's CUDA calls (a server's) neither break this
                # capture nor fail because of it
                graph.capture_begin(capture_error_mode="thread_local")
                try:
                    static_out = self.fn(*inputs)
                finally:
                    graph.capture_end()
        except RuntimeError as exc:
            self.note = f"CUDA graph capture failed, calls run eagerly: {exc}".splitlines()[0]
            torch.cuda.synchronize(device)
            return out
        self.graphs[layout] = _Graph(graph, inputs, static_out)
        return out
