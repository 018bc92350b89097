"""LazyAdam against torch.optim.Adam: dense groups equal it, lazy rows equal it run per row; pose corrections."""

import math

import pytest
import torch

from pghm.train.data import PoseCorrections
from pghm.train.loop import decay_factor
from pghm.train.optim import LazyAdam

STEPS = 12


def random_gradients(steps: int, shape: tuple[int, ...], seed: int) -> list[torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return [torch.randn(shape, generator=gen) for _ in range(steps)]


def test_dense_group_is_adam():
    start = torch.randn(5, 3)
    ours, reference = torch.nn.Parameter(start.clone()), torch.nn.Parameter(start.clone())
    lazy = LazyAdam([ours], lr=0.05)
    adam = torch.optim.Adam([reference], lr=0.05)
    for grad in random_gradients(STEPS, (5, 3), 0):
        # The gradient depends on the parameters, so a wrong update compounds.
        ours.grad = grad + ours.detach()
        reference.grad = grad + reference.detach()
        lazy.step()
        adam.step()
    torch.testing.assert_close(ours, reference)


def test_lazy_rows_are_adam_on_the_steps_that_touched_them():
    rows, width = 6, 4
    gen = torch.Generator().manual_seed(1)
    touched = torch.rand(STEPS, rows, generator=gen) < 0.4
    touched[:, 0] = False  # a row never touched must not move at all
    start = torch.randn(rows, 2, width)
    table = torch.nn.Parameter(start.clone())
    lazy = LazyAdam([{"params": [table], "lazy": True}], lr=0.05)
    grads = random_gradients(STEPS, (rows, 2, width), 2)
    for step in range(STEPS):
        table.grad = (grads[step] + table.detach()) * touched[step].reshape(-1, 1, 1)
        lazy.step()

    for row in range(rows):
        reference = torch.nn.Parameter(start[row].clone())
        adam = torch.optim.Adam([reference], lr=0.05)
        for step in range(STEPS):
            if touched[step, row]:
                reference.grad = grads[step][row] + reference.detach()
                adam.step()
        torch.testing.assert_close(table[row], reference)
    assert torch.equal(table[0], start[0])


def test_state_round_trips_through_state_dict():
    table = torch.nn.Parameter(torch.randn(4, 3))
    first = LazyAdam([{"params": [table], "lazy": True}], lr=0.1)
    table.grad = torch.tensor([[1.0, 0, 0], [0, 0, 0], [0, 2.0, 0], [0, 0, 0]])
    first.step()
    second = LazyAdam([{"params": [table], "lazy": True}], lr=0.1)
    second.load_state_dict(first.state_dict())
    assert torch.equal(second.state[table]["step"], torch.tensor([1.0, 0.0, 1.0, 0.0], dtype=torch.float64))
    torch.testing.assert_close(second.state[table]["exp_avg"], first.state[table]["exp_avg"])


def test_pose_corrections_touch_only_the_estimated_joints_of_the_frames_seen(body):
    """A step on frames {1, 3} moves their rows only, and corrects only the estimator's joints."""
    frames, bones = 5, body.num_bones
    corrections = PoseCorrections.of_estimated_joints(frames, body)
    estimated = sorted(set(body.joint_map.values()))
    optimizer = LazyAdam([{"params": list(corrections.parameters()), "lr": 0.01, "lazy": True}])
    stored = torch.randn(2, bones, 3)
    keys = torch.tensor([1, 3])
    rotations, translation = corrections(keys, stored, torch.zeros(2, 3))
    (rotations.square().sum() + translation.sum()).backward()
    optimizer.step()

    rotations, _ = corrections(keys, stored, torch.zeros(2, 3))
    others = [b for b in range(bones) if b not in estimated]
    assert torch.equal(rotations[:, others], stored[:, others])
    assert not torch.equal(rotations[:, estimated], stored[:, estimated])
    moved = corrections.rotations.detach().flatten(1).ne(0).any(1)
    assert moved.tolist() == [False, True, False, True, False]


def test_dense_parameters_stepped_together_are_each_adam_even_resumed():
    """Several tensors updated by one set of foreach ops, one of which gets its first gradient
    later (its own step count), and the optimiser rebuilt from its state dict halfway: each tensor
    follows torch's Adam run on it alone."""
    shapes = [(5, 3), (7,), (2, 2, 2)]
    starts = [torch.randn(shape, generator=torch.Generator().manual_seed(i)) for i, shape in enumerate(shapes)]
    ours = [torch.nn.Parameter(s.clone()) for s in starts]
    references = [torch.nn.Parameter(s.clone()) for s in starts]
    adams = [torch.optim.Adam([r], lr=0.05) for r in references]
    lazy = LazyAdam(ours, lr=0.05)
    grads = [random_gradients(STEPS, shape, 10 + i) for i, shape in enumerate(shapes)]
    late = 2  # the last tensor has no gradient before this step
    for step in range(STEPS):
        if step == STEPS // 2:
            resumed = LazyAdam(ours, lr=0.05)
            resumed.load_state_dict(lazy.state_dict())
            lazy = resumed
        for i, (p, r, adam) in enumerate(zip(ours, references, adams)):
            if i == len(shapes) - 1 and step < late:
                continue
            p.grad = grads[i][step] + p.detach()
            r.grad = grads[i][step] + r.detach()
            adam.step()
        lazy.step()
    for p, r in zip(ours, references):
        torch.testing.assert_close(p, r)


def test_the_masked_lazy_update_is_the_gathered_one_bit_for_bit():
    """The update a GPU uses (every row computed, the untouched kept by a mask) against the one the
    CPU uses (the touched rows gathered): the same arithmetic on the same rows."""
    from pghm.train.optim import _lazy_update, _masked_lazy_update

    rows = 8
    gen = torch.Generator().manual_seed(3)
    touched = torch.rand(STEPS, rows, generator=gen) < 0.3
    tables = [torch.nn.Parameter(torch.randn(rows, 3, generator=torch.Generator().manual_seed(4))) for _ in "ab"]
    states = [
        {"exp_avg": torch.zeros(rows, 3), "exp_avg_sq": torch.zeros(rows, 3), "step": torch.zeros(rows, dtype=torch.float64)}
        for _ in "ab"
    ]
    group = {"lr": 0.05, "betas": (0.9, 0.999), "eps": 1e-8}
    for step, grad in enumerate(random_gradients(STEPS, (rows, 3), 5)):
        with torch.no_grad():
            for table, state, update in zip(tables, states, (_lazy_update, _masked_lazy_update)):
                table.grad = (grad + table.detach()) * touched[step, :, None]
                update(table, state, group)
    assert torch.equal(tables[0], tables[1])
    assert all(torch.equal(states[0][k], states[1][k]) for k in states[0])


def test_decay_is_one_then_a_half_cosine_to_zero():
    steps = 200
    assert [decay_factor(step, steps, 0.0) for step in (0, 100, 199)] == [1.0, 1.0, 1.0]
    factors = [decay_factor(step, steps, 0.25) for step in range(steps)]
    assert factors[:150] == [1.0] * 150  # the first three quarters undecayed
    assert all(a > b for a, b in zip(factors[150:], factors[151:]))  # then strictly falling
    assert factors[175] == pytest.approx(0.5)  # half way down at the decay's middle: cos(pi / 2) = 0
    assert 0.0 < factors[-1] < 1e-3  # the last step still moves, by (1 - cos(pi / 50)) / 2 of the rate
    whole = [decay_factor(step, steps, 1.0) for step in range(steps)]
    assert whole[0] == 1.0 and sum(whole) == pytest.approx(steps / 2, abs=1)  # the mean of a half cosine


def test_the_fused_finiteness_flag_is_every_value_checked_one_by_one():
    """finite_flag against the brute force over lists mixing dtypes, empty tensors, values next to
    overflow (finite: a maximum cannot overflow) and one NaN, inf or -inf placed anywhere."""
    from pghm.train.loop import finite_flag

    generator = torch.Generator().manual_seed(3)
    base = [
        torch.randn(5, 3, generator=generator),
        torch.full((4,), 3e38),
        torch.randn(7, generator=generator, dtype=torch.float64) * 1e300,
        torch.zeros(0),
        torch.randn(2, 2, 2, generator=generator),
    ]
    assert bool(finite_flag(base)) and bool(finite_flag([])) and bool(finite_flag([torch.zeros(0)]))
    for bad in (math.nan, math.inf, -math.inf):
        for which in (0, 1, 2, 4):
            tensors = [t.clone() for t in base]
            flat = tensors[which].view(-1)
            flat[int(torch.randint(flat.numel(), (1,), generator=generator))] = bad
            truth = all(bool(torch.isfinite(t).all()) for t in tensors)
            assert bool(finite_flag(tensors)) == truth is False, (bad, which)
