"""Inference-only copy of the temporal U-Net: the same function as
:class:`~rapidds.motion.unet.TemporalUnet1d` with fewer and cheaper CPU operations.

Steering sends batches of a few hundred trajectories through a network of a few thousand
weights, so on a CPU the time goes less to the convolutions than to what surrounds them
(measured on the bundled policy, 256 rows, one thread: ``nn.Mish`` alone took 43 % of a pass,
convolutions 37 %). This copy changes how the function is computed, never what it computes:

- Mish rewritten exactly with one vectorised sigmoid (PyTorch's own Mish kernel evaluates
  ``tanh`` and ``log1p`` element by element and was four times slower). Off the CPU the
  native kernel is kept: there each of the rewrite's eight operations is a kernel the host
  launches, and launches, not arithmetic, bound a pass.
- The FiLM conditioning, identical for every block, goes through Mish once and through all
  blocks' FiLM layers as one matrix product instead of twelve; the step encoding is computed
  once when the whole batch shares its diffusion step, as in sampling.
- The transposed convolution runs as an ordinary one (see :class:`_Upsample`).
- FiLM and the residual sum run in place on the block outputs.

Outputs agree with the training network to float32 rounding (differences of about 1e-6;
tests check it).
The copy holds detached weights: it is rebuilt, never updated, when the network changes
(:meth:`rapidds.motion.policy.DiffusionPolicy.denoiser` checks that on every call).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from rapidds.motion.unet import ConvNormAct, FiLMResidualBlock, TemporalUnet1d, check_inputs


def mish(x: Tensor) -> Tensor:
    """Mish(x) = x * tanh(softplus(x)) = x * (2 / (1 + q) - 1) with q = (1 - sigmoid(x))^2.

    Exact rewrite: tanh(log w) = (w^2 - 1) / (w^2 + 1) with w = 1 + e^x = 1 / (1 - sigmoid(x)).
    One vectorised sigmoid and cheap in-place arithmetic, no overflow: q runs from 1 (x far
    below 0, result 0) to 0 (x large, result x). New tensor; ``x`` is left alone."""
    q = torch.sigmoid(x).sub_(1.0).square_()
    return q.add_(1.0).reciprocal_().mul_(2.0).sub_(1.0).mul_(x)


class _Conv:
    """A Conv1d's detached weights and the call that applies them."""

    def __init__(self, conv: nn.Conv1d):
        self.weight = conv.weight.detach().contiguous()
        self.bias = None if conv.bias is None else conv.bias.detach().contiguous()
        self.stride, self.padding = conv.stride, conv.padding

    def __call__(self, h: Tensor) -> Tensor:
        return F.conv1d(h, self.weight, self.bias, self.stride, self.padding)


class _Upsample:
    """The U-Net's ConvTranspose1d(C, C, 4, stride=2, padding=1) as one ordinary convolution.

    Output 2j takes taps 1 and 3 of the kernel at inputs j and j-1, output 2j+1 taps 0 and 2
    at inputs j+1 and j (polyphase form). A kernel-3 convolution with 2C output channels
    computes both phases; interleaving them is the copy that writes the result into the
    caller's buffer (the concatenation with the skip features), so PyTorch's slower
    transposed convolution and the separate concatenation copy both go.
    """

    def __init__(self, conv: nn.ConvTranspose1d):
        if (conv.kernel_size, conv.stride, conv.padding, conv.output_padding, conv.groups,
                conv.dilation) != ((4,), (2,), (1,), (0,), 1, (1,)):
            raise ValueError("expected ConvTranspose1d(kernel 4, stride 2, padding 1)")
        w = conv.weight.detach()                                    # (C_in, C_out, 4)
        wt = w.transpose(0, 1)                                      # (C_out, C_in, 4)
        zero = torch.zeros_like(wt[..., 0])
        # Taps at input offsets -1, 0, +1 around output pair j.
        even = torch.stack([wt[..., 3], wt[..., 1], zero], dim=-1)
        odd = torch.stack([zero, wt[..., 2], wt[..., 0]], dim=-1)
        self.weight = torch.cat([even, odd]).contiguous()         # (2 C_out, C_in, 3)
        b = conv.bias.detach() if conv.bias is not None else wt.new_zeros(wt.shape[0])
        self.bias = torch.cat([b, b]).contiguous()
        self.channels = wt.shape[0]

    def into(self, h: Tensor, out: Tensor) -> None:
        """Write the (B, C_out, 2L) up-sampled ``h`` (B, C_in, L) into ``out``."""
        b, _, length = h.shape
        phases = F.conv1d(h, self.weight, self.bias, padding=1)    # (B, 2 C_out, L)
        out.view(b, self.channels, length, 2).copy_(
            phases.view(b, 2, self.channels, length).permute(0, 2, 3, 1))


Activation = Callable[[Tensor], Tensor]


class _ConvNormMish:
    """Conv1d -> GroupNorm -> Mish of a :class:`ConvNormAct`."""

    def __init__(self, block: ConvNormAct, act: Activation):
        conv, norm, _ = block
        self.conv, self.act = _Conv(conv), act
        self.groups, self.eps = norm.num_groups, norm.eps
        self.weight, self.bias = norm.weight.detach(), norm.bias.detach()

    def __call__(self, h: Tensor) -> Tensor:
        h = F.group_norm(self.conv(h), self.groups, self.weight, self.bias, self.eps)
        return self.act(h)


class _Block:
    """A :class:`FiLMResidualBlock`; its FiLM layer lives in the shared matrix of
    :class:`FastUnet`, which hands each block its (B, C, 1) scale and bias."""

    def __init__(self, block: FiLMResidualBlock, act: Activation):
        self.conv1 = _ConvNormMish(block.conv1, act)
        self.conv2 = _ConvNormMish(block.conv2, act)
        self.skip = None if isinstance(block.skip, nn.Identity) else _Conv(block.skip)

    def __call__(self, h: Tensor, scale: Tensor, bias: Tensor) -> Tensor:
        y = self.conv1(h)
        y = self.conv2(y.mul_(scale).add_(bias))
        return y.add_(h if self.skip is None else self.skip(h))


class FastUnet:
    """eps_theta(x (B, H, d), t (B,) or scalar, cond (B, cond_dim)) -> (B, H, d), computed like
    ``model`` but faster on CPU; inference only (no gradients).

    model: the trained network; its weights are copied by reference (detached), so build a new
    FastUnet after changing them. native_mish: PyTorch's Mish kernel instead of the rewrite
    (:func:`mish`); None: native off the CPU, where it is one kernel launch instead of eight.
    """

    def __init__(self, model: TemporalUnet1d, native_mish: bool | None = None):
        if not isinstance(model, TemporalUnet1d):
            raise TypeError(f"FastUnet copies a TemporalUnet1d, got {type(model).__name__}")
        if native_mish is None:
            native_mish = next(model.parameters()).device.type != "cpu"
        act: Activation = F.mish if native_mish else mish
        self.act = act
        self.state_dim, self.cond_dim = model.state_dim, model.cond_dim
        embed, lin1, _, lin2 = model.step_encoder
        self.step_embedding = embed
        self.step_layers = (lin1.weight.detach(), lin1.bias.detach(), lin2.weight.detach(),
                            lin2.bias.detach())
        blocks: list[FiLMResidualBlock] = []
        self.down = []
        for block1, block2, downsample in model.down:
            blocks += [block1, block2]
            self.down.append((_Block(block1, act), _Block(block2, act),
                              None if isinstance(downsample, nn.Identity) else _Conv(downsample)))
        self.mid = [_Block(b, act) for b in model.mid]
        blocks += list(model.mid)
        self.up = []
        for upsample, block1, block2 in model.up:
            blocks += [block1, block2]
            self.up.append((_Upsample(upsample), _Block(block1, act), _Block(block2, act)))
        self.head = (_ConvNormMish(model.head[0], act), _Conv(model.head[1]))
        # All FiLM layers as one: rows of the stacked weight are block 0's (scale, bias), then
        # block 1's, ... in the order the blocks run.
        films = [b.film[1] for b in blocks]
        self.film_weight = torch.cat([f.weight.detach() for f in films]).contiguous()
        self.film_bias = torch.cat([f.bias.detach() for f in films]).contiguous()
        self.film_widths = [f.out_features // 2 for f in films]

    def _step_features(self, t: Tensor, n: int) -> Tensor:
        """(n, step_embed_dim) step encodings; one row computed when all steps are equal (as
        in sampling, where a batch shares its diffusion step)."""
        if t.ndim == 0 or bool((t == t[0]).all()):
            t = t.reshape(-1)[:1]
        w1, b1, w2, b2 = self.step_layers
        feats = F.linear(self.act(F.linear(self.step_embedding(t), w1, b1)), w2, b2)
        return feats.expand(n, -1)

    def _films(self, t: Tensor, cond: Tensor, dtype: torch.dtype) -> list[tuple[Tensor, Tensor]]:
        film = torch.cat([self._step_features(t, cond.shape[0]), cond.to(dtype)], dim=-1)
        out = F.linear(self.act(film), self.film_weight, self.film_bias).unsqueeze(-1)
        chunks = out.split([2 * c for c in self.film_widths], dim=1)
        return [(ch[:, :c], ch[:, c:]) for ch, c in zip(chunks, self.film_widths, strict=True)]

    @torch.no_grad()
    def __call__(self, x: Tensor, t: Tensor, cond: Tensor) -> Tensor:
        check_inputs(x, cond, self.state_dim, self.cond_dim)
        films = iter(self._films(t, cond, x.dtype))
        h = x.transpose(1, 2)  # (B, d, H): convolve along time
        skips = []
        for block1, block2, downsample in self.down:
            h = block2(block1(h, *next(films)), *next(films))
            skips.append(h)
            if downsample is not None:
                h = downsample(h)
        skips.pop()  # the deepest level is not down-sampled; mid continues from it directly
        for block in self.mid:
            h = block(h, *next(films))
        for upsample, block1, block2 in self.up:
            skip = skips.pop()
            b, c_skip, length = skip.shape
            joined = h.new_empty(b, upsample.channels + c_skip, length)
            upsample.into(h, joined[:, :upsample.channels])
            joined[:, upsample.channels:] = skip
            h = block2(block1(joined, *next(films)), *next(films))
        conv_norm_mish, out = self.head
        return out(conv_norm_mish(h)).transpose(1, 2)
