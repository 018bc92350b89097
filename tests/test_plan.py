"""The fit's plan (pghm.train.plan): without a budget it is the config's; with one it fits the time
left, re-sized as the measured costs come in, and a fit simulated on a clock it does not know the
speed of ends within the budget's tolerance."""

from __future__ import annotations

import pytest

from pghm.train import plan as plan_module
from pghm.train.plan import (
    CALIBRATION_STEPS,
    COARSE_STEP_COST,
    COST_RATIOS,
    DETAIL,
    EARLY_SETTLING,
    HELD_OUT,
    MIN_DETAIL_SHARE,
    MIN_STAGE_SCALE,
    PHASES,
    POSE_SETTLING,
    STAGE1,
    STAGE2,
    Budget,
    CostModel,
    Phase,
    budget_plan,
)

DEFAULT = [
    Phase(STAGE1, 50, coarse=1.0),
    Phase(EARLY_SETTLING, 20, 35),
    Phase(STAGE2, 450, coarse=2 / 3),
    Phase(POSE_SETTLING, 0, 35),
    Phase(HELD_OUT, 90, 5),
    Phase(DETAIL, 100),
]
"""The default plan of a 40-frame capture (35 training frames, 5 held out)."""


def cost(phases, costs: CostModel, done=None) -> float:
    done = done or {}
    return sum(costs.seconds_left(p, done.get(p.name, 0)) for p in phases)


def test_without_a_budget_the_plan_is_the_configs():
    budget = Budget(DEFAULT)
    assert budget.plan() == DEFAULT
    budget.start(STAGE1)
    assert budget.steps(CALIBRATION_STEPS + 1) == 50
    assert budget.eta() == pytest.approx(cost(DEFAULT, budget.costs))


def test_an_ample_budget_goes_to_the_stages_and_keeps_the_rest():
    costs = CostModel(reference_step=0.5)
    seconds = 2 * cost(DEFAULT, costs)
    planned = {p.name: p for p in budget_plan(DEFAULT, costs, seconds)}
    for name in (EARLY_SETTLING, HELD_OUT, DETAIL):
        assert planned[name] == next(p for p in DEFAULT if p.name == name)
    scale = planned[STAGE2].steps / 450
    assert scale > 1 and planned[STAGE1].steps == round(50 * scale)
    # As close to the budget as a whole step allows (the stages scale together, one step each).
    spent = cost(list(planned.values()), costs)
    assert seconds - 2 * COST_RATIOS[STAGE1] * costs.step_seconds() <= spent <= seconds


def test_a_short_budget_shortens_the_detail_stage_then_drops_it_then_shrinks_the_stages():
    costs = CostModel(reference_step=0.5)
    detail = costs.seconds_left(DEFAULT[-1])
    seconds = cost(DEFAULT, costs) - detail / 2  # room for the stages at their steps and half the layer
    planned = {p.name: p for p in budget_plan(DEFAULT, costs, seconds)}
    assert planned[STAGE1].steps == 50 and planned[STAGE2].steps == 450
    assert 49 <= planned[DETAIL].steps <= 50 and cost(list(planned.values()), costs) <= seconds
    seconds = cost(DEFAULT, costs) - (1 - MIN_DETAIL_SHARE + 0.1) * detail  # less than the least share
    planned = {p.name: p for p in budget_plan(DEFAULT, costs, seconds)}
    assert planned[DETAIL].steps == 0 and planned[STAGE2].steps >= 450
    assert cost(list(planned.values()), costs) <= seconds
    seconds = cost(DEFAULT[1:2] + DEFAULT[4:5], costs) + 0.5 * cost([DEFAULT[0], DEFAULT[2]], costs)
    planned = {p.name: p for p in budget_plan(DEFAULT, costs, seconds)}
    assert planned[DETAIL].steps == 0 and 0.45 * 450 <= planned[STAGE2].steps <= 0.5 * 450
    assert planned[EARLY_SETTLING].steps == 20 and planned[HELD_OUT].steps == 90


def test_a_budget_below_the_fewest_stage_steps_shrinks_the_settling():
    costs = CostModel(reference_step=0.5)
    stages = cost([Phase(STAGE1, round(50 * MIN_STAGE_SCALE)), Phase(STAGE2, round(450 * MIN_STAGE_SCALE))], costs)
    planned = {p.name: p for p in budget_plan(DEFAULT, costs, stages + 10.0)}
    assert planned[STAGE2].steps == round(450 * MIN_STAGE_SCALE)
    assert 0 < planned[EARLY_SETTLING].steps < 20 and 0 < planned[HELD_OUT].steps < 90
    assert cost(list(planned.values()), costs) <= stages + 10.0


def test_a_part_run_phase_keeps_what_it_has_run():
    costs = CostModel(reference_step=0.5)
    planned = {p.name: p for p in budget_plan(DEFAULT[2:], costs, 1.0, done={STAGE2: 300})}
    assert planned[STAGE2].steps == 300


def test_a_phase_measured_replaces_its_estimate_and_informs_its_kind():
    costs = CostModel(reference_step=0.5)
    assert costs.unit_seconds(STAGE2) == 0.5
    costs.record(STAGE1, CALIBRATION_STEPS - 1, 100.0)  # too few steps to trust
    assert costs.unit_seconds(STAGE2) == 0.5
    costs.record(STAGE1, 10, 10 * COST_RATIOS[STAGE1])
    assert costs.unit_seconds(STAGE1) == pytest.approx(COST_RATIOS[STAGE1])
    assert costs.unit_seconds(STAGE2) == pytest.approx(1.0)  # stage 1's step over its ratio
    assert costs.unit_seconds(HELD_OUT) == pytest.approx(COST_RATIOS[HELD_OUT])
    costs.record(EARLY_SETTLING, 700, 700 * 0.2)  # settling measured: the held-out alignment follows it
    assert costs.unit_seconds(HELD_OUT) == pytest.approx(0.2 * COST_RATIOS[HELD_OUT] / COST_RATIOS[EARLY_SETTLING])
    assert costs.unit_seconds(STAGE2) == pytest.approx(1.0)  # a stage still follows the stages


class Clock:
    """A clock the simulated fit advances: what ``time.perf_counter`` reads in the plan."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_a_stages_coarse_steps_count_their_share_of_a_full_step():
    stage = Phase(STAGE2, 450, coarse=2 / 3)
    assert stage.work(450) == pytest.approx(300 * COARSE_STEP_COST + 150)
    assert stage.work(100) == pytest.approx(100 * COARSE_STEP_COST) and stage.work(0) == 0
    costs = CostModel(reference_step=0.5)
    assert costs.seconds_left(stage, 300) == pytest.approx(150 * 0.5)  # the fine steps are left
    costs.record(STAGE2, 200, 200 * 0.3, work=stage.work(200))  # coarse steps at 0.3 s each
    assert costs.unit_seconds(STAGE2) == pytest.approx(0.3 / COARSE_STEP_COST)  # a full step's


@pytest.mark.parametrize("coarse_cost", [0.5, 0.9])
@pytest.mark.parametrize("speed", [0.3, 1.0, 3.0])
@pytest.mark.parametrize("minutes", [2, 5, 10])
def test_a_simulated_fit_ends_within_its_budget(monkeypatch, speed, minutes, coarse_cost):
    """Each unit of each phase costs its ratio times a true step cost that the plan's reference
    misses by ``speed`` (0.3 to 3 times), plus 5 % per-phase noise in the ratios, and a stage's
    coarse step ``coarse_cost`` of a full one where the plan assumes :data:`COARSE_STEP_COST`; the
    fit runs its stages step by step as the loop does, asking the plan after each: it ends within
    15 % of the budget (docs: the fit's --minutes target on an idle machine)."""
    clock = Clock()
    monkeypatch.setattr(plan_module.time, "perf_counter", clock)
    true_step = plan_module.REFERENCE_STEP_SECONDS * speed
    noise = dict(zip(PHASES, (1.05, 0.95, 1.0, 1.05, 0.95, 1.05)))
    budget = Budget(DEFAULT, 60.0 * minutes)
    for name in PHASES:
        if not budget.phases[name].steps:
            budget.skip(name, "not planned")
            continue
        phase = budget.start(name)
        unit = COST_RATIOS[name] * noise[name] * true_step
        if name in (STAGE1, STAGE2, DETAIL):
            done = 0
            while done < (steps := budget.steps(done)):
                clock.now += unit * (coarse_cost if done < phase.coarse * steps else 1.0)
                done += 1
                budget.progress(done)
        else:
            clock.now += phase.units * unit
            budget.progress(phase.units)
        budget.finish()
    spent = budget.elapsed()
    assert abs(spent - 60 * minutes) <= 0.15 * 60 * minutes, budget.records


def test_after_the_stages_the_detail_stage_gets_the_time_left():
    costs = CostModel(reference_step=0.5)
    after = [Phase(HELD_OUT, 90, 5), Phase(DETAIL, 100)]
    held = costs.seconds_left(after[0])
    # Half a step's time more than the steps asked: the plan rounds down what rounding may leave under 30.
    planned = {p.name: p for p in budget_plan(after, costs, held + 30.5 * costs.unit_seconds(DETAIL))}
    assert planned[HELD_OUT].steps == 90 and planned[DETAIL].steps == 30
    planned = {p.name: p for p in budget_plan(after[1:], costs, 5.5 * costs.unit_seconds(DETAIL), {DETAIL: 40})}
    assert planned[DETAIL].steps == 45


def test_every_replan_sizes_the_phases_from_the_configs_steps(monkeypatch):
    """A slow start drops the detail stage; once the stage runs faster than the reference the plan
    gives it back all its steps: a re-plan scales the config's phases, not the last plan's, whose
    dropped detail stage could never come back."""
    clock = Clock()
    monkeypatch.setattr(plan_module.time, "perf_counter", clock)
    costs = CostModel(reference_step=0.5)
    budget = Budget(DEFAULT, cost(DEFAULT, costs), costs)
    assert budget.phases[DETAIL].steps == 100
    budget.start(STAGE1)
    unit = COST_RATIOS[STAGE1] * 0.5
    clock.now += 3 * 2 * unit  # three steps at twice the reference cost
    budget.progress(3)
    budget.steps(3)
    assert budget.phases[DETAIL].steps == 0
    clock.now += 27 * 0.5 * unit  # 27 more at half of it: the stage's mean 0.65 of the reference
    budget.progress(30)
    budget.steps(30)
    assert budget.phases[STAGE2].steps >= 450 and budget.phases[DETAIL].steps == 100
