"""A published version gives its weights back under any torch: ``generator.safetensors`` holds them as plain
tensors, where a TorchScript file loads only under a torch with every operator its writer recorded. A version
published before that (0.9.0 and older) still loads from TorchScript, and where it cannot says why in one line.
"""

from __future__ import annotations

import pytest
import torch
from conftest import REPO

from contract.card import TORCHSCRIPT_FILE, WEIGHTS_FILE, load_card
from contract.errors import UserError
from trainer.checkpoint import load_weights

BUNDLED_0_9_0 = REPO / "weights" / "rgb2cloud-7scenes" / "0.9.0"


def refuse_torchscript(monkeypatch) -> None:
    """Stand in for torch 2.11: every TorchScript file fails as 0.9.0's does there, on an operator 2.11 lacks."""

    def cannot(*args, **kwargs):
        raise RuntimeError("Unknown builtin op: aten::_upsample_lanczos2d_aa.\nCould not find any similar ops")

    monkeypatch.setattr(torch.jit, "load", cannot)


def test_a_version_gives_back_the_weights_it_was_trained_to_without_torchscript(
    registry, trained_checkpoint, monkeypatch
):
    version = registry / "tiny" / "0.1.0"
    assert {WEIGHTS_FILE, TORCHSCRIPT_FILE} <= set(load_card(version).files)
    refuse_torchscript(monkeypatch)
    published = load_weights(version).generator
    trained = load_weights(trained_checkpoint).generator
    assert set(published) == set(trained)
    assert all(torch.equal(published[key], trained[key]) for key in trained), "the weights changed on the way"


@pytest.mark.skipif(torch.__version__ != "2.13.0+cpu", reason="0.9.0's TorchScript loads under the torch that wrote it")
def test_an_older_version_still_loads_from_torchscript():
    weights = load_weights(BUNDLED_0_9_0)
    assert WEIGHTS_FILE not in load_card(BUNDLED_0_9_0).files
    assert weights.generator and weights.published == "rgb2cloud-7scenes 0.9.0"


@pytest.mark.skipif(torch.__version__ != "2.13.0+cpu", reason="0.9.0's TorchScript loads under the torch that wrote it")
def test_the_bundled_base_that_fit_starts_from_holds_0_9_0s_weights_without_torchscript(monkeypatch, tmp_path):
    """0.9.1 is 0.9.0 published again with its weights in safetensors: fit's default start loads under a torch
    that reads no TorchScript, and gives back 0.9.0's weights to the bit."""
    from contract.registries import Registries
    from trainer.fit.start import resolve_start

    base = resolve_start(None, Registries(tmp_path / "own", REPO / "weights"))
    assert base is not None and WEIGHTS_FILE in load_card(base).files
    older = load_weights(BUNDLED_0_9_0).generator
    refuse_torchscript(monkeypatch)
    weights = load_weights(base)
    assert weights.published == "rgb2cloud-7scenes 0.9.1" and set(weights.generator) == set(older)
    assert all(torch.equal(weights.generator[key], older[key]) for key in older)


def test_an_older_version_another_torch_cannot_read_is_refused_in_one_line_that_says_what_to_do(monkeypatch):
    refuse_torchscript(monkeypatch)
    with pytest.raises(UserError) as refused:
        load_weights(BUNDLED_0_9_0)
    message = str(refused.value)
    assert "\n" not in message
    assert f"written by torch 2.13.0+cpu, which torch {torch.__version__} cannot load" in message
    assert "Unknown builtin op: aten::_upsample_lanczos2d_aa." in message
    assert "install torch==2.13.0 to start from it" in message and WEIGHTS_FILE in message
