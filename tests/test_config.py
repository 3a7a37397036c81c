"""Config files and overrides: typed, strict, with the paper's defaults."""

from __future__ import annotations

import sys

import pytest
import typer
from conftest import REPO, SEVEN_SCENES, tiny_config, write_config

from cli.main import run_app
from contract.card import load_card
from contract.errors import UserError
from trainer.config import OptimConfig, apply_overrides, complete_config, load_config, migrate_config


def test_overrides_are_typed_and_nested(tmp_path):
    path = write_config(tmp_path / "c.yaml", tiny_config(tmp_path / "run"))
    config = load_config(path, ["train.steps=42", "loss.gan_mode=vanilla", "data.transform.size=[64, 96]"])
    assert config.train.steps == 42 and config.loss.gan_mode == "vanilla"
    assert config.data.transform.size == (64, 96)
    assert config.optim.lr == 0.0002 and (config.optim.beta1, config.optim.beta2) == (0.5, 0.999)
    assert config.loss.feature_matching == 10.0 and config.data.train[0].root == SEVEN_SCENES


def test_typos_and_bad_values_are_errors(tmp_path):
    path = write_config(tmp_path / "c.yaml", tiny_config(tmp_path / "run"))
    with pytest.raises(UserError, match="stpes"):
        load_config(path, ["train.stpes=5"])
    with pytest.raises(UserError, match="multiple of 4"):
        load_config(path, ["data.transform.size=[90, 128]"])
    with pytest.raises(ValueError, match=r"section\.key=value"):
        apply_overrides({}, ["train.steps"])


def test_linear_decay_schedule():
    optim = OptimConfig(lr=1.0, decay_start=10, decay_steps=10)
    assert [optim.lr_at(s) for s in (0, 9, 10, 15, 20, 30)] == [1.0, 1.0, 1.0, 0.5, 0.0, 0.0]
    assert OptimConfig().lr_at(10**6) == 0.0002  # the paper: constant


BUNDLED_VERSIONS = sorted((REPO / "weights").glob("*/*"))


def test_every_config_file_loads():
    paths = sorted((REPO / "configs").glob("*.yaml"))
    assert paths, "configs/ holds no config to check"
    for path in paths:
        load_config(path)


def test_there_are_bundled_versions_to_check():
    assert BUNDLED_VERSIONS, "weights/ holds no published version: the per-version tests below check nothing"


@pytest.mark.parametrize("version_dir", BUNDLED_VERSIONS, ids=lambda p: f"{p.parent.name}")
def test_each_bundled_model_has_one_config_that_reproduces_it(version_dir):
    """configs/NAME-VERSION.yaml is the training config in the card, plus the inference settings exported.

    A version exported from another with other inference settings (``derived_from``) has its
    source's config: the same training, with the inference the card records."""
    card = load_card(version_dir)
    own = REPO / "configs" / f"{card.name}-{card.version}.yaml"
    path = (
        own
        if own.is_file() or not card.derived_from
        else REPO / "configs" / f"{card.derived_from.replace(' ', '-')}.yaml"
    )
    config = load_config(path).model_dump(mode="json")
    if path != own:
        config["inference"] = card.inference.model_dump(mode="json")
    trained = complete_config(card.training.config)
    for tree in (config, trained):
        del tree["train"]["out_dir"]  # where the run writes, not what it trains
    assert {k: v for k, v in config.items() if k != "inference"} == {
        k: v for k, v in trained.items() if k != "inference"
    }
    assert config["inference"] == card.inference.model_dump(mode="json")
    assert config["generator"] == card.generator.model_dump(mode="json")


def test_an_old_config_migrates_and_a_retired_option_that_was_on_is_refused():
    old = {
        "generator": {"ngf": 8, "skips": False, "flip_average": False, "median_radius": 2},
        "optim": {"ema": 0.0},
        "data": {"train": [], "transform": {"zoom_depth": False, "rotate_deg": 0.0}},
    }
    assert migrate_config(old) == {
        "generator": {"ngf": 8},
        "inference": {"median_radius": 2},
        "optim": {},
        "data": {"train": [], "transform": {}},
    }
    assert old["generator"]["skips"] is False  # the input is left as it was
    with pytest.raises(
        ValueError, match=r"retired options \{'generator.skips': True, 'loss.gradient_matching': 50.0\}"
    ):
        migrate_config({"generator": {"skips": True}, "loss": {"gradient_matching": 50.0}})


def _failing_command_line() -> typer.Typer:
    commands = typer.Typer()

    @commands.command()
    def go(kind: str) -> None:
        if kind == "mistake":
            raise UserError("recording/: no colour image has a depth image")
        raise KeyError("an index the code got wrong")

    return commands


def test_a_users_mistake_is_one_line_and_a_bug_keeps_its_traceback(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["rgb2cloud", "mistake"])
    with pytest.raises(SystemExit) as stopped:
        run_app(_failing_command_line())
    assert stopped.value.code == 1
    assert capsys.readouterr().err == "error: recording/: no colour image has a depth image\n"
    monkeypatch.setattr(sys, "argv", ["rgb2cloud", "bug"])
    with pytest.raises(KeyError, match="an index the code got wrong"):  # not swallowed into one line
        run_app(_failing_command_line())
