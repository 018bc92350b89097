"""LazyAdam against torch.optim.Adam: dense groups equal it, lazy rows equal it run per row; pose corrections."""

import torch

from pghm.train.data import PoseCorrections
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
