"""Adam with lazy rows, for tables of per-item parameters that a step touches sparsely.

The identity bank (one latent per identity) and the pose corrections (one per frame) are
tables whose rows a step sees only when its batch contains that identity or frame: one
frame in several hundred per step. Dense Adam mishandles such rows twice over:

- after a visit, the first moment keeps moving the row for ~1 / (1 - beta1) steps with
  no gradient, so the visit's step is applied about ten times over;
- between visits, the second moment decays towards zero, so the next visit's step is
  larger than the gradient warrants.

A lazy group (``lazy=True``) updates only the rows whose gradient is not all zero, each with
its own step count for the bias correction (TensorFlow's LazyAdam, torch's SparseAdam),
and leaves the other rows and their moments untouched. Its gradients stay dense tensors, so
DDP's all-reduce, gradient clipping and the loop's finite-value guard see them as before;
a row is touched when any process's batch touched it. Other groups are plain Adam.

Per element, with g the gradient, t the row's step count and alpha the learning rate:
    m <- beta1 m + (1 - beta1) g,   v <- beta2 v + (1 - beta2) g^2,
    p <- p - alpha (m / (1 - beta1^t)) / (sqrt(v / (1 - beta2^t)) + eps).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch
from torch import Tensor


class LazyAdam(torch.optim.Optimizer):
    """Adam whose ``lazy`` param groups update only the rows (first index) a step touched.

    Args:
        params: parameters or param groups; a group with ``lazy=True`` is a table of rows.
        lr, betas, eps: Adam's hyperparameters (torch.optim.Adam's defaults).
    """

    def __init__(
        self,
        params: Iterable,
        lr: float = 1e-3,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        super().__init__(params, {"lr": lr, "betas": betas, "eps": eps, "lazy": False})
        self._host_steps: dict[Tensor, int] = {}
        """Each dense parameter's step count, kept on the host beside its ``state["step"]``."""

    def load_state_dict(self, state_dict: dict) -> None:
        """As torch's, with each parameter's step counts on its device: torch moves the moments to
        the parameter's device but leaves "step" where the checkpoint held it (the CPU)."""
        super().load_state_dict(state_dict)
        self._host_steps = {}
        for parameter, state in self.state.items():
            if "step" in state:
                state["step"] = state["step"].to(parameter.device)

    @torch.no_grad()
    def step(self, closure=None) -> None:
        if closure is not None:
            raise ValueError("LazyAdam does not take a closure")
        for group in self.param_groups:
            dense = []
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if not state:
                    rows = p.shape[0] if group["lazy"] else 1
                    state["exp_avg"] = torch.zeros_like(p)
                    state["exp_avg_sq"] = torch.zeros_like(p)
                    state["step"] = torch.zeros(rows, dtype=torch.float64, device=p.device)
                    self._host_steps[p] = 0
                if group["lazy"]:
                    (_masked_lazy_update if p.is_cuda else _lazy_update)(p, state, group)
                else:
                    dense.append(p)
            if dense:
                self._dense_update(dense, group)

    def _dense_update(self, params: list[Tensor], group: dict) -> None:
        """Adam on every element of ``params``, each op once for all of them (torch's foreach ops).

        The bias corrections come from step counts the host keeps beside the tensors (read from
        them once, after a checkpoint is loaded), so no step reads the device."""
        beta1, beta2 = group["betas"]
        grads = [p.grad for p in params]
        states = [self.state[p] for p in params]
        exp_avgs, exp_avg_sqs = [s["exp_avg"] for s in states], [s["exp_avg_sq"] for s in states]
        steps = []
        for p, state in zip(params, states):
            step = self._host_steps.get(p)
            step = (round(float(state["step"][0])) if step is None else step) + 1
            self._host_steps[p] = step
            steps.append(step)
        torch._foreach_add_([s["step"] for s in states], 1.0)
        torch._foreach_lerp_(exp_avgs, grads, 1 - beta1)
        torch._foreach_mul_(exp_avg_sqs, beta2)
        torch._foreach_addcmul_(exp_avg_sqs, grads, grads, value=1 - beta2)
        denominators = torch._foreach_sqrt(exp_avg_sqs)
        torch._foreach_div_(denominators, [math.sqrt(1 - beta2**t) for t in steps])
        torch._foreach_add_(denominators, group["eps"])
        torch._foreach_addcdiv_(params, exp_avgs, denominators, [-group["lr"] / (1 - beta1**t) for t in steps])


def _adam_update(p: Tensor, grad: Tensor, exp_avg: Tensor, exp_avg_sq: Tensor, step: Tensor, group: dict) -> None:
    """One in-place Adam update of p (R, ...) with per-row step counts step (R,) or (1,)."""
    beta1, beta2 = group["betas"]
    exp_avg.lerp_(grad, 1 - beta1)
    exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
    per_row = (-1,) + (1,) * (p.dim() - 1) if p.dim() else ()
    # Bias corrections in float64, as torch.optim.Adam computes them.
    step_size = (group["lr"] / (1 - beta1**step)).to(p.dtype).reshape(per_row)
    correction2_sqrt = (1 - beta2**step).sqrt().to(p.dtype).reshape(per_row)
    denominator = (exp_avg_sq.sqrt() / correction2_sqrt).add_(group["eps"])
    p.sub_(exp_avg / denominator * step_size)


def _lazy_update(p: Tensor, state: dict, group: dict) -> None:
    """Adam on the rows of p (R, ...) whose gradient has a non-zero entry; the rest are untouched."""
    rows = p.grad.reshape(p.shape[0], -1).ne(0).any(1).nonzero().squeeze(1)
    if len(rows) == 0:
        return
    exp_avg, exp_avg_sq, step = state["exp_avg"][rows], state["exp_avg_sq"][rows], state["step"][rows] + 1
    values = p[rows]
    _adam_update(values, p.grad[rows], exp_avg, exp_avg_sq, step, group)
    p[rows] = values
    state["exp_avg"][rows] = exp_avg
    state["exp_avg_sq"][rows] = exp_avg_sq
    state["step"][rows] = step


def _masked_lazy_update(p: Tensor, state: dict, group: dict) -> None:
    """:func:`_lazy_update` without asking which rows were touched: every row is computed and the
    untouched ones kept by a mask (on a GPU, reading the touched rows' indices would wait for the
    device; computing the whole table costs it little). Equal to :func:`_lazy_update` bit for bit."""
    touched = p.grad.reshape(p.shape[0], -1).ne(0).any(1)
    step = state["step"] + touched
    exp_avg, exp_avg_sq, values = state["exp_avg"].clone(), state["exp_avg_sq"].clone(), p.clone()
    _adam_update(values, p.grad, exp_avg, exp_avg_sq, step.clamp(min=1), group)
    rows = touched.reshape((-1,) + (1,) * (p.dim() - 1))
    p.copy_(torch.where(rows, values, p))
    state["exp_avg"].copy_(torch.where(rows, exp_avg, state["exp_avg"]))
    state["exp_avg_sq"].copy_(torch.where(rows, exp_avg_sq, state["exp_avg_sq"]))
    state["step"].copy_(step)
