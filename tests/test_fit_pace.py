"""A fit keeps its budget on any device: ``trainer.fit.budget.Pacer`` re-plans the steps from the rate they run at.

On CUDA the first steps are slow (kernel choice, allocations) and the plan measured them: a fit planned 929 steps
of 0.14 s for 2.1 minutes and trained them in 15 s. Here a step that is slow only at first stands in for that.
"""

from __future__ import annotations

import time
from dataclasses import replace

import pytest
from conftest import tiny_config

import trainer.train as training
from trainer.config import OptimConfig, RunConfig
from trainer.fit.budget import VALIDATIONS, Pacer, Plan, continued_decay, resumed_deadline, validation_every

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
    # The plan it ended on is the steps it trained (the deadline may cut its last step or two: within 2%), and
    # its learning rate decays to zero at that plan's end, the decay under way where training stopped.
    final = pacer.config
    assert summary.steps == final.train.steps or (ended >= deadline and summary.steps >= 0.98 * final.train.steps)
    assert final.optim.lr_at(final.train.steps) == 0.0 and final.optim.decay_start < summary.steps
    assert final.optim.lr_at(summary.steps - 1) < final.optim.lr_at(final.optim.decay_start)
    assert pacer.plan.steps == final.train.steps and pacer.plan.decay_start == final.optim.decay_start


@pytest.mark.parametrize("step", [5, 30, 70, 95])
def test_a_re_planned_decay_never_jumps_and_ends_at_the_new_end(step):
    # lr 1, decaying linearly from step 50 to zero at step 100; re-planned at ``step`` to end at 400 or 120.
    optim = OptimConfig(lr=1.0, decay_start=50, decay_steps=50)
    for new_end in (400, 120):
        after = continued_decay(optim, step, new_end)
        # No jump where it is re-planned, but for the rounding of the decay's first step to a whole one: at most
        # half a step of a decay at least ``new_end - step`` long, relative to the rate reached.
        assert after.lr_at(step) == pytest.approx(optim.lr_at(step), rel=1 / (new_end - step))
        assert after.lr_at(new_end) == 0.0 and after.lr_at(new_end - 1) > 0
        assert all(after.lr_at(s) >= after.lr_at(s + 1) for s in range(step, new_end))  # it only falls from here
        if step < 50:  # the decay had not begun: it is the new run's last half, as a plan makes it
            assert (after.lr, after.decay_start, after.decay_steps) == (1.0, new_end // 2, new_end - new_end // 2)


class Clock:
    """A clock the test moves: the Pacer reads the time only through it."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def steady_run(tmp_path, steps: int = 100) -> tuple[Plan, RunConfig]:
    """A plan of ``steps`` steps of 1 s in 100 s of training, no validations, and its run's config."""
    config = RunConfig.model_validate(
        tiny_config(
            tmp_path / "run",
            train={"steps": steps, "val_every": steps, "checkpoint_every": 10},
            optim={"decay_start": steps // 2, "decay_steps": steps - steps // 2},
        )
    )
    return Plan(100.0, 1.0, 100.0, steps, steps // 2, steps, 10, 100.0, False, 0.0), config


def test_a_hiccup_near_the_end_costs_only_the_steps_it_took(tmp_path):
    # Steps of 1 s on plan, then one of 5 s (a checkpoint, a collection) in the last 10%: 4 s are lost, so
    # it re-plans at once to end within the deadline, and cuts about those 4 steps (and one more, to end a step
    # early), not the many that a rate taken over the last few steps would.
    plan, config = steady_run(tmp_path)
    clock, lines = Clock(), []
    pacer = Pacer(plan, config, 100.0, lambda p, c, line: lines.append(line), clock)
    busy, step = 0.0, 0
    while step < pacer.config.train.steps:
        step += 1
        seconds = 5.0 if step == 93 else 1.0
        clock.now += seconds
        busy += seconds
        pacer(step, busy)
    assert len(lines) == 1 and 93 <= pacer.plan.steps <= 96, lines
    assert clock.now <= 100.0 and pacer.config.optim.lr_at(step) == 0.0


def test_a_noisy_machine_does_not_swing_the_plan(tmp_path):
    # Windows of 20 steps (5% of the run) alternately 10% fast and 10% slow average the plan's 1 s. The first
    # windows may move the plan; once the rate is taken over a long window it settles at about 1 s and stays.
    plan, config = steady_run(tmp_path, steps=400)
    plan = replace(plan, train_s=400.0, deadline_s=400.0)
    clock, lines = Clock(), []
    pacer = Pacer(plan, config, 400.0, lambda p, c, line: lines.append(line), clock)
    busy = 0.0
    for step in range(1, 400):
        seconds = 0.9 if (step // 20) % 2 else 1.1
        clock.now += seconds
        busy += seconds
        pacer(step, busy)
    assert len(lines) <= 3 and pacer.plan.step_s == pytest.approx(1.0, rel=0.05), lines


def test_steps_that_fall_behind_near_the_end_end_a_step_early_not_cut_off(tmp_path):
    # From step 90 every step takes 2 s: the 10 left would end 10 s late. It re-plans to end before the deadline.
    plan, config = steady_run(tmp_path)
    clock, lines = Clock(), []
    pacer = Pacer(plan, config, 100.0, lambda p, c, line: lines.append(line), clock)
    busy, step = 0.0, 0
    while step < pacer.config.train.steps and clock.now < 100.0:
        step += 1
        seconds = 2.0 if step > 90 else 1.0
        clock.now += seconds
        busy += seconds
        pacer(step, busy)
    assert lines and step == pacer.config.train.steps and clock.now <= 100.0, (step, clock.now, lines)
    assert pacer.config.optim.lr_at(step) == 0.0


def test_a_resumed_fit_gets_the_time_its_steps_left_were_given(tmp_path):
    plan, _ = steady_run(tmp_path)
    plan = Plan(100.0, 1.0, 90.0, 100, 50, 25, 10, 100.0, False, 10.0)  # 90 s of steps, 10 of validations
    assert resumed_deadline(plan, 0, 1000.0) == 1100.0
    assert resumed_deadline(plan, 60, 1000.0) == pytest.approx(1040.0)  # 40% of the steps: 40% of 100 s


def test_a_late_last_step_ends_the_run_not_re_plans_it(tmp_path):
    # The last step takes 10 s: the run is over, its learning rate at zero; the Pacer must not re-plan one more
    # step at a rate of zero (a fit once failed there: "optim.lr: Input should be greater than 0").
    plan, config = steady_run(tmp_path)
    clock, lines = Clock(), []
    pacer = Pacer(plan, config, 100.0, lambda p, c, line: lines.append(line), clock)
    busy = 0.0
    for step in range(1, 101):
        seconds = 10.0 if step == 100 else 1.0
        clock.now += seconds
        busy += seconds
        assert pacer(step, busy) is None or step < 100
    assert pacer.config.train.steps == 100 and pacer.config.optim.lr > 0, lines


def paced_run(tmp_path, step_seconds, validation_seconds: float, plan_validation_s: float):
    """A fit's training loop as ``trainer.train`` runs it, on a fake clock: 1,000 steps planned at 1 s in 1,000 s,
    validations reserved at ``plan_validation_s`` in all (the initial one among them) but taking
    ``validation_seconds`` each, at every multiple of ``val_every`` and at the last step, and a deadline at the
    end of the training share. Returns when training ended, the steps trained, the validations and the pacer."""
    steps = 1000
    config = RunConfig.model_validate(
        tiny_config(
            tmp_path / "run",
            train={"steps": steps, "val_every": validation_every(0, steps, VALIDATIONS), "checkpoint_every": 100},
            optim={"decay_start": steps // 2, "decay_steps": steps - steps // 2},
        )
    )
    per_validation = plan_validation_s / (VALIDATIONS + 1)
    deadline = 1000.0 + VALIDATIONS * per_validation  # training's share: its steps and the validations in it
    plan = Plan(2000.0, 1.0, 1000.0, steps, steps // 2, config.train.val_every, 100, deadline, False, plan_validation_s)
    clock, lines = Clock(), []
    pacer = Pacer(plan, config, deadline, lambda p, c, line: lines.append(line), clock)
    step, busy, validating, validations = 0, 0.0, 0.0, 0
    while True:
        step += 1
        seconds = step_seconds(clock.now)
        clock.now += seconds
        busy += seconds
        pacer(step, busy, validating, validations)
        train = pacer.config.train
        last = step >= train.steps or clock.now >= deadline
        if step % train.val_every == 0 or last:
            clock.now += validation_seconds
            validating += validation_seconds
            validations += 1
        if last:
            return clock.now, deadline, step, validations, pacer, lines


@pytest.mark.parametrize("slow_share", [0.1, 0.2])
def test_a_slow_start_is_forgotten_however_long_it_lasts(tmp_path, slow_share):
    """Steps 3x slower than planned for the first 10% or 20% of the time, then as planned: the rate over the
    later two thirds of the steps leave the slow ones behind, and training ends at 97% of its share or later (the old
    window kept them to the end and stopped at 93% and 91%), on its last step, with the planned validations."""
    ended, deadline, step, validations, pacer, lines = paced_run(
        tmp_path, lambda now: 3.0 if now < slow_share * 1000 else 1.0, 2.0, 5 * 2.0
    )
    assert 0.97 * deadline <= ended <= deadline + 1.0, (ended, lines)
    assert step == pacer.config.train.steps and pacer.config.optim.lr_at(step) == 0.0
    assert validations == VALIDATIONS, lines


def test_validations_slower_than_planned_are_measured_into_the_plan(tmp_path):
    """Validations take 2.5x the plan's estimate (25 s against 10): from the first one on, the pacer reserves what
    they take, so training ends no later than one step past its deadline, with the four planned validations."""
    ended, deadline, step, validations, pacer, lines = paced_run(tmp_path, lambda now: 1.0, 25.0, 5 * 10.0)
    assert 0.97 * deadline <= ended <= deadline + 1.0, (ended, deadline, lines)
    assert validations == VALIDATIONS and step == pacer.config.train.steps, lines


#: (step, steps, validations left, the steps they fall at), worked out by hand: train re-plans after a step, then
#: validates at it if it is a multiple of val_every, and at its last step.
SPACINGS = [
    (0, 1000, 4, {250, 500, 750, 1000}),  # every 250
    (0, 225, 4, {57, 114, 171, 225}),  # every 57: 56 would add 224 beside 225
    (100, 1000, 3, {334, 668, 1000}),  # 300 to 333 each leave three multiples of their own before 1000
    (100, 200, 4, {116, 145, 174, 200}),  # every 29: 25 to 28 would validate at the re-planning step 100 too
    (196, 200, 3, {196, 198, 200}),  # every 2, the step itself among them
    (730, 866, 1, {866}),  # the last alone
    (0, 3, 4, {1, 2, 3}),  # too short for four: every step
]


@pytest.mark.parametrize(("step", "steps", "left", "expected"), SPACINGS)
def test_validations_are_spaced_to_the_count_left(step, steps, left, expected):
    every = validation_every(step, steps, left)
    assert {s for s in range(max(step, 1), steps + 1) if s % every == 0} | {steps} == expected, every
