"""Config files and overrides: typed, strict, with the paper's defaults."""

from __future__ import annotations

import pytest
from conftest import SEVEN_SCENES, tiny_config, write_config
from pydantic import ValidationError

from model.config import OptimConfig, apply_overrides, load_config


def test_overrides_are_typed_and_nested(tmp_path):
    path = write_config(tmp_path / "c.yaml", tiny_config(tmp_path / "run"))
    config = load_config(path, ["train.steps=42", "loss.gan_mode=vanilla", "data.transform.size=[64, 96]"])
    assert config.train.steps == 42 and config.loss.gan_mode == "vanilla"
    assert config.data.transform.size == (64, 96)
    assert config.optim.lr == 0.0002 and (config.optim.beta1, config.optim.beta2) == (0.5, 0.999)
    assert config.loss.feature_matching == 10.0 and config.data.train[0].root == SEVEN_SCENES


def test_typos_and_bad_values_are_errors(tmp_path):
    path = write_config(tmp_path / "c.yaml", tiny_config(tmp_path / "run"))
    with pytest.raises(ValidationError, match="stpes"):
        load_config(path, ["train.stpes=5"])
    with pytest.raises(ValidationError, match="multiple of 4"):
        load_config(path, ["data.transform.size=[90, 128]"])
    with pytest.raises(ValueError, match=r"section\.key=value"):
        apply_overrides({}, ["train.steps"])


def test_linear_decay_schedule():
    optim = OptimConfig(lr=1.0, decay_start=10, decay_steps=10)
    assert [optim.lr_at(s) for s in (0, 9, 10, 15, 20, 30)] == [1.0, 1.0, 1.0, 0.5, 0.0, 0.0]
    assert OptimConfig().lr_at(10**6) == 0.0002  # the paper: constant
