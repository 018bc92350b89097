"""The optimisation loop shared by prior training and personalisation.

One step: plan the global batch from (seed, step), evaluate this process's groups (model,
both renders, the paper's loss), average, backward (DDP averages across processes),
guard against non-finite values, clip, update. Every ``checkpoint_every`` steps, and on
Ctrl-C, the full state (parameters, optimizer, step, learning-rate scale, skipped frames)
is saved atomically; ``resume`` continues from it exactly.

Numerical guard: a step whose loss or gradients are not finite is skipped and the
learning rate halved (logged); a step that would leave non-finite parameters is undone
from a copy taken before it and likewise halves the rate. No NaN is ever left behind.
"""

from __future__ import annotations

import contextlib
import io
import logging
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor, nn
from tqdm import tqdm

from pghm._fault_injection import interrupt_point
from pghm.body.pose import BodyPose
from pghm.device import move
from pghm.errors import DatasetError, PghmError
from pghm.io.atomic import atomic_write_bytes
from pghm.io.torch_file import TorchFileError, load_torch_file
from pghm.model.geometry import SubjectGeometry
from pghm.model.pghm import PGHM, AvatarOutput
from pghm.splat import Camera, render
from pghm.train import distributed, profile
from pghm.train.background import BACKGROUND_KINDS, BLACK, WHITE, composite_render, composite_target, draw_backgrounds
from pghm.train.coarse import coarse_samples, coarse_steps
from pghm.train.data import PoseCorrections, Sample, TrainingData
from pghm.train.losses import LossWeights, objective, psnr, silhouette
from pghm.train.plan import Budget
from pghm.train.resident import Resident

log = logging.getLogger(__name__)

LR_BACKOFF = 0.5
"""Learning-rate factor applied after a non-finite step."""
SAFE_VALUES = (0.0, 1.0, 0.0, 0.0)
"""Means, scales, colours and opacities that stand in for non-finite ones in a step that is then
skipped: an invisible Gaussian the splatter accepts."""
CHECKPOINT_FORMAT = "pghm-checkpoint"
BYTES_PER_TRAINING_PIXEL = 8192
"""Memory one image pixel of a step holds (target, mask, both renders, the splatter's per-pixel
state, their gradients), measured: ``pghm fit`` of the tiny subject (64 x 64) with the shipped
prior peaks at 2.4 GB RSS with 50 images per group and 12.9 GB with 400, 7.3 KB per pixel."""
MAX_LEARNING_RATE = 1e6
"""Largest learning rate accepted: far above any useful one (below 1), far below the 3e37 where
Adam's float32 step size (up to 10 lr early on) overflows and torch raises instead of stepping."""


@dataclass
class LoopConfig:
    """How long and on what one optimisation stage runs."""

    steps: int = 1000
    """Optimisation steps of this stage."""
    shards: int = 1
    """Identity groups per global batch; must be a multiple of the number of processes."""
    images_per_shard: int = 4
    """Images per group (views/frames of one identity)."""
    seed: int = 0
    """Seeds the batch plan; the same seed and step give the same batch."""
    checkpoint_every: int = 100
    """Steps between atomic checkpoints (0: only on Ctrl-C). The checkpoint is removed once the
    output is written (pghm.train.prior, pghm.train.fit): a finished run leaves only its result."""
    same_instant: bool = True
    """Draw a multi-view group's images from one time step: its views share one pose
    evaluation (skinning, E_p, D_pose), so a step costs one pose branch, not one per image."""
    max_grad_norm: float = 1.0
    """Gradient clipping threshold (global L2 norm)."""
    loss: LossWeights = field(default_factory=LossWeights)
    progress: bool = True
    """A tqdm bar of the stage's steps on stderr (rank 0's)."""
    decay: float = 0.0
    """Share of the stage's last steps over which every learning rate falls to zero as a half
    cosine (:func:`decay_factor`); 0: constant rates."""
    coarse: float = 0.0
    """Share of the stage's first steps that render and score each image at half its resolution
    (:mod:`pghm.train.coarse`): a quarter of the pixels; 0: every step at full resolution."""
    background: str = "white"
    """What the targets are composited on and the renders drawn on, one of
    :data:`pghm.train.background.BACKGROUND_KINDS`: ``white`` (the paper's stored targets) or a
    background drawn per image and step (``colour``, ``gradient``)."""

    def __post_init__(self) -> None:
        for name in ("decay", "coarse"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 <= value <= 1.0):
                raise PghmError(f"{name} must be a share of the steps from 0 to 1, got {value!r}")
        if self.background not in BACKGROUND_KINDS:
            raise PghmError(f"background must be one of {', '.join(BACKGROUND_KINDS)}, got {self.background!r}")


def decay_factor(step: int, steps: int, share: float) -> float:
    """The learning rates' factor at ``step`` (0-based) of ``steps`` when the last ``share`` of them decay:

        f = 1                              for step < s0 = (1 - share) steps
        f = (1 + cos(pi t)) / 2,  t = (step - s0) / (steps - s0)   after,

    so f falls from 1 to just above 0 at the last step. Adam's constant rate leaves the parameters
    jittering by about that rate around their optimum; annealing it lets them settle there. It does
    not make fewer steps do: 300 annealed steps of stage 2 score 0.4-0.9 dB below 450 constant ones
    (docs/training.md, "Coarse to fine").
    """
    start = (1.0 - share) * steps
    if share <= 0.0 or step < start:
        return 1.0
    return 0.5 * (1.0 + math.cos(math.pi * (step - start) / (steps - start)))


def distinct_frames(samples: list[Sample]) -> list[int]:
    """The sorted frame keys of samples; the views of one frame share its pose."""
    return sorted({s.frame_key for s in samples})


class AvatarObjective(nn.Module):
    """Model, optional personal latent, optional pose corrections, and the paper's loss.

    Wrapped as a whole by DDP, so every trainable tensor's gradient is averaged across
    processes in the same way.

    Args:
        model: the network.
        latent: a personal full-resolution latent (1, C, L, L) that replaces the decoded
            identity map (personalisation), or None to decode bank latents (prior).
        corrections: per-frame pose corrections, or None.
        lpips: the LPIPS network, or None to leave the term out.
        dynamic_only: render and score the dynamic set alone, its terms standing in for the
            static set's (:func:`pghm.train.losses.objective`): what fits poses to a frozen
            avatar, which is shown with its dynamic set, at half the splatting.
    """

    def __init__(
        self,
        model: PGHM,
        latent: nn.Parameter | None,
        corrections: PoseCorrections | None,
        weights: LossWeights,
        lpips: nn.Module | None,
        dynamic_only: bool = False,
    ) -> None:
        super().__init__()
        self.model = model
        self.latent = latent
        self.corrections = corrections
        self.weights = weights
        self.lpips = lpips
        self.dynamic_only = dynamic_only
        self._resident: Resident | None = None

    @property
    def device(self) -> torch.device:
        """Where the model lives: the step's samples, backgrounds and indices are made there."""
        return self.model.identity_bank.device

    @property
    def resident(self) -> Resident:
        """The samples, indices and constants of the steps, kept on the model's device."""
        if self._resident is None or self._resident.device != self.device:
            self._resident = Resident(self.device)
        return self._resident

    def identity_map(self, identity: int) -> Tensor:
        return self.latent if self.latent is not None else self.model.decode_identity(identity)

    def avatar(
        self, identity: int, geometry: SubjectGeometry, pose: BodyPose, centres: Tensor, pose_index: Tensor
    ) -> AvatarOutput:
        """Both Gaussian sets of B views (camera centres (B, 3)) of P poses (see :meth:`PGHM.forward`)."""
        return self.model(self.identity_map(identity), geometry, pose, centres, pose_index)

    def renders(
        self, samples: list[Sample], geometry: SubjectGeometry, backgrounds: Tensor | None = None
    ) -> tuple[Tensor | None, Tensor, Tensor | None, Tensor, Tensor]:
        """Static and dynamic renders (B, 3, H, W) of one identity's samples on white, or on
        ``backgrounds`` (B, 3, H, W) when given; their accumulated alphas (B, 1, H, W); the regulariser.
        The static render and alpha are None when :attr:`dynamic_only`."""
        with profile.part(profile.NETWORK_FORWARD):
            # One pose per distinct frame; the views of a frame share it.
            keys = [s.frame_key for s in samples]
            unique = distinct_frames(samples)
            first = [keys.index(k) for k in unique]
            rotations = torch.stack([samples[i].rotations for i in first])
            translation = torch.stack([samples[i].translation for i in first])
            if self.corrections is not None:
                rotations, translation = self.corrections(self.resident.indices(unique), rotations, translation)
            pose_index = self.resident.indices([unique.index(k) for k in keys])
            centres = torch.stack([s.camera.centre.float() for s in samples])
            out = self.avatar(samples[0].identity, geometry, BodyPose(rotations, translation), centres, pose_index)
        # Both sets of all B views in one batched render: (2B, H, W, 3).
        if len({(s.camera.width, s.camera.height) for s in samples}) > 1:
            raise DatasetError("the images of one subject must all have the same size")
        sets = (out.dynamic,) if self.dynamic_only else (out.static, out.dynamic)
        cameras = Camera.stack([s.camera for s in samples] * len(sets))
        both = [torch.cat([getattr(g, f) for g in sets]) for f in ("means", "scales", "colors", "opacities")]
        with profile.part(profile.GUARD):
            # A diverged network: the loss is made NaN (the loop's guard then skips the step and
            # lowers the rate) and the non-finite values replaced by ones render accepts, all on
            # the device (asking whether they are finite would wait for it).
            masks = [torch.isfinite(t) for t in both]
            finite = torch.stack([m.all() for m in masks]).all()
            both = [torch.where(m, t, torch.full_like(t, safe)) for t, m, safe in zip(both, masks, SAFE_VALUES)]
            poison = torch.where(finite, 0.0, math.nan)
        with profile.part(profile.SPLAT_FORWARD):
            drawn = render(*both, cameras, background=WHITE if backgrounds is None else BLACK, check_finite=False)
            profile.mark_backward([drawn.rgb, drawn.alpha], both)
            images, alphas = drawn.rgb.permute(0, 3, 1, 2), drawn.alpha[:, None]
            if backgrounds is not None:
                images = composite_render(images, alphas, torch.cat([backgrounds] * len(sets)))
        regularizer = out.regularizer + poison
        if self.dynamic_only:
            return None, images, None, alphas, regularizer
        count = len(samples)
        return images[:count], images[count:], alphas[:count], alphas[count:], regularizer

    def forward(
        self, samples: list[Sample], geometry: SubjectGeometry, backgrounds: Tensor | None = None
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """The loss of one identity's samples and its terms; with ``backgrounds`` (B, 3, H, W),
        targets and renders are composited on them (see :mod:`pghm.train.background`). Samples and
        backgrounds are moved to the model's device (loaded on the CPU, they are read there once)."""
        samples, backgrounds = [self.resident.sample(s) for s in samples], move(backgrounds, self.device)
        static, dynamic, static_alpha, dynamic_alpha, regularizer = self.renders(samples, geometry, backgrounds)
        with profile.part(profile.DATA):
            target = torch.stack([s.image for s in samples])
            mask = torch.stack([s.mask for s in samples])
            if backgrounds is not None:
                target = composite_target(target, mask, backgrounds)
        with profile.part(profile.LOSSES):
            return self._loss(static, dynamic, static_alpha, dynamic_alpha, regularizer, samples, target, mask)

    def _loss(
        self,
        static: Tensor | None,
        dynamic: Tensor,
        static_alpha: Tensor | None,
        dynamic_alpha: Tensor,
        regularizer: Tensor,
        samples: list[Sample],
        target: Tensor,
        mask: Tensor,
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """The loss of renders (B, 3, H, W) and alphas (B, 1, H, W) against targets and masks, and its
        terms (0-dim tensors on the device); those of the full frames when the samples are crops. A
        static render of None: the dynamic one stands in for it (:attr:`dynamic_only`)."""
        area = self.resident.areas(samples)
        share = area[:, 0] if area is not None else None
        loss, terms = objective(static, dynamic, target, regularizer, self.weights, self.lpips, area)
        if self.weights.silhouette > 0:
            sil_d = silhouette(dynamic_alpha, mask, share).mean()
            sil_s = sil_d if static_alpha is None else silhouette(static_alpha, mask, share).mean()
            loss = loss + self.weights.silhouette * (sil_s + sil_d)
            terms.update(sil_s=sil_s.detach(), sil_d=sil_d.detach(), loss=loss.detach())
        if self.corrections is not None and self.weights.pose_prior > 0:
            prior = self.corrections.prior(self.resident.indices(distinct_frames(samples)))
            loss = loss + self.weights.pose_prior * prior
            terms["pose_prior"] = prior.detach()
            terms["loss"] = loss.detach()
        terms["psnr"] = psnr(dynamic.detach().clamp(0, 1), target, share).mean()
        return loss, terms


@dataclass
class LoopState:
    """What a checkpoint restores besides the parameters."""

    step: int = 0
    lr_scale: float = 1.0
    skipped_steps: int = 0
    bad_images: list = field(default_factory=list)
    seconds: float = 0.0
    history: list = field(default_factory=list)


def state_record(state: LoopState) -> dict:
    """A loop state as plain values (a checkpoint's ``state``)."""
    return {
        "step": state.step,
        "lr_scale": state.lr_scale,
        "skipped_steps": state.skipped_steps,
        "bad_images": [list(b) for b in state.bad_images],
        "seconds": state.seconds,
        "history": state.history,
    }


def state_from_record(raw: dict) -> LoopState:
    """The loop state of :func:`state_record`; PghmError for one that cannot be (a damaged checkpoint)."""
    try:
        state = LoopState(
            step=int(raw["step"]),
            lr_scale=float(raw["lr_scale"]),
            skipped_steps=int(raw["skipped_steps"]),
            bad_images=[tuple(b) for b in raw["bad_images"]],
            seconds=float(raw["seconds"]),
            history=list(raw["history"]),
        )
    except (KeyError, TypeError, ValueError) as error:
        raise PghmError(f"checkpoint has an invalid loop state ({type(error).__name__}: {error})") from None
    if state.step < 0 or not (math.isfinite(state.lr_scale) and state.lr_scale > 0):
        raise PghmError(
            f"checkpoint has an invalid loop state (step {state.step}, learning-rate scale {state.lr_scale})"
        )
    return state


def save_checkpoint(
    path: Path,
    objective: AvatarObjective,
    optimizer: torch.optim.Optimizer | None,
    state: LoopState,
    extra: dict,
) -> None:
    """The run's state to ``path``, atomically: the objective's tensors, the optimizer's (None: a
    checkpoint between stages, which starts the next one afresh), the loop state and ``extra``."""
    buffer = io.BytesIO()
    torch.save(
        {
            "format": CHECKPOINT_FORMAT,
            "objective": {k: v for k, v in objective.state_dict().items() if not k.startswith("lpips.")},
            "optimizer": {} if optimizer is None else optimizer.state_dict(),
            "state": state_record(state),
            "extra": extra,
        },
        buffer,
    )
    atomic_write_bytes(path, buffer.getvalue())


def load_checkpoint(path: Path) -> dict:
    """Read a checkpoint (weights_only: never runs code); PghmError if it is not one."""
    try:
        payload = load_torch_file(path)
    except TorchFileError as error:
        raise PghmError(f"{path}: unreadable checkpoint: {error}") from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise PghmError(f"{path}: not a pghm checkpoint")
    return payload


def restore_objective(payload: dict, objective: AvatarObjective) -> None:
    """Load a checkpoint's parameters into ``objective``; PghmError if they are from another run or
    not finite (a run that diverged before it was saved must not continue as if it had not)."""
    try:
        missing, unexpected = objective.load_state_dict(payload["objective"], strict=False)
    except (RuntimeError, KeyError, TypeError, ValueError, AttributeError, IndexError) as error:
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise PghmError(
            f"checkpoint does not match this run (other options or another command?): {first[:200]}"
        ) from None
    missing = [k for k in missing if not k.startswith("lpips.")]
    if missing or unexpected:
        raise PghmError(f"checkpoint does not match this run (missing {missing[:3]}, unexpected {unexpected[:3]})")
    tensors = objective.state_dict().items()
    bad = [name for name, value in tensors if value.is_floating_point() and not all_finite([value])]
    if bad:
        raise PghmError(f"checkpoint holds non-finite values ({', '.join(bad[:3])}); run again without --resume")


def restore(payload: dict, objective: AvatarObjective, optimizer: torch.optim.Optimizer) -> LoopState:
    """Load a checkpoint's parameters, optimizer and loop state; PghmError if it is from another run.

    A checkpoint of another model size, stage or command (resuming with changed options, or
    into the wrong ``--out``) is one line, not torch's size-mismatch traceback.
    """
    restore_objective(payload, objective)
    try:
        optimizer.load_state_dict(payload["optimizer"])
    except (RuntimeError, KeyError, TypeError, ValueError, AttributeError, IndexError) as error:
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise PghmError(
            f"checkpoint does not match this run (other options or another command?): {first[:200]}"
        ) from None
    return state_from_record(payload.get("state") if isinstance(payload.get("state"), dict) else {})


def check_learning_rate(name: str, value: float) -> None:
    """PghmError unless ``value`` is a positive number up to MAX_LEARNING_RATE."""
    if isinstance(value, bool) or not (
        isinstance(value, (int, float)) and math.isfinite(value) and 0 < value <= MAX_LEARNING_RATE
    ):
        raise PghmError(f"{name} must be a positive number up to {MAX_LEARNING_RATE:g}, got {value}")


def available_memory() -> int:
    """Bytes of memory available to a new allocation (MemAvailable; else all RAM; 0 if unknown)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 0


def check_step_memory(data: TrainingData, config: LoopConfig, description: str) -> None:
    """PghmError, before any step, when one step's images would need more memory than the machine has."""
    pixels = max(int((s.arrays.width * s.arrays.height).max()) for s in data.subjects)
    images = config.images_per_shard * config.shards // distributed.world_size()
    need, have = images * pixels * BYTES_PER_TRAINING_PIXEL, available_memory()
    if have and need > have:
        raise PghmError(
            f"{description}: {images} images of {pixels:,} pixels per step would need about {need / 2**30:,.0f} GB "
            f"of memory, more than the {have / 2**30:,.0f} GB available; ask for fewer images per group"
        )


def check_trained(states: list[LoopState], out: Path) -> None:
    """PghmError instead of writing ``out`` from a run that trained on nothing.

    Refused: no step at all, no step that saw an image (every image unreadable), or no step with
    a finite loss (every step skipped as non-finite, as with an overflowing loss weight). A run
    whose last steps were skipped keeps the parameters of its last finite step (the guard undid
    the others) and is written. The checkpoint, if any, stays.
    """
    steps = sum(state.step for state in states)
    history = [entry for state in states for entry in state.history]
    skipped = sum(state.skipped_steps for state in states)
    reason = None
    if steps == 0:
        reason = "no training step was asked (every step count is 0)"
    elif not history:
        reason = f"none of its {steps} step(s) saw an image: every image it drew was unreadable (see the warnings)"
    elif skipped >= steps or not any(math.isfinite(entry.get("loss", math.nan)) for entry in history):
        reason = f"all {steps} step(s) were non-finite and skipped; lower the learning rates or loss weights"
    if reason:
        raise PghmError(f"{out}: not written: {reason}")


def all_finite(tensors) -> bool:
    """Whether every value of every tensor in ``tensors`` is finite (one read of the device)."""
    return bool(finite_flag(tensors))


def finite_flag(tensors) -> Tensor:
    """A 0-dim bool tensor: every value of every (floating-point) tensor in ``tensors`` is finite.

    Each tensor's largest magnitude, max |t|, is NaN when it holds a NaN and inf when it holds an
    inf, and finite otherwise (a maximum cannot overflow), so one fused norm per dtype checks them
    all; the host reads one value however many tensors there are (a read per tensor would wait for
    the device once per parameter), and the CPU runs one kernel where a check per tensor ran three.
    """
    groups: dict[torch.dtype, list[Tensor]] = {}
    for t in tensors:
        if t.numel():  # the inf-norm of nothing is undefined; nothing is finite
            groups.setdefault(t.dtype, []).append(t)
    flags = [torch.isfinite(torch.stack(torch._foreach_norm(ts, math.inf))).all() for ts in groups.values()]
    return torch.stack(flags).all() if flags else torch.tensor(True)


def run_stage(
    *,
    objective: AvatarObjective,
    trainable: list[nn.Parameter],
    optimizer: torch.optim.Optimizer,
    data: TrainingData,
    geometry_of: Callable[[int], SubjectGeometry],
    config: LoopConfig,
    checkpoint: Path | None,
    state: LoopState,
    extra: dict,
    description: str,
    budget: Budget | None = None,
) -> LoopState:
    """Run steps ``state.step`` .. ``config.steps`` - 1 of one stage; returns the final state.

    ``trainable`` are the parameters ``optimizer`` steps, ``geometry_of`` an identity's geometry,
    ``checkpoint`` where the stage saves its state (None: nowhere; the caller keeps one), ``extra``
    what the checkpoint records beside the state (the stage, the kind), ``description``
    the progress bar's label. ``budget``: the fit's plan (:mod:`pghm.train.plan`), in this stage's
    phase, which sets the stage's steps instead of ``config.steps`` (asked again after each step)
    and whose time left the bar shows.

    Raises KeyboardInterrupt after saving a checkpoint when interrupted.
    """
    world, rank = distributed.world_size(), distributed.rank()
    if config.shards % world:
        raise PghmError(f"--shards {config.shards} is not a multiple of the {world} processes")
    # The configured rates, kept in the groups so that a resumed optimizer restores them unscaled.
    for group in optimizer.param_groups:
        group.setdefault("initial_lr", group["lr"])
        check_learning_rate("learning rate", group["initial_lr"])
    module = distributed.wrap(objective)
    data.bad.update(state.bad_images)

    def set_lr() -> None:
        factor = state.lr_scale * decay_factor(state.step, steps, config.decay)
        for group in optimizer.param_groups:
            group["lr"] = group["initial_lr"] * factor

    steps = config.steps if budget is None else budget.steps(state.step)
    progress = tqdm(
        total=steps,
        initial=state.step,
        desc=description,
        disable=rank != 0 or not config.progress,
        dynamic_ncols=True,
        leave=True,
    )
    started = time.perf_counter() - state.seconds
    try:
        while state.step < steps:
            set_lr()
            plan = data.plan(config.seed, state.step, config.shards, config.images_per_shard, config.same_instant)
            mine = plan[rank::world]
            optimizer.zero_grad(set_to_none=False)
            terms_sum: dict[str, Tensor] = {}
            groups = 0
            for position, (identity, images) in enumerate(mine):
                with profile.part(profile.DATA):
                    samples = data.load_group(identity, images)
                    if not samples:
                        continue
                    if state.step < coarse_steps(config.coarse, steps):
                        samples = coarse_samples(samples)
                    # Drawn from the group's place in the global plan, whichever process computes it.
                    backgrounds = draw_backgrounds(
                        config.background,
                        len(samples),
                        samples[0].camera.height,
                        samples[0].camera.width,
                        (config.seed, state.step, rank + position * world),
                    )
                # Gradients of all but the last group accumulate locally; DDP averages once.
                last = position == len(mine) - 1
                with contextlib.nullcontext() if last else distributed.no_sync(module):
                    loss, terms = module(samples, geometry_of(identity), backgrounds)
                    with profile.part(profile.LOSSES_BACKWARD):
                        (loss / len(mine)).backward()
                groups += 1
                for key, value in terms.items():
                    terms_sum[key] = terms_sum[key] + value if key in terms_sum else value
            with profile.part(profile.GUARD):
                backup = torch._foreach_mul([p.detach() for p in trainable], 1.0)  # copies, in one call
                # One read of the device decides the step: the loss and every gradient finite.
                losses = [terms_sum["loss"]] if groups else []
                finite = all_finite([*losses, *(p.grad for p in trainable if p.grad is not None)])
            if finite:
                with profile.part(profile.OPTIMISER):
                    torch.nn.utils.clip_grad_norm_(trainable, config.max_grad_norm)
                    optimizer.step()
            with profile.part(profile.GUARD):
                # The second read: the update finite, and the step's terms for the log.
                skipped = torch.zeros((), dtype=torch.bool, device=objective.device)
                updated = finite_flag(trainable) if finite else skipped
                names = list(terms_sum)
                values = torch.stack([updated.to(torch.float64), *(terms_sum[k].double() for k in names)]).tolist()
                if finite and not values[0]:
                    with torch.no_grad():
                        for p, saved in zip(trainable, backup):
                            p.copy_(saved)
                    finite = False
            if not finite:
                state.skipped_steps += 1
                state.lr_scale *= LR_BACKOFF
                log.warning(
                    "step %d: non-finite loss, gradient or update; step skipped, learning rate x%.2f (now scale %.3g)",
                    state.step,
                    LR_BACKOFF,
                    state.lr_scale,
                )
            state.step += 1
            state.seconds = time.perf_counter() - started
            postfix = {}
            if budget is not None:
                budget.progress(state.step)
                steps = progress.total = budget.steps(state.step)
                postfix["fit_left"] = f"{budget.eta() / 60:.1f}min"
            if groups:
                mean = {k: v / groups for k, v in zip(names, values[1:])}
                state.history.append({"step": state.step, **{k: round(v, 5) for k, v in mean.items()}})
                postfix.update(loss=f"{mean['loss']:.4f}", psnr=f"{mean['psnr']:.2f}")
            progress.set_postfix(postfix)
            progress.update(1)
            periodic = checkpoint is not None and config.checkpoint_every > 0
            if rank == 0 and periodic and state.step % config.checkpoint_every == 0:
                state.bad_images = sorted(data.bad)
                with profile.part(profile.CHECKPOINT):
                    save_checkpoint(checkpoint, objective, optimizer, state, extra)
            interrupt_point("train-step")
    except KeyboardInterrupt:
        if rank == 0 and checkpoint is not None:
            state.bad_images = sorted(data.bad)
            save_checkpoint(checkpoint, objective, optimizer, state, extra)
            progress.write(
                f"interrupted at step {state.step}: checkpoint saved to {checkpoint}; continue with --resume",
                file=sys.stderr,
            )
        raise
    finally:
        progress.close()
    state.bad_images = sorted(data.bad)
    return state
