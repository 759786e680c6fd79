"""The untrained U-Net ``R_θ`` of the deep-image-prior reconstructor (paper §2.3, Eq. 12).

The architecture follows GIDC (Wang et al. 2022, "Far-field super-resolution ghost
imaging with a deep neural network constraint", Light Sci. Appl. 11, 1): every
convolution is followed by batch normalisation and LeakyReLU(0.2); the encoder halves
the resolution with stride-2 convolutions and doubles the width, the decoder doubles
it with stride-2 transposed convolutions and concatenates the encoder feature map of
the same resolution (skip connection); a last convolution + batch norm + sigmoid maps
to ``out_ch`` channels in ``[0, 1]``.

Widths are ``base · 2^l`` at level ``l = 0 … depth``; the bottleneck has side
``n / 2^depth``. The fitting loop (:func:`torchtof.recon.dip.fit_dip`) lives outside
the module, so ``forward`` is a plain feed-forward network that exports to ONNX.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .._checks import check_rank, is_tracing

__all__ = ["UNet"]


def _conv_bn(c_in: int, c_out: int, kernel: int, stride: int = 1) -> nn.Sequential:
    """``conv(k×k) → BN → LeakyReLU(0.2)``; the conv has no bias (the BN shift replaces it)."""
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=kernel // 2, bias=False),
        nn.BatchNorm2d(c_out),
        nn.LeakyReLU(0.2),
    )


def _up_bn(c_in: int, c_out: int, kernel: int) -> nn.Sequential:
    """Stride-2 transposed ``k×k`` conv (exactly doubles H and W) → BN → LeakyReLU(0.2)."""
    return nn.Sequential(
        nn.ConvTranspose2d(
            c_in, c_out, kernel, stride=2, padding=kernel // 2, output_padding=1, bias=False
        ),
        nn.BatchNorm2d(c_out),
        nn.LeakyReLU(0.2),
    )


class UNet(nn.Module):
    """GIDC-style U-Net with skip connections, batch norm, LeakyReLU and sigmoid output.

    Per level: two ``k×k`` conv blocks; down-sampling by a stride-2 conv block,
    up-sampling by a stride-2 transposed conv block followed by concatenation with the
    skip and two conv blocks (Wang et al. 2022, GIDC; Ronneberger et al. 2015, U-Net).

    Args:
        in_ch: input channels (1: the normalised DGI/g2 image).
        out_ch: output channels.
        base: width of the first level; level ``l`` has ``base · 2^l`` channels.
        depth: number of down-sampling steps (``>= 1``); inputs need sides divisible by
            ``2^depth`` and at least ``2^(depth+1)`` (a bottleneck of at least 2×2: batch
            norm of a 1×1 map of one image is degenerate). ``depth=3`` suits 32×32 (4×4
            bottleneck), GIDC uses 4 at 64×64.
        kernel: odd convolution size (3 or 5; GIDC uses 5).

    Raises:
        TypeError: if an argument is not an int.
        ValueError: if an argument is out of range, or (in ``forward``) the input is not
            ``(B, in_ch, H, W)`` with ``H`` and ``W`` multiples of ``2^depth``, ``>= 2^(depth+1)``.

    Shape:
        - Input: :math:`(B, C_{in}, H, W)`, ``H, W`` multiples of ``2^depth``, at least
          ``2^(depth+1)`` (e.g. 16…128 for ``depth=3``).
        - Output: :math:`(B, C_{out}, H, W)`, values in ``[0, 1]``.

    Note:
        In training mode the batch norms use the statistics of the batch; DIP fits one
        image, so these are spatial statistics of that image.
        :func:`torchtof.recon.dip.fit_dip` folds them into the running buffers after the
        fit (:meth:`fold_batch_stats`), so that the module in ``eval`` mode — the one
        exported to ONNX — computes exactly the fitted function on the fitted input.

    Example:
        >>> net = UNet(base=8, depth=3)
        >>> net(torch.randn(2, 1, 32, 32)).shape
        torch.Size([2, 1, 32, 32])
    """

    def __init__(
        self, in_ch: int = 1, out_ch: int = 1, base: int = 16, depth: int = 3, kernel: int = 3
    ) -> None:
        super().__init__()
        for name, val, lo in (
            ("in_ch", in_ch, 1),
            ("out_ch", out_ch, 1),
            ("base", base, 1),
            ("depth", depth, 1),
            ("kernel", kernel, 1),
        ):
            if isinstance(val, bool) or not isinstance(val, int):
                raise TypeError(f"UNet: expected {name} to be an int, got {type(val).__name__}")
            if val < lo:
                raise ValueError(f"UNet: expected {name} >= {lo}, got {val}")
        if kernel % 2 == 0:
            raise ValueError(f"UNet: expected an odd kernel, got {kernel}")
        self.in_ch, self.out_ch, self.base, self.depth, self.kernel = (
            in_ch,
            out_ch,
            base,
            depth,
            kernel,
        )
        w = [base * 2**level for level in range(depth + 1)]
        k = kernel
        self.inc = nn.Sequential(_conv_bn(in_ch, w[0], k), _conv_bn(w[0], w[0], k))
        self.down = nn.ModuleList(
            nn.Sequential(
                _conv_bn(w[lv], w[lv], k, stride=2),
                _conv_bn(w[lv], w[lv + 1], k),
                _conv_bn(w[lv + 1], w[lv + 1], k),
            )
            for lv in range(depth)
        )
        self.up = nn.ModuleList(_up_bn(w[lv + 1], w[lv], k) for lv in reversed(range(depth)))
        self.merge = nn.ModuleList(
            nn.Sequential(_conv_bn(2 * w[lv], w[lv], k), _conv_bn(w[lv], w[lv], k))
            for lv in reversed(range(depth))
        )
        self.out = nn.Sequential(
            nn.Conv2d(w[0], out_ch, k, padding=k // 2, bias=False),
            nn.BatchNorm2d(out_ch),
            nn.Sigmoid(),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        check_rank(x, 4, "x", "UNet", "(B, C, H, W)")
        f = 2**self.depth
        h, w = x.shape[-2:]
        # static shape facts, checked in eager mode only (traced sizes are tensors)
        if not is_tracing() and (
            x.shape[1] != self.in_ch or h % f or w % f or h < 2 * f or w < 2 * f
        ):
            raise ValueError(
                f"UNet: expected x of shape (B, {self.in_ch}, H, W) with H and W divisible by "
                f"2^depth = {f} and at least {2 * f}, got {tuple(x.shape)}"
            )
        skips = []
        h = self.inc(x)
        for down in self.down:
            skips.append(h)
            h = down(h)
        for up, merge, skip in zip(self.up, self.merge, reversed(skips)):
            h = merge(torch.cat((up(h), skip), dim=1))
        return self.out(h)

    @torch.no_grad()
    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """Re-draw the weights as ``nn.Conv2d``/``nn.ConvTranspose2d`` initialise them
        (Kaiming-uniform with ``a = √5``), from ``generator`` (``None``: the global RNG), and
        reset the batch norms. With a fresh generator seeded ``s`` the weights equal those of
        a ``UNet`` built after ``torch.manual_seed(s)`` (same draws, same module order)."""
        for m in self.modules():
            if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
                nn.init.kaiming_uniform_(m.weight, a=math.sqrt(5), generator=generator)
                if m.bias is not None:
                    fan_in, _ = nn.init._calculate_fan_in_and_fan_out(m.weight)
                    bound = 1 / math.sqrt(fan_in) if fan_in > 0 else 0.0
                    nn.init.uniform_(m.bias, -bound, bound, generator=generator)
            elif isinstance(m, nn.BatchNorm2d):
                m.reset_parameters()

    @torch.no_grad()
    def fold_batch_stats(self, x: torch.Tensor) -> None:
        """Store the batch statistics of ``x`` in every batch norm's running buffers.

        Runs ``x`` through the network in training mode and sets each layer's
        ``running_mean`` and ``running_var`` to the mean and *biased* variance that
        training-mode normalisation used (``nn.BatchNorm2d`` itself would store the
        unbiased variance, which differs by ``N/(N−1)``). Afterwards ``eval()`` computes
        on ``x`` the same function as training mode. Parameters are left unchanged; the
        module is left in eval mode.

        Args:
            x: the input to fold, ``(B, in_ch, H, W)`` (DIP: the single fitted input).
        """
        stats = {}

        def hook(mod: nn.Module, args: tuple[torch.Tensor, ...]) -> None:
            inp = args[0]
            stats[mod] = (inp.mean(dim=(0, 2, 3)), inp.var(dim=(0, 2, 3), unbiased=False))

        bns = [m for m in self.modules() if isinstance(m, nn.BatchNorm2d)]
        handles = [bn.register_forward_pre_hook(hook) for bn in bns]
        try:
            self.train()
            self(x)
        finally:
            for h in handles:
                h.remove()
        for bn in bns:
            mean, var = stats[bn]
            bn.running_mean.copy_(mean)
            bn.running_var.copy_(var)
        self.eval()

    def extra_repr(self) -> str:
        return (
            f"in_ch={self.in_ch}, out_ch={self.out_ch}, base={self.base}, depth={self.depth}, "
            f"kernel={self.kernel}"
        )
