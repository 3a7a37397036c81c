"""pix2pixHD's adversarial update: the networks as initialised, and one G step and one D step.

Order of one step, as pix2pixHD: G is updated against the current D (cGAN +
mu * feature matching, + optional masked L1), then D against the same fake
batch. Each D forward is followed by exactly one backward, with the fake and
real halves in one batch, which keeps DistributedDataParallel's gradient
hooks simple.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from trainer.config import LossConfig, RunConfig
from trainer.efficientnet import load_imagenet_encoder
from trainer.losses import GANLoss, feature_matching, fill_holes, masked_l1, patch_weights, silog
from trainer.networks import MultiscaleDiscriminator, UNetGenerator, build_generator


def init_weights(module: nn.Module) -> None:
    """pix2pixHD's initialisation: conv weights ~ N(0, 0.02), biases 0; ICNR before a pixel shuffle."""
    if isinstance(module, nn.Conv2d | nn.ConvTranspose2d):
        nn.init.normal_(module.weight, 0.0, 0.02)
        if module.bias is not None:
            nn.init.zeros_(module.bias)
    if isinstance(module, nn.Sequential) and len(module) == 2 and isinstance(module[1], nn.PixelShuffle):
        icnr_(module[0], module[1].upscale_factor)


def icnr_(conv: nn.Conv2d, factor: int) -> None:
    """ICNR (Aitken et al. 2017): the r^2 sub-pixel outputs of each channel start with one kernel, so the
    shuffled map starts as a nearest-neighbour upsampling of one convolution, with no checkerboard."""
    out = conv.out_channels // factor**2
    with torch.no_grad():
        conv.weight.copy_(conv.weight[:out].repeat_interleave(factor**2, dim=0))
        if conv.bias is not None:
            conv.bias.copy_(conv.bias[:out].repeat_interleave(factor**2))


def _split(outputs: list[list[torch.Tensor]], n: int) -> tuple[list[list[torch.Tensor]], list[list[torch.Tensor]]]:
    """Split D's outputs for a [fake; real] batch into the fake and the real halves."""
    fake = [[t[:n] for t in scale] for scale in outputs]
    real = [[t[n:] for t in scale] for scale in outputs]
    return fake, real


@dataclass(frozen=True)
class Autocast:
    """Training's autocast: mixed precision on CUDA (bf16 where supported, else fp16 with a gradient scaler),
    fp32 elsewhere. Not to be confused with ``contract.runtime.Precision``, the exported graph a service runs.

    bf16 autocast on a CPU was measured and not kept: 1.86x the steps per minute on an AVX512-BF16
    CPU, but on top of the discriminator-free fit it lost 0.033 δ1 on aims-lab (docs/research.md).
    """

    enabled: bool
    dtype: torch.dtype

    @property
    def scaled(self) -> bool:
        """fp16 gradients need a scaler against underflow; bf16 and fp32 do not."""
        return self.enabled and self.dtype == torch.float16

    @classmethod
    def for_device(cls, device: torch.device, wanted: bool) -> Autocast:
        enabled = wanted and device.type == "cuda"
        return cls(enabled, torch.bfloat16 if enabled and torch.cuda.is_bf16_supported() else torch.float16)


def build_networks(
    config: RunConfig, device: torch.device
) -> tuple[nn.Module, MultiscaleDiscriminator, torch.optim.Adam, torch.optim.Adam]:
    """G and D with pix2pixHD's initialisation, seeded so every rank starts identical, and their Adams.

    A pretrained encoder then takes ImageNet's weights (``train.encoder_weights``; ``train.start_from``
    replaces them all later) and learns at ``optim.encoder_lr_scale`` times the rate, in its own
    parameter group whose ``lr_scale`` the loop applies at every step; at 0 it is frozen.
    """
    torch.manual_seed(config.train.seed)
    generator = build_generator(config.generator)
    discriminator = MultiscaleDiscriminator(
        config.discriminator, config.generator.input_nc + config.generator.output_nc
    )
    generator.apply(init_weights)
    discriminator.apply(init_weights)
    groups: list[dict] = [{"params": list(generator.parameters()), "lr_scale": 1.0}]
    if isinstance(generator, UNetGenerator):
        if config.train.encoder_weights == "imagenet":
            load_imagenet_encoder(generator.encoder)
        encoder = set(generator.encoder.parameters())
        scale = config.optim.encoder_lr_scale
        groups = [{"params": [p for p in generator.parameters() if p not in encoder], "lr_scale": 1.0}]
        if scale > 0:
            groups.append({"params": list(generator.encoder.parameters()), "lr_scale": scale})
        else:
            generator.freeze_encoder()
    generator.to(device)
    discriminator.to(device)
    betas = (config.optim.beta1, config.optim.beta2)
    opt_g = torch.optim.Adam(groups, lr=config.optim.lr, betas=betas)
    opt_d = torch.optim.Adam(discriminator.parameters(), lr=config.optim.lr, betas=betas)
    return generator, discriminator, opt_g, opt_d


def gan_step(
    generator: nn.Module,
    discriminator: nn.Module,
    optimisers: tuple[torch.optim.Optimizer, torch.optim.Optimizer],
    scaler: torch.amp.GradScaler,
    gan_loss: GANLoss,
    loss: LossConfig,
    batch: dict[str, torch.Tensor],
    amp: Autocast,
) -> dict[str, torch.Tensor]:
    """One pix2pixHD update: G against the current D, then D against the same fake batch; the losses."""
    opt_g, opt_d = optimisers
    x, real, valid = batch["rgb"], batch["depth"], batch["valid"]
    n = x.shape[0]
    device_type = x.device.type
    # Generator: fool D and match its features on real pairs (when D takes part), and the masked L1.
    with torch.autocast(device_type, dtype=amp.dtype, enabled=amp.enabled):
        fake = generator(x)
        losses: dict[str, torch.Tensor] = {}
        loss_g = torch.zeros((), device=x.device)
        if loss.adversarial:
            real_filled = fill_holes(real, fake, valid)
            pairs = torch.cat([torch.cat([x, fake], 1), torch.cat([x, real_filled], 1)], 0)
            pred_fake, pred_real = _split(discriminator(pairs), n)
            weights = patch_weights(valid, pred_real)
            losses["G_gan"] = gan_loss(pred_fake, True)
            losses["G_fm"] = feature_matching(pred_fake, pred_real, weights)
            loss_g = loss.gan * losses["G_gan"] + loss.feature_matching * losses["G_fm"]
        if loss.l1_depth > 0:
            losses["G_l1"] = masked_l1(fake, real, valid)
            loss_g = loss_g + loss.l1_depth * losses["G_l1"]
        if loss.silog > 0:
            losses["G_silog"] = silog(fake, real, valid, loss.silog_lambda)
            loss_g = loss_g + loss.silog * losses["G_silog"]
    opt_g.zero_grad(set_to_none=True)
    scaler.scale(loss_g).backward()
    scaler.step(opt_g)
    if not loss.adversarial:
        scaler.update()
        return losses

    # Discriminator: the same fake batch (detached) against real pairs with holes filled.
    with torch.autocast(device_type, dtype=amp.dtype, enabled=amp.enabled):
        pairs = torch.cat([torch.cat([x, fake.detach()], 1), torch.cat([x, real_filled], 1)], 0)
        pred_fake, pred_real = _split(discriminator(pairs), n)
        losses["D_fake"] = gan_loss(pred_fake, False)
        losses["D_real"] = gan_loss(pred_real, True, weights)  # the same cells as in the G step
        loss_d = 0.5 * (losses["D_fake"] + losses["D_real"])
    opt_d.zero_grad(set_to_none=True)
    scaler.scale(loss_d).backward()
    scaler.step(opt_d)
    scaler.update()
    return losses
