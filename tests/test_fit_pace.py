"""A fit keeps its budget on any device: ``trainer.fit.budget.Pacer`` re-plans the steps from the rate they run at.

On CUDA the first steps are slow (kernel choice, allocations) and the plan measured them: a fit planned 929 steps
of 0.14 s for 2.1 minutes and trained them in 15 s. Here a step that is slow only at first stands in for that.
"""

from __future__ import annotations

import time

import pytest
from conftest import tiny_config

import trainer.train as training
from trainer.config import OptimConfig, RunConfig
from trainer.fit.budget import VALIDATIONS, Pacer, Plan, continued_decay

#: The first steps' extra seconds, and how many of them are slow.
SLOW_S, SLOW_STEPS = 0.5, 3
TRAIN_S = 20.0


def test_a_step_slow_only_at_first_still_trains_to_the_deadline(tmp_path, monkeypatch):
    real_step, calls = training.gan_step, [0]

    def slow_at_first(*args, **kwargs):
        calls[0] += 1
        if calls[0] <= SLOW_STEPS:
            time.sleep(SLOW_S)
        return real_step(*args, **kwargs)

    monkeypatch.setattr(training, "gan_step", slow_at_first)
    # The plan, as fit makes it from steps timed at the slow start: 20 s of 0.5 s steps, 40 steps.
    steps = int(TRAIN_S / SLOW_S)
    config = RunConfig.model_validate(
        tiny_config(
            tmp_path / "run",
            train={"steps": steps, "val_every": steps // VALIDATIONS, "checkpoint_every": steps, "log_every": 10},
            optim={"decay_start": steps // 2, "decay_steps": steps - steps // 2},
        )
    )
    plan = Plan(TRAIN_S, SLOW_S, TRAIN_S, steps, steps // 2, steps // VALIDATIONS, steps, TRAIN_S, False, 0.0)
    lines: list[str] = []
    began = time.monotonic()
    deadline = began + TRAIN_S
    pacer = Pacer(plan, config, deadline, lambda plan, config, line: lines.append(line))
    summary = training.train(config, deadline=deadline, revise=pacer)
    ended = time.monotonic()
    # Trained through to the deadline (within 5% of the training time), not for the 40 steps planned.
    assert ended - began >= 0.95 * TRAIN_S, (ended - began, summary.steps, lines)
    assert summary.steps > 2 * steps and lines and lines[0].startswith("re-planned at step")
    # The plan it ended on is the steps it trained, its learning rate decayed to (nearly) zero by the last one.
    final = pacer.config
    assert summary.steps == final.train.steps or ended >= deadline
    assert final.optim.lr_at(summary.steps - 1) <= 0.05 * final.optim.lr
    assert pacer.plan.steps == final.train.steps and pacer.plan.decay_start == final.optim.decay_start


@pytest.mark.parametrize("step", [5, 30, 70, 95])
def test_a_re_planned_decay_never_jumps_and_ends_at_the_new_end(step):
    # lr 1, decaying linearly from step 50 to zero at step 100; re-planned at ``step`` to end at 400 or 120.
    optim = OptimConfig(lr=1.0, decay_start=50, decay_steps=50)
    for new_end in (400, 120):
        after = continued_decay(optim, step, new_end)
        # No jump where it is re-planned (but for the rounding of the decay's first step to a whole one).
        assert after.lr_at(step) == pytest.approx(optim.lr_at(step), abs=1 / (new_end - step))
        assert after.lr_at(new_end) == 0.0 and after.lr_at(new_end - 1) > 0
        assert all(after.lr_at(s) >= after.lr_at(s + 1) for s in range(step, new_end))  # it only falls from here
        if step < 50:  # the decay had not begun: it is the new run's last half, as a plan makes it
            assert (after.lr, after.decay_start, after.decay_steps) == (1.0, new_end // 2, new_end - new_end // 2)
