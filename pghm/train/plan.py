"""The fit as a plan of phases, what each costs on the machine it runs on, and a time budget.

``pghm fit`` runs :data:`PHASES` in order (:mod:`pghm.train.fit`). A phase's size is counted in
units of its own kind (:class:`Phase`): a stage's optimisation steps, a settling pass's
frame-steps (frames x steps per frame), the detail stage's steps. The cost model
(:class:`CostModel`) gives seconds per unit: a phase's own mean once it has run some, else the
stage-2 step's cost times the phase's ratio to it (:data:`COST_RATIOS`, measured on 2 cores); the
stage-2 step is itself estimated from stage 1's first steps before it runs, and from
:data:`REFERENCE_STEP_SECONDS` before any step.

Without a budget the plan is the config's: fixed steps, so the avatar is a function of the inputs,
seed and options. With one (``pghm fit --minutes N``, :class:`Budget`) the plan is sized to the
time left, and sized again at every step of a stage as the measured costs come in:

    sum over the phases p still to run of  units_p * c_p  <=  deadline - now.

The time goes first to the settling passes and the held-out alignment at their default steps
(cheap, and what the outline needs), then to the stages at their config's steps, then to the
detail stage (down to :data:`MIN_DETAIL_SHARE` of its steps), and only then to more stage steps,
which scale together (stage 1 : stage 2 kept): measured, the detail layer buys more than stage
steps past the config's, which buy next to nothing. A budget too small for the stages drops the
detail stage and scales them down to :data:`MIN_STAGE_SCALE` of their steps, and then the settling
passes (docs/training.md, "The plan and the budget").
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

from pghm.train.coarse import coarse_steps

log = logging.getLogger(__name__)

STAGE1, EARLY_SETTLING, STAGE2, POSE_SETTLING, HELD_OUT, DETAIL = (
    "stage 1",
    "early settling",
    "stage 2",
    "pose settling",
    "held-out poses",
    "detail",
)
PHASES = (STAGE1, EARLY_SETTLING, STAGE2, POSE_SETTLING, HELD_OUT, DETAIL)
"""A fit's phases in the order they run (the names its profile uses)."""
STAGES = (STAGE1, STAGE2)
SETTLING = (EARLY_SETTLING, POSE_SETTLING, HELD_OUT)

COST_RATIOS = {
    STAGE1: 0.82,
    EARLY_SETTLING: 0.073,
    STAGE2: 1.0,
    POSE_SETTLING: 0.1,
    HELD_OUT: 0.096,
    DETAIL: 1.1,
}
"""Seconds per full-resolution unit of each phase over a full-resolution stage-2 step's: the shared
real video's and the synthetic turn's default fits on 2 cores, their settling in two processes
(benchmarks/results/fit_profile_*_zen4_processes.json: stage 1 0.80-0.83, early settling 0.073 on
both, held-out 0.083 and 0.109; the detail stage with its validations, on the dynamic render and
at most 12 checked frames, 1.07-1.14 in fit_profile_*_zen4_wide_skinning.json; the pose settling as
first measured, fit_profile_*_after3.json). A settling unit is one frame's step."""
REFERENCE_STEP_SECONDS = 0.6
"""A stage-2 step of a 512-pixel capture at L = 128 on 2 cores, the estimate before any step has run."""
CALIBRATION_STEPS = 3
"""Steps of a phase after which its own mean cost replaces the estimate."""
MIN_STAGE_SCALE = 0.1
"""Fewest stage steps a budget plans, as a share of the config's (stage 1 at 50 keeps 5): what a
2-minute budget leaves the stages on a machine 3 times slower than the reference."""
MAX_STAGE_SCALE = 40.0
"""Most stage steps a budget plans, as a multiple of the config's."""
COARSE_STEP_COST = 0.7
"""A coarse stage step's seconds (:mod:`pghm.train.coarse`: a quarter of the pixels, the same
network) over a full-resolution one's, until the stage's own steps say otherwise: 0.73-0.78
measured on the real video and the turn (docs/lab/fit-speed.md)."""
MIN_DETAIL_SHARE = 0.4
"""Least share of the detail stage's steps a budget plans rather than none: at the default 100,
40 steps, two of its validations (every 20); on the synthetic turn its best layer came at step 40
and bought 0.8 dB (benchmarks/results/bench_real_budget.json)."""


@dataclass(frozen=True)
class Phase:
    """One phase of a plan: ``steps`` optimisation steps (a settling pass: steps per frame) over
    ``frames`` frames each (1 for a stage); its size is ``steps * frames`` units. A stage's first
    ``coarse`` share of steps are coarse, each :data:`COARSE_STEP_COST` of a full step's work."""

    name: str
    steps: int
    frames: int = 1
    coarse: float = 0.0

    @property
    def units(self) -> int:
        return self.steps * self.frames

    def work(self, units: int) -> float:
        """The first ``units`` units in full steps' worth: the coarse ones (the step numbers below
        ``coarse * steps``, as the loop counts them) at :data:`COARSE_STEP_COST` each."""
        coarse = min(units, coarse_steps(self.coarse, self.steps))
        return COARSE_STEP_COST * coarse + (units - coarse)


class CostModel:
    """Seconds per unit of each phase on this machine, measured as phases run (module doc)."""

    def __init__(self, reference_step: float = REFERENCE_STEP_SECONDS) -> None:
        self.reference_step = reference_step
        self.seconds: dict[str, float] = {}
        self.units: dict[str, int] = {}
        self.work: dict[str, float] = {}

    def record(self, name: str, units: int, seconds: float, work: float | None = None) -> None:
        """A phase has run ``units`` units, ``work`` full units' worth (:meth:`Phase.work`; default
        ``units``), in ``seconds`` so far (its totals, not increments)."""
        self.units[name], self.seconds[name] = units, seconds
        self.work[name] = units if work is None else work

    def measured(self, name: str) -> float | None:
        """The phase's own mean seconds per full unit, once it has run :data:`CALIBRATION_STEPS` units."""
        units = self.units.get(name, 0)
        return self.seconds[name] / self.work[name] if units >= CALIBRATION_STEPS else None

    def step_seconds(self, like: str = STAGE2) -> float:
        """The stage-2 step's cost as a phase of the kind of ``like`` predicts it: the latest measured
        phase of that kind (a settling pass for a settling pass, else a stage) over its ratio, else any
        measured phase's, else the reference."""
        kinds = [SETTLING, (*STAGES, DETAIL)]
        kinds.sort(key=lambda kind: like not in kind)
        for kind in kinds:
            for name in reversed(kind):
                if (rate := self.measured(name)) is not None:
                    return rate / COST_RATIOS[name]
        return self.reference_step

    def unit_seconds(self, name: str) -> float:
        measured = self.measured(name)
        return measured if measured is not None else COST_RATIOS[name] * self.step_seconds(name)

    def seconds_left(self, phase: Phase, done: int = 0) -> float:
        """Seconds ``phase`` still needs with ``done`` of its units run."""
        left = phase.work(phase.units) - phase.work(min(done, phase.units))
        return left * self.unit_seconds(phase.name)


def scaled(
    phases: list[Phase], stage_scale: float, settle_scale: float, detail: float, done: dict[str, int]
) -> list[Phase]:
    """``phases`` with the stages' steps times ``stage_scale``, the settling passes' times
    ``settle_scale`` and the detail stage's times ``detail`` (0: dropped), each at least its
    ``done`` units."""
    out = []
    for phase in phases:
        if phase.name in STAGES:
            steps = max(1, round(phase.steps * stage_scale))
        elif phase.name in SETTLING:
            steps = round(phase.steps * settle_scale) if phase.steps else 0
        else:
            steps = round(phase.steps * detail)
        floor = math.ceil(done.get(phase.name, 0) / max(phase.frames, 1))
        out.append(replace(phase, steps=max(steps, floor)))
    return out


def budget_plan(
    phases: list[Phase], costs: CostModel, seconds: float, done: dict[str, int] | None = None
) -> list[Phase]:
    """The phases still to run (the first possibly part-run: ``done`` units of it), resized to
    cost at most ``seconds`` by the policy of the module doc."""
    done = done or {}

    def cost(plan: list[Phase]) -> float:
        return sum(costs.seconds_left(p, done.get(p.name, 0)) for p in plan)

    def largest_scale(low: float, high: float, plan_at) -> float | None:
        """The largest scale in [low, high] whose plan fits (bisection: cost grows with the scale)."""
        if cost(plan_at(low)) > seconds:
            return None
        if cost(plan_at(high)) <= seconds:
            return high
        for _ in range(40):
            middle = (low + high) / 2
            low, high = (middle, high) if cost(plan_at(middle)) <= seconds else (low, middle)
        return low

    has_detail = any(p.name == DETAIL and p.steps for p in phases)
    if not any(p.name in STAGES for p in phases):
        # The stages are done: the settling passes keep their steps if they can, and the detail
        # stage gets what time they leave.
        settle = largest_scale(0.0, 1.0, lambda s: scaled(phases, 1.0, s, 0.0, done))
        plan = scaled(phases, 1.0, 1.0 if settle is None else settle, 0.0, done)
        if has_detail:
            spare = max(seconds - cost(plan), 0.0) / costs.unit_seconds(DETAIL)
            detail = next(p for p in phases if p.name == DETAIL)
            steps = min(detail.steps, done.get(DETAIL, 0) + math.floor(spare))
            plan = [replace(p, steps=steps) if p.name == DETAIL else p for p in plan]
        return plan
    if has_detail:
        # The stages at their config's steps and the whole detail stage, with more stage steps if
        # there is time; else the stages at their steps and as much of the detail stage as fits
        # (it keeps its best layer whenever it stops: MIN_DETAIL_SHARE of it holds two checks).
        scale = largest_scale(1.0, MAX_STAGE_SCALE, lambda s: scaled(phases, s, 1.0, 1.0, done))
        if scale is not None:
            return scaled(phases, scale, 1.0, 1.0, done)
        share = largest_scale(MIN_DETAIL_SHARE, 1.0, lambda d: scaled(phases, 1.0, 1.0, d, done))
        if share is not None:
            return scaled(phases, 1.0, 1.0, share, done)
    scale = largest_scale(MIN_STAGE_SCALE, MAX_STAGE_SCALE, lambda s: scaled(phases, s, 1.0, 0.0, done))
    if scale is not None:
        return scaled(phases, scale, 1.0, 0.0, done)
    settle = largest_scale(0.0, 1.0, lambda s: scaled(phases, MIN_STAGE_SCALE, s, 0.0, done))
    return scaled(phases, MIN_STAGE_SCALE, settle or 0.0, 0.0, done)


def describe(plan: list[Phase], costs: CostModel) -> str:
    """One line per phase to run: its steps, frames and estimated seconds, and the total."""
    lines = []
    for phase in plan:
        if not phase.units:
            continue
        size = f"{phase.steps} steps" + (f" x {phase.frames} frames" if phase.frames > 1 else "")
        lines.append(f"  {phase.name:<15} {size:<24} ~{costs.seconds_left(phase):5.0f} s")
    total = sum(costs.seconds_left(p) for p in plan)
    return "\n".join([*lines, f"  {'total':<15} {'':<24} ~{total:5.0f} s ({total / 60:.1f} min)"])


class Budget:
    """A fit's plan as it runs: the phases' sizes, their costs as measured, and the deadline of a
    time budget of ``seconds`` from ``started`` (a ``time.perf_counter`` reading; default now;
    ``seconds`` None: the config's plan, unchanged).

    The fit asks :meth:`steps` of the phase it is in (at every step of a stage: its planned total,
    re-sized to the time left when there is a budget), reports progress with :meth:`progress`, and
    closes each phase with :meth:`finish`; :meth:`eta` is the seconds the plan has left.
    """

    def __init__(
        self,
        phases: list[Phase],
        seconds: float | None = None,
        costs: CostModel | None = None,
        started: float | None = None,
    ) -> None:
        self.costs = costs or CostModel()
        self.started = time.perf_counter() if started is None else started
        self.deadline = None if seconds is None else self.started + seconds
        self.phases = {p.name: p for p in phases}
        self.planned = dict(self.phases)
        """The config's phases: every re-plan sizes the remaining ones from these, so the policy's
        shares and scales are of the config's steps, not of the last plan's."""
        self.order = [p.name for p in phases]
        self.done: dict[str, int] = {}
        self.records: dict[str, dict] = {}
        self.current: str | None = None
        self._phase_started = self.started
        self._units_at_start = 0
        self._replan()

    def remaining(self) -> list[Phase]:
        """The phases not yet finished, the current one first."""
        return [self.phases[n] for n in self.order if n not in self.records]

    def plan(self) -> list[Phase]:
        return [self.phases[n] for n in self.order]

    def _replan(self) -> None:
        if self.deadline is None:
            return
        left = self.deadline - time.perf_counter()
        remaining = [self.planned[p.name] for p in self.remaining()]
        for phase in budget_plan(remaining, self.costs, max(left, 0.0), self.done):
            self.phases[phase.name] = phase

    def start(self, name: str, done: int = 0) -> Phase:
        """Enter phase ``name``, ``done`` of its units already run (a resumed stage); returns its planned size."""
        self.current, self._phase_started, self._units_at_start = name, time.perf_counter(), done
        self.done[name] = done
        self._replan()
        return self.phases[name]

    def progress(self, units: int) -> None:
        """The current phase has run ``units`` of its units; those since it started measure its cost."""
        self.done[self.current] = units
        phase, start = self.phases[self.current], self._units_at_start
        work = phase.work(units) - phase.work(start)
        self.costs.record(self.current, units - start, time.perf_counter() - self._phase_started, work)

    def steps(self, units_done: int) -> int:
        """The current stage's planned steps, re-sized to the time left after ``units_done`` steps."""
        if self.deadline is not None and units_done >= CALIBRATION_STEPS:
            self._replan()
        return self.phases[self.current].steps

    def finish(self, result: dict | None = None) -> dict:
        """Close the current phase: its record (steps, seconds, what it bought) for the avatar's metadata."""
        phase, seconds = self.phases[self.current], time.perf_counter() - self._phase_started
        record = {"steps": phase.steps, "frames": phase.frames, "seconds": round(seconds, 1), **(result or {})}
        self.records[self.current] = record
        self.current = None
        return record

    def skip(self, name: str, why: str) -> None:
        """Phase ``name`` will not run (resumed past it, or nothing to do)."""
        self.phases[name] = replace(self.phases[name], steps=0)
        self.records[name] = {"steps": 0, "why": why}

    def eta(self) -> float:
        """Seconds the plan still needs, by the cost model."""
        return sum(self.costs.seconds_left(p, self.done.get(p.name, 0)) for p in self.remaining())

    def elapsed(self) -> float:
        return time.perf_counter() - self.started
