"""Short real runs on real 7-Scenes frames: learning, exact resume, DDP, logs and CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import REPO, run_cli, tiny_config, write_config
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from harness.service import free_port

#: Real processes, networks or browsers: the full suite (`make test`) runs these, `-m 'not slow'` skips them.
pytestmark = pytest.mark.slow


def _scalars(run_dir, tag):
    acc = EventAccumulator(str(run_dir / "tensorboard"))
    acc.Reload()
    return {e.step: e.value for e in acc.Scalars(tag)}


def test_overfits_a_handful_of_frames(tmp_path):
    """The paper's objective alone (no L1 term) at least halves REL on 4 frames."""
    config = tiny_config(tmp_path / "run", train={"steps": 80, "val_every": 80, "log_every": 20})
    result = run_cli("train", str(write_config(tmp_path / "c.yaml", config)))
    rel = _scalars(tmp_path / "run", "val/rel")
    assert set(rel) == {0, 80}
    assert rel[80] <= 0.5 * rel[0], rel
    # The other artefacts a user expects.
    assert (tmp_path / "run" / "samples" / "step_0000080.png").is_file()
    assert {"loss/G_gan", "loss/G_fm", "loss/D_real", "loss/D_fake", "images_per_s"} <= set(
        EventAccumulator(str(tmp_path / "run" / "tensorboard")).Reload().Tags()["scalars"]
    )
    assert "best validation" in result.stdout
    saved = (tmp_path / "run" / "config.yaml").read_text()
    assert "ngf: 8" in saved and "feature_matching: 10.0" in saved


def test_resume_repeats_the_uninterrupted_run(tmp_path):
    overrides = {"train": {"steps": 8, "checkpoint_every": 4}, "generator": {"dropout": 0.5}}
    straight = write_config(tmp_path / "a.yaml", tiny_config(tmp_path / "a", **overrides))
    run_cli("train", str(straight))

    interrupted = write_config(tmp_path / "b.yaml", tiny_config(tmp_path / "b", **overrides))
    run_cli("train", str(interrupted), "-s", "train.steps=4")
    run_cli("train", str(interrupted), "--resume")

    a = torch.load(tmp_path / "a/checkpoints/last.pt", weights_only=True)
    b = torch.load(tmp_path / "b/checkpoints/last.pt", weights_only=True)
    assert a["step"] == b["step"] == 8
    for net in ("generator", "discriminator"):
        for name, tensor in a[net].items():
            assert torch.equal(tensor, b[net][name]), f"{net}.{name} differs after resume"
    summary_a = json.loads((tmp_path / "a/summary.json").read_text())
    summary_b = json.loads((tmp_path / "b/summary.json").read_text())
    assert summary_a["rank_weight_sha256"] == summary_b["rank_weight_sha256"]


def test_resume_on_other_settings_records_each_stretch_of_hardware(tmp_path):
    config = write_config(tmp_path / "c.yaml", tiny_config(tmp_path / "c", train={"steps": 4, "checkpoint_every": 2}))
    run_cli("train", str(config), "-s", "train.steps=2", "-s", "train.threads=1")
    run_cli("train", str(config), "--resume", "-s", "train.threads=2")
    hardware = json.loads((tmp_path / "c/summary.json").read_text())["hardware"]
    assert hardware.startswith("steps 0-2: ") and "1 threads each; steps 2-4: " in hardware
    assert hardware.endswith("2 threads each")
    assert torch.load(tmp_path / "c/checkpoints/last.pt", weights_only=True)["hardware"] == hardware


def test_a_checkpoint_saved_before_options_were_retired_still_resumes(tmp_path):
    config = write_config(tmp_path / "c.yaml", tiny_config(tmp_path / "run", train={"steps": 4, "checkpoint_every": 2}))
    run_cli("train", str(config), "-s", "train.steps=2")
    last = tmp_path / "run/checkpoints/last.pt"
    state = torch.load(last, weights_only=True)
    # As written then: retired options at their off values, inference settings inside the generator.
    saved = state["config"]
    saved["generator"] |= {"skips": False, "flip_average": False, "upsample_sigma": 0.0, "median_radius": 0}
    del saved["inference"]
    saved["optim"]["ema"] = 0.0
    saved["data"]["transform"] |= {"rotate_deg": 0.0, "zoom_depth": False, "zoom_out": False}
    torch.save(state, last)
    run_cli("train", str(config), "--resume")
    assert torch.load(last, weights_only=True)["step"] == 4


def test_a_config_that_turns_on_a_retired_option_is_refused_by_name(tmp_path):
    config = write_config(tmp_path / "c.yaml", tiny_config(tmp_path / "run", optim={"ema": 0.9}))
    result = subprocess.run(
        [sys.executable, "-m", "cli", "train", str(config)], cwd=REPO, capture_output=True, text=True
    )
    assert result.returncode == 1
    assert result.stderr.startswith("error: ") and "retired options {'optim.ema': 0.9}" in result.stderr
    assert "Traceback" not in result.stderr


def test_resume_refuses_a_different_network(tmp_path):
    config = write_config(tmp_path / "c.yaml", tiny_config(tmp_path / "run", train={"steps": 2}))
    run_cli("train", str(config))
    result = subprocess.run(
        [sys.executable, "-m", "cli", "train", str(config), "--resume", "-s", "generator.ngf=16"],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert result.returncode != 0 and "generator" in (result.stderr + result.stdout)


def torchrun(launch: list[str], config: Path) -> list[str]:
    """The command line that trains ``config`` on the CPU under torchrun with ``launch`` options."""
    train = ["-m", "cli", "train", str(config), "-s", "train.device=cpu"]
    return [sys.executable, "-m", "torch.distributed.run", *launch, *train]


def ddp_config(tmp_path: Path) -> Path:
    return write_config(
        tmp_path / "c.yaml", tiny_config(tmp_path / "run", train={"steps": 4, "batch_size": 2, "threads": 1})
    )


def assert_two_ranks_agree(run: Path) -> None:
    summary = json.loads((run / "summary.json").read_text())
    digests = summary["rank_weight_sha256"]
    assert len(digests) == 2 and digests[0] == digests[1]
    assert summary["hardware"].startswith("CPU") and "2 process(es)" in summary["hardware"]


ONE_THREAD = {**os.environ, "OMP_NUM_THREADS": "1"}


def test_ddp_two_cpu_processes_end_with_identical_weights(tmp_path):
    command = torchrun(["--standalone", "--nproc_per_node", "2"], ddp_config(tmp_path))
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, env=ONE_THREAD, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert_two_ranks_agree(tmp_path / "run")


def test_two_nodes_on_loopback_end_with_identical_weights(tmp_path):
    """Two torchrun "nodes" (one process each, gloo on CPU) that meet through c10d rendezvous, as on two machines."""
    port = free_port()
    rendezvous = ["--rdzv-backend", "c10d", "--rdzv-endpoint", f"127.0.0.1:{port}", "--rdzv-id", "two-nodes"]
    command = torchrun(["--nnodes", "2", "--nproc_per_node", "1", *rendezvous], ddp_config(tmp_path))
    # Each node logs to a file: waiting on one node while the other fills an undrained pipe would stall both.
    logs = [tmp_path / f"node-{i}.log" for i in range(2)]
    nodes = []
    for log in logs:
        with open(log, "w") as out:
            nodes.append(subprocess.Popen(command, cwd=REPO, env=ONE_THREAD, stdout=out, stderr=subprocess.STDOUT))
    codes = [node.wait(timeout=300) for node in nodes]
    assert codes == [0, 0], "\n".join(log.read_text()[-2000:] for log in logs)
    assert_two_ranks_agree(tmp_path / "run")


def test_a_run_that_swaps_the_upsampler_starts_from_every_other_layer(trained_checkpoint):
    """0.9.0 starts from 0.8.1 with another upsampler: the encoder, residual blocks and output layer carry
    over; the upsampling layers keep their fresh start. Any other difference is refused."""
    from contract.errors import UserError
    from trainer.checkpoint import load_weights, start_weights
    from trainer.gan import init_weights
    from trainer.networks import GlobalGenerator

    given = load_weights(trained_checkpoint)
    spec = given.config.generator.model_copy(update={"upsampler": "bilinear"})
    generator = GlobalGenerator(spec)
    generator.apply(init_weights)
    fresh = {key: tensor.clone() for key, tensor in generator.state_dict().items()}
    started = start_weights(generator, trained_checkpoint, spec)
    carried = [key for key in started if key in given.generator and torch.equal(started[key], given.generator[key])]
    kept_fresh = [key for key in started if torch.equal(started[key], fresh[key])]
    assert set(carried) | set(kept_fresh) == set(started)
    assert len(carried) == len(given.generator) - 2 * spec.n_downsample  # all but each stage's weight and bias
    assert all(".0." in key for key in kept_fresh) and len(kept_fresh) == 2 * spec.n_downsample
    with pytest.raises(UserError, match="is not this run's"):
        start_weights(generator, trained_checkpoint, spec.model_copy(update={"ngf": spec.ngf * 2}))
