"""The objective: cGAN loss (formula (2) or LSGAN) + mu * feature matching (formula (3)).

Missing ground-truth depth is handled in two ways so the discriminator never
learns that holes are real:

1. ``fill_holes``: before D sees a real pair, hole pixels take the generator's own
   (detached) prediction, so the "real" input carries no hole pattern at all.
2. Every term that compares with ground truth is weighted by ``patch_weights``: the
   fraction of valid pixels under each discriminator cell (or each pixel for L1),
   so regions of missing depth contribute nothing.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

Features = list[list[torch.Tensor]]


def fill_holes(real: torch.Tensor, fake: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Real depth with its holes replaced by the (detached) prediction."""
    return torch.where(valid > 0, real, fake.detach())


def patch_weights(valid: torch.Tensor, features: Features) -> list[list[torch.Tensor]]:
    """Valid-pixel fraction under each cell of each discriminator layer, per scale.

    The mask follows the multi-scale discriminator's own downsampling, then is
    area-pooled to every layer's spatial size.
    """
    weights = []
    mask = valid.float()
    for i, scale in enumerate(features):
        if i:
            mask = F.avg_pool2d(mask, 3, stride=2, padding=1, count_include_pad=False)
        weights.append([F.adaptive_avg_pool2d(mask, f.shape[-2:]) for f in scale])
    return weights


def _weighted_mean(values: torch.Tensor, weight: torch.Tensor | None) -> torch.Tensor:
    if weight is None:
        return values.mean()
    weight = weight.expand_as(values)
    return (values * weight).sum() / weight.sum().clamp_min(1e-6)


class GANLoss:
    """LSGAN (squared error to 1/0) or the log-likelihood loss of formula (2).

    Summed over discriminator scales, on each scale's last output (the patch logits).
    """

    def __init__(self, mode: str):
        if mode not in ("lsgan", "vanilla"):
            raise ValueError(f"unknown gan_mode {mode!r}")
        self.mode = mode

    def __call__(
        self, outputs: Features, target_is_real: bool, weights: list[list[torch.Tensor]] | None = None
    ) -> torch.Tensor:
        total = outputs[0][-1].new_zeros(())
        for i, scale in enumerate(outputs):
            logits = scale[-1].float()
            target = torch.full_like(logits, 1.0 if target_is_real else 0.0)
            if self.mode == "lsgan":
                per_cell = (logits - target) ** 2
            else:
                per_cell = F.binary_cross_entropy_with_logits(logits, target, reduction="none")
            total = total + _weighted_mean(per_cell, None if weights is None else weights[i][-1])
        return total


def feature_matching(fake: Features, real: Features, weights: list[list[torch.Tensor]] | None = None) -> torch.Tensor:
    """Formula (3): L1 between D's features of fake and real pairs, every layer but the last.

    pix2pixHD's weights: 4 / (n_layers + 1) per layer and 1 / num_D per scale. The
    real features are treated as constants (detached).
    """
    num_d = len(fake)
    total = fake[0][0].new_zeros((), dtype=torch.float32)
    for i in range(num_d):
        n_layers = len(fake[i]) - 2  # outputs = n_layers strided/unstrided convs + final conv
        layer_weight = 4.0 / (n_layers + 1)
        for j in range(len(fake[i]) - 1):
            diff = (fake[i][j].float() - real[i][j].detach().float()).abs()
            w = None if weights is None else weights[i][j]
            total = total + layer_weight / num_d * _weighted_mean(diff, w)
    return total


def silog(fake: torch.Tensor, real: torch.Tensor, valid: torch.Tensor, lam: float) -> torch.Tensor:
    """The scale-invariant log loss (Eigen et al. 2014, as BTS and AdaBins train with it), per image then averaged:
    sqrt(mean(d^2) - lam * mean(d)^2) over its valid pixels, ``d`` the difference of encoded depths. With the
    ``log`` encoding that is log depth times a constant, so ``lam`` below 1 keeps part of the metric scale an
    image's mean error carries. An image without a valid pixel adds nothing."""
    d = (fake.float() - real.float()) * valid.float()
    count = valid.float().flatten(1).sum(1)
    mean = d.flatten(1).sum(1) / count.clamp(min=1)
    square = (d**2).flatten(1).sum(1) / count.clamp(min=1)
    per_image = torch.sqrt((square - lam * mean**2).clamp(min=1e-8))
    seen = count > 0
    return (per_image * seen).sum() / seen.sum().clamp(min=1)


def masked_l1(fake: torch.Tensor, real: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Mean absolute error over valid pixels only (an opt-in term beyond the paper)."""
    return _weighted_mean((fake.float() - real.float()).abs(), valid.float())
