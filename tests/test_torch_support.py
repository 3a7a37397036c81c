"""The trainer's torch range: one place (pyproject's train extra), checked before fit and train start."""

from __future__ import annotations

import subprocess
import sys
import tomllib

import pytest
from conftest import REPO
from packaging.specifiers import SpecifierSet

from contract.errors import UserError
from trainer.torch_support import check_torch, supported_torch

RANGE = SpecifierSet(">=2.11,<2.14")


def test_the_range_checked_is_the_train_extras():
    declared = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]["train"]
    (torch,) = [text for text in declared if text.startswith("torch")]
    assert supported_torch() == SpecifierSet(torch.removeprefix("torch"))


@pytest.mark.parametrize("version", ["2.11.0", "2.11.0+cu130", "2.13.0+cpu", "2.13.1"])
def test_a_torch_in_the_range_passes(version):
    check_torch(version, RANGE)


@pytest.mark.parametrize("version", ["2.10.2", "2.10.0+cu128", "2.14.1", "3.0.0"])
def test_a_torch_outside_the_range_is_one_line_naming_both(version):
    with pytest.raises(UserError) as refused:
        check_torch(version, RANGE)
    message = str(refused.value)
    assert "\n" not in message and f"torch {version} is outside" in message and "torch<2.14,>=2.11" in message


@pytest.mark.parametrize("command", ["train", "fit"])
def test_fit_and_train_stop_at_once_under_an_unsupported_torch(command, tmp_path):
    # torch as an older release would report itself; the command must stop before training or reading a recording.
    config = REPO / "configs" / "rgb2cloud-7scenes-0.9.0.yaml"
    fit_args = [str(tmp_path), "--name", "room", "--licence", "CC0"]
    args = [command, str(config)] if command == "train" else [command, *fit_args]
    code = (
        "import sys, torch; torch.__version__ = '2.10.0'; from cli.main import main; "
        f"sys.argv = ['rgb2cloud', *{args!r}]; main()"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    assert result.stderr.strip().splitlines() == [
        f"error: torch 2.10.0 is outside the versions the trainer supports (torch{supported_torch()}): "
        f"pip install 'torch{supported_torch()}', or the CPU build: pip install torch==2.13.0"
    ]
