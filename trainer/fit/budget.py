"""A wall-clock budget turned into a training plan: steps, learning-rate schedule, checkpoints.

The step time depends on the machine, the image size and the threads, so it is
measured on the run's own data before anything is planned: a few real steps, and a
few predictions, on throwaway networks. The plan leaves room for validation and for
what follows training (scoring the held-out frames, export and its parity check),
and decays the learning rate to zero over the second half of the steps, as pix2pixHD
does over its last epochs. Steps measured before training can be far from what they cost
once it runs (on CUDA the first steps are slow), so ``Pacer`` re-plans from the rate the
steps really run at, and the budget is kept on any device.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import torch

from contract.errors import UserError
from trainer.config import OptimConfig, RunConfig
from trainer.data.loader import training_loader
from trainer.data.sources import open_source
from trainer.data.transforms import resize_frame
from trainer.devices import Distributed, pick_device
from trainer.gan import Autocast, build_networks, gan_step
from trainer.inference import EagerGenerator, InferenceGraph
from trainer.losses import GANLoss
from trainer.quantize import CALIBRATION_FRAMES

#: Runs timed after one warm-up run; their median is the plan's figure.
MEASURED_RUNS = 3
#: Times the selection frames are scored during training (and once before it).
VALIDATIONS = 4
#: Export and its parity check, on 2 CPU cores: mostly tracing the graph, and a colour-weighted median
#: adds a sorting network per tap. Measured with ``time rgb2cloud export VERSION_DIR ...``: 12.7 s for a
#: graph without a median, 50.7 s with ``--inference median_radius=2``; these figures carry a margin.
EXPORT_BASE_S = 20.0
EXPORT_PER_TAP_S = 2.4
#: ``--precision int8``: preparing and quantising the graph, then calibration, whose frames each cost a few
#: predictions (every activation is an output). ``time rgb2cloud export weights/rgb2cloud-7scenes/0.8.1 ...``
#: took 15.9 s, and 22.7 s with ``--precision int8``; these figures carry a margin (they reserve 23 s for that 6.8 s).
INT8_BASE_S = 20.0
INT8_PER_FRAME_PREDICTIONS = 4
#: Reading the train frames for the baselines, and the rest of scoring, beside the predictions.
SCORING_OVERHEAD_S = 15.0
#: Share of the steps over which the learning rate decays linearly to zero.
DECAY_SHARE = 0.5
#: Checkpoints (for --resume) at least this often, in seconds of training.
CHECKPOINT_SECONDS = 120.0


@dataclass(frozen=True)
class Plan:
    """How a fit spends its budget; saved beside the run, so ``--resume`` continues the same plan."""

    budget_s: float
    step_s: float
    train_s: float
    steps: int
    decay_start: int
    val_every: int
    checkpoint_every: int
    #: Seconds after the start of the command by which training must stop.
    deadline_s: float
    #: The steps were given (``fit --steps``), not fitted to the budget: training runs them all.
    fixed: bool = False
    #: Seconds set aside for scoring the selection frames, all ``VALIDATIONS`` times and once before the first step.
    validation_s: float = 0.0

    def line(self) -> str:
        if self.fixed:
            return (
                f"plan: {self.steps} steps as given, about {self.steps * self.step_s / 60:.1f} min at "
                f"{self.step_s:.2f} s each (the budget does not stop them), learning rate decaying to zero from "
                f"step {self.decay_start}"
            )
        return (
            f"plan: {self.steps} steps of {self.step_s:.2f} s ({self.train_s / 60:.1f} of {self.budget_s / 60:.1f} "
            f"min), learning rate decaying to zero from step {self.decay_start}"
        )


def measure_seconds(config: RunConfig) -> tuple[float, float]:
    """Median seconds of one training step, and of one prediction on a frame of the recording, on this machine."""
    device = pick_device(config.train.device, 0)
    if config.train.threads:
        torch.set_num_threads(config.train.threads)
    generator, discriminator, opt_g, opt_d = build_networks(config, device)
    amp = Autocast.for_device(device, config.train.amp)
    scaler = torch.amp.GradScaler(device.type, enabled=amp.scaled)
    quiet = config.model_copy(update={"train": config.train.model_copy(update={"num_workers": 0})})
    batches = iter(training_loader(quiet, Distributed(), 0, pin_memory=False))
    gan_loss = GANLoss(config.loss.gan_mode)

    def step() -> None:
        batch = {k: v.to(device) for k, v in next(batches).items()}
        gan_step(generator, discriminator, (opt_g, opt_d), scaler, gan_loss, config.loss, batch, amp)

    frame = open_source(config.data.train[0])[0]  # a photo of the recording, as the service will see its photos
    height, width = frame.depth.shape
    frame = resize_frame(frame, round(height * config.data.val_scale), round(width * config.data.val_scale))
    runner = EagerGenerator(InferenceGraph(generator, config.inference), config.generator.input_multiple)
    return _timed(step, device), _timed(lambda: runner.predict_raw(frame.rgb), device)


def _timed(work: Callable[[], object], device: torch.device) -> float:
    """Median seconds of ``work`` over MEASURED_RUNS runs after one warm-up run (allocations, kernel choice)."""
    seconds = []
    for i in range(MEASURED_RUNS + 1):
        if device.type == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        work()
        if device.type == "cuda":
            torch.cuda.synchronize()
        if i:
            seconds.append(time.perf_counter() - start)
    return statistics.median(seconds)


@dataclass(frozen=True)
class Workload:
    """What the plan must leave time for besides training steps."""

    selection_frames: int
    holdout_frames: int
    predict_s: float
    scores_start: bool
    median_taps: int
    #: The publish also quantises an int8 graph (``fit --precision int8``).
    int8: bool = False

    def validation_s(self) -> float:
        """The selection frames scored VALIDATIONS times, plus once before the first step."""
        return (VALIDATIONS + 1) * self.selection_frames * self.predict_s

    def tail_s(self) -> float:
        """Scoring the held-out frames (the fitted model, and the start on ONNX Runtime), then export."""
        models = 1 + (2 if self.scores_start else 0)  # the start's ONNX graph runs about twice as slow on CPU
        export_s = EXPORT_BASE_S + EXPORT_PER_TAP_S * self.median_taps
        if self.int8:  # calibration runs the frames through a graph that also outputs every activation
            export_s += INT8_BASE_S + INT8_PER_FRAME_PREDICTIONS * CALIBRATION_FRAMES * self.predict_s
        return models * self.holdout_frames * self.predict_s + export_s + SCORING_OVERHEAD_S


def plan_training(budget_s: float, spent_s: float, step_s: float, work: Workload, steps: int | None = None) -> Plan:
    """Steps that fit what is left of the budget once validation, scoring and export are set aside.

    ``steps`` fixes the count instead (the same plan on another machine, or a comparison at equal
    steps); training then runs them all, however long they take.
    """
    train_s = budget_s - spent_s - work.tail_s() - work.validation_s()
    fixed = steps is not None
    steps = steps if fixed else int(train_s / step_s)
    if steps < 1:
        raise UserError(
            f"the budget of {budget_s / 60:.1f} min leaves no time to train: {spent_s:.0f} s went to reading and "
            f"checking the data, {work.tail_s() + work.validation_s():.0f} s are needed to validate, score and "
            f"export, and one step takes {step_s:.1f} s; give a larger --budget"
        )
    # Often enough that an interruption loses little: every CHECKPOINT_SECONDS, and ten times a run at least.
    per_checkpoint = max(1, min(int(CHECKPOINT_SECONDS / step_s), steps // 10))
    return Plan(
        budget_s=budget_s,
        step_s=step_s,
        train_s=train_s,
        steps=steps,
        decay_start=round(steps * (1 - DECAY_SHARE)),
        val_every=validation_every(0, steps, VALIDATIONS),
        checkpoint_every=min(per_checkpoint, steps),
        deadline_s=budget_s - work.tail_s(),
        fixed=fixed,
        validation_s=work.validation_s(),
    )


#: How often a fit compares its steps' real rate with its plan: after each share of its planned steps or of its
#: training time, whichever comes first, over at least ``REVISE_MIN_STEPS`` steps. It re-plans when the steps
#: left would end more than ``REVISE_TOLERANCE`` of the training time early or late; in the last
#: ``SETTLED_SHARE`` of the steps it looks after every one and re-plans when they would end more than a step
#: late (so the deadline never cuts the decay short) or more than ``SETTLED_EARLY`` of the training time early.
REVISE_SHARE, REVISE_MIN_STEPS, REVISE_TOLERANCE, SETTLED_SHARE, SETTLED_EARLY = 0.05, 5, 0.05, 0.1, 0.02


def validation_every(step: int, steps: int, left: int) -> int:
    """The ``val_every`` that gives ``left`` validations from ``step`` on in a run of ``steps`` (every step
    validated where fewer steps are left).

    ``train`` re-plans after a step and then validates at it if it is a multiple of ``val_every``, and at its
    last step, so ``left - 1`` multiples must fall in ``[step, steps - 1]``: the first such spacing from an even
    one (the steps left over ``left``) up; where none gives that count exactly, the nearest count, fewer first.
    """
    first = max(step, 1)  # a plan made before the first step: train validates after steps, from step 1
    wanted = min(left - 1, steps - first)

    def count(every: int) -> int:
        return (steps - 1) // every - (first - 1) // every

    if wanted <= 0:
        return steps + 1
    for every in range(max(1, (steps - step) // left), steps + 1):
        if count(every) == wanted:
            return every
    return min(range(1, steps + 1), key=lambda every: (abs(count(every) - wanted), count(every) > wanted))


def resumed_deadline(plan: Plan, step: int, now: float) -> float:
    """When a fit resumed at ``step`` must stop: the share of the plan's training (validations included)
    that its steps left were given, from ``now``. A deadline is the Pacer's target, so it is never the
    whole training time again: a fit stopped halfway would otherwise train half as long again."""
    return now + (plan.steps - step) / plan.steps * (plan.train_s + plan.validation_s)


def continued_decay(optim: OptimConfig, step: int, steps: int) -> OptimConfig:
    """The learning-rate schedule of a run re-planned at ``step`` to end at ``steps``: zero at the new end, over
    its last ``DECAY_SHARE`` as a plan makes it where the decay has not begun, and never a jump: a decay under
    way goes on from the rate it has reached (from step 0 at a lower peak, where it must be that long)."""
    fraction = optim.lr_at(step) / optim.lr
    nominal = round(steps * (1 - DECAY_SHARE))
    under_way = fraction < 1.0 or step > nominal
    start = round(steps - (steps - step) / max(fraction, 1e-9)) if under_way else nominal
    if start >= 0:
        return optim.model_copy(update={"decay_start": start, "decay_steps": steps - start})
    peak = optim.lr * fraction * steps / (steps - step)  # lr_at(step) unchanged, decaying from step 0
    return optim.model_copy(update={"lr": peak, "decay_start": 0, "decay_steps": steps})


class Pacer:
    """Re-plans a fit's steps from the rate they really run at, so training fills the time the plan gave it.

    Called after each step (``trainer.train.Revise``) with the seconds the steps took and the validations done
    (how many, and how long they took). Every so often it measures the rate over the later two thirds of the
    steps so far: a window that grows, so a noisy machine or a checkpoint does not swing the plan to and fro,
    and that forgets a slow start (a GPU's first steps, a busy machine) however long it lasted. Where the steps
    left at that rate would end the training more than ``REVISE_TOLERANCE`` early or late, with the
    validations left at their measured length (the plan's estimate until one is measured), it sets a new step
    count, its learning-rate decay, checkpoints, and validations at the count the plan made, tells
    ``on_revise`` (which says so and saves the plan for ``--resume``), and returns the run's new config.
    """

    def __init__(
        self,
        plan: Plan,
        config: RunConfig,
        deadline: float,
        on_revise: Callable[[Plan, RunConfig, str], None],
        clock: Callable[[], float] = time.monotonic,
    ):
        self.plan, self.config, self.deadline, self.on_revise, self.clock = plan, config, deadline, on_revise, clock
        self.validation_s = plan.validation_s / (VALIDATIONS + 1)
        self.every_s = REVISE_SHARE * plan.train_s
        self.busy: dict[int, float] = {}  # busy seconds after each step, from the first
        self.looked: tuple[float, int] = (0.0, 0)  # (clock, step) at the last look
        self.revised = 0

    def __call__(self, step: int, busy_s: float, validating_s: float = 0.0, validations: int = 0) -> RunConfig | None:
        now = self.clock()
        if not self.busy:  # the first step (warm-up, allocations) is not a rate
            self.busy[step], self.looked = busy_s, (now, step)
            return None
        self.busy[step] = busy_s
        first = min(self.busy)
        steps = self.config.train.steps
        if step >= steps:  # the last step is done and its decay has reached zero: nothing is left to re-plan
            return None
        settled = step >= steps * (1 - SETTLED_SHARE)
        since_look_s, since_look = now - self.looked[0], step - self.looked[1]
        due = settled or since_look_s >= self.every_s or since_look >= REVISE_SHARE * steps
        if not due or since_look < (1 if settled else REVISE_MIN_STEPS):
            return None
        self.looked = (now, step)
        since = min(step - 1, step - (step - first) * 2 // 3)  # the later two thirds of the steps so far
        rate = (busy_s - self.busy[since]) / (step - since)
        validation_s = validating_s / validations if validations else self.validation_s
        left = max(1, VALIDATIONS - validations)  # the last step always validates
        left_s = self.deadline - now - left * validation_s
        off_s = (steps - step) * rate - left_s  # > 0: the deadline would cut the steps off before their decay ends
        if settled:  # a step late, or a share of the training time early, is worth a change now
            if -SETTLED_EARLY * self.plan.train_s <= off_s <= rate:
                return None
            left_s -= rate if off_s > 0 else 0.0
        elif abs(off_s) <= REVISE_TOLERANCE * self.plan.train_s:
            return None
        new_steps = max(step + 1, step + int(left_s / rate))
        optim = continued_decay(self.config.optim, step, new_steps)
        decay_start = optim.decay_start or 0
        checkpoint_every = max(1, min(int(CHECKPOINT_SECONDS / rate), new_steps // 10))
        val_every = validation_every(step, new_steps, left)
        self.config = self.config.model_copy(
            update={
                "train": self.config.train.model_copy(
                    update={"steps": new_steps, "val_every": val_every, "checkpoint_every": checkpoint_every}
                ),
                "optim": optim,
            }
        )
        line = (
            f"re-planned at step {step}: {steps} -> {new_steps} steps, as they run at {rate:.3f} s, not "
            f"{self.plan.step_s:.3f} s; learning rate decaying to zero from step {decay_start}"
        )
        self.plan = replace(
            self.plan,
            step_s=rate,
            steps=new_steps,
            decay_start=decay_start,
            val_every=val_every,
            checkpoint_every=checkpoint_every,
        )
        self.revised += 1
        self.on_revise(self.plan, self.config, line)
        return self.config
