"""``pghm train-prior``, ``pghm fit`` and ``pghm eval``: thin layers over pghm.train."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import replace
from pathlib import Path

from pghm.cli.options import (
    MAX_INDEX,
    POSITIVE_STEPS,
    SEED,
    STEPS,
    Integer,
    Real,
    add_device_option,
    rendering_device,
)
from pghm.cli.render import parse_colour
from pghm.device import PRECISION_CHOICES
from pghm.errors import PghmError
from pghm.io.atomic import all_or_none
from pghm.io.outputs import PNG_SUFFIXES, check_output
from pghm.model import ModelConfig
from pghm.model.config import MAX_CHANNELS
from pghm.train.background import BACKGROUND_KINDS, WHITE
from pghm.train.fit import EARLY_TRACK_STEPS, HELD_OUT_STEPS, TRACK_MIN_VISITS, TRACK_STEPS, FitConfig
from pghm.train.loop import MAX_LEARNING_RATE, LoopConfig
from pghm.train.losses import LossWeights
from pghm.train.prior import PriorConfig
from pghm.uv.atlas import MAX_RESOLUTION, MIN_RESOLUTION

MAX_IMAGES_PER_GROUP = 10_000
"""Parser bound of --images; the loop also refuses a group whose images would not fit in memory."""
MAX_SHARDS = 1024
MAX_POSE_PRIOR = 100.0
"""Largest --pose-prior weight: 2e5 times the default, past which the loss overflows float32."""
MAX_SILHOUETTE = 100.0
"""Largest --silhouette weight: 25 times the fit's default (100 times the prior's), far past
where the mask term dominates the photometric ones."""
MAX_POSE_SMOOTHING = 100.0
"""Largest --pose-smoothing sigma, in frames (the filter's support is a few sigma)."""
LEARNING_RATE = Real(0.0, MAX_LEARNING_RATE, open_low=True)
MAX_FIT_MINUTES = 10_000.0
"""Largest --minutes: about a week, far past where more steps buy anything."""


def _model_arguments(parser: argparse.ArgumentParser) -> None:
    defaults = ModelConfig()
    group = parser.add_argument_group("model (prior training only)")
    group.add_argument(
        "--uv-resolution",
        type=Integer(MIN_RESOLUTION, MAX_RESOLUTION),
        default=defaults.uv_resolution,
        help="L, texels per side (default %(default)s)",
    )
    group.add_argument(
        "--latent-channels",
        type=Integer(1, MAX_CHANNELS),
        default=defaults.latent_channels,
        help="C (default %(default)s)",
    )
    group.add_argument(
        "--head", choices=("multi", "single"), default=defaults.head, help="U-Net heads (default %(default)s)"
    )


def _loop_arguments(parser: argparse.ArgumentParser, prefix: str, defaults: LoopConfig, steps: Integer) -> None:
    parser.add_argument(
        f"--{prefix}steps", type=steps, default=defaults.steps, help="optimisation steps (default %(default)s)"
    )
    parser.add_argument(
        f"--{prefix}images",
        type=Integer(1, MAX_IMAGES_PER_GROUP),
        default=defaults.images_per_shard,
        help="images per identity group (default %(default)s)",
    )
    parser.add_argument(
        f"--{prefix}decay",
        type=Real(0.0, 1.0),
        default=defaults.decay,
        help="share of the last steps over which the learning rates fall to zero as a half cosine; "
        "0: constant (default %(default)s)",
    )
    parser.add_argument(
        f"--{prefix}coarse",
        type=Real(0.0, 1.0),
        default=defaults.coarse,
        help="share of the first steps that render each image at half its resolution; 0: none (default %(default)s)",
    )


def _common(parser: argparse.ArgumentParser, loop: LoopConfig) -> None:
    loss = loop.loss
    parser.add_argument("--seed", type=SEED, default=0, help="seeds the batch plan (default %(default)s)")
    parser.add_argument(
        "--checkpoint-every",
        type=STEPS,
        default=100,
        help="steps between checkpoints; 0: only on Ctrl-C. OUT.ckpt is removed once OUT is written "
        "(default %(default)s)",
    )
    parser.add_argument("--resume", action="store_true", help="continue from OUT.ckpt")
    parser.add_argument("--no-pose-refinement", action="store_true", help="keep the stored poses fixed")
    parser.add_argument(
        "--pose-prior",
        type=Real(0.0, MAX_POSE_PRIOR),
        default=loss.pose_prior,
        help="weight of a Gaussian prior holding the pose corrections near the estimate; 0: off (default %(default)s)",
    )
    parser.add_argument(
        "--background",
        choices=BACKGROUND_KINDS,
        default=loop.background,
        help="what targets are composited on and renders drawn on: white (the paper), a random colour "
        "or a random gradient per image and step (default %(default)s)",
    )
    parser.add_argument(
        "--silhouette",
        type=Real(0.0, MAX_SILHOUETTE),
        default=loss.silhouette,
        help="weight of the L1 term between the render's alpha and the mask; 0: off (default %(default)s)",
    )
    parser.add_argument("--no-lpips", action="store_true", help="leave the LPIPS term out even if its weights exist")
    parser.add_argument("--body-model-path", default=None, help="your SMPL-X model file, for SMPL-X data")
    add_device_option(parser)


def register(subparsers) -> None:
    prior = subparsers.add_parser("train-prior", help="train a prior over many identities (multi-view data)")
    prior.add_argument("data_dir", help="a folder of subject folders (pghm synth --config prior)")
    prior.add_argument("--out", required=True, help="prior file to write, e.g. prior.pt")
    _loop_arguments(prior, "", PriorConfig().loop, POSITIVE_STEPS)
    prior.add_argument(
        "--shards",
        type=Integer(1, MAX_SHARDS),
        default=1,
        help="identity groups per step; a multiple of the torchrun processes",
    )
    prior.add_argument(
        "--lr", type=LEARNING_RATE, default=PriorConfig().network_lr, help="network learning rate (default %(default)s)"
    )
    prior.add_argument(
        "--identities",
        type=Integer(1, MAX_INDEX),
        default=None,
        help="train on the first N subjects only (default: all)",
    )
    _model_arguments(prior)
    _common(prior, PriorConfig().loop)
    prior.set_defaults(func=cmd_train_prior)

    fit = subparsers.add_parser("fit", help="personalise a prior to one subject (monocular video)")
    fit.add_argument("subject_dir")
    fit.add_argument("--prior", required=True, help="prior file (pghm train-prior), or 'scratch' to train from nothing")
    fit.add_argument("--out", required=True, help="avatar file to write, e.g. avatar.pt")
    fit_defaults = FitConfig()
    _loop_arguments(fit, "stage1-", fit_defaults.stage1, STEPS)
    _loop_arguments(fit, "stage2-", fit_defaults.stage2, STEPS)
    fit.add_argument(
        "--pose-smoothing",
        type=Real(0.0, MAX_POSE_SMOOTHING),
        default=fit_defaults.pose_smoothing,
        help="sigma in frames of the temporal filter on the estimated poses; 0: as stored (default %(default)s)",
    )
    fit.add_argument(
        "--track-steps",
        type=STEPS,
        default=None,
        help="pose refinement steps per training frame after stage 2, which settle the avatar's pose track "
        f"(default: {TRACK_STEPS} for poses stated noisier than 2 degrees, as a capture's, when stage 2 visits "
        f"each frame fewer than {TRACK_MIN_VISITS} times; else 0)",
    )
    fit.add_argument(
        "--early-track-steps",
        type=STEPS,
        default=None,
        help="coarse pose refinement steps per training frame between the stages, against the stage-1 avatar, so "
        f"stage 2 learns from aligned frames (default: {EARLY_TRACK_STEPS} for poses stated noisier than 2 degrees, "
        "as a capture's; else 0)",
    )
    fit.add_argument(
        "--held-out-steps",
        type=STEPS,
        default=None,
        help="pose refinement steps per frame outside the training split once the avatar is finished, which align "
        f"the held-out frames to their images (default: {HELD_OUT_STEPS} for poses stated noisier than 2 degrees, "
        "as a capture's; else 0)",
    )
    fit.add_argument(
        "--uv-resolution",
        type=Integer(MIN_RESOLUTION, MAX_RESOLUTION),
        default=None,
        help="L of the avatar's UV maps, a power of two; another L than the prior's carries its weights over "
        "((L / L_prior)^2 times the Gaussians; default: the prior's)",
    )
    fit.add_argument(
        "--detail-steps",
        type=STEPS,
        default=fit_defaults.detail.steps,
        help="steps of a last stage that trains a detail layer: Gaussians at twice the UV resolution whose "
        "colours are trained texel by texel (4 times the Gaussians; docs/training.md, 'Detail layer'); "
        "0: none (default %(default)s)",
    )
    fit.add_argument(
        "--detail-validation",
        type=STEPS,
        default=fit_defaults.detail_validation,
        metavar="EVERY",
        help="hold every EVERY-th training frame (at most 12, spread over the video) out of the detail stage and "
        "keep the layer only if it draws those frames closer than the avatar without it; 0: train it on every "
        "frame and keep it (default %(default)s)",
    )
    fit.add_argument(
        "--minutes",
        type=Real(0.0, MAX_FIT_MINUTES, open_low=True),
        default=None,
        help="a wall-clock budget: the fit sizes its phases to N minutes on this machine as it runs (the stages' "
        "steps scale from the ones given; the avatar then depends on the machine's speed); default: the fixed steps",
    )
    fit.add_argument(
        "--precision",
        choices=PRECISION_CHOICES,
        default=fit_defaults.precision,
        help="what the networks compute in: float32, bfloat16, or auto (default: bfloat16 on a CPU that "
        "multiplies it natively (AMX or AVX512-BF16), where it is faster; else float32)",
    )
    fit.add_argument(
        "--profile",
        default=None,
        metavar="JSON",
        help="time each part of the fit (data, network, splatting, losses, optimiser, guard, pose settling): "
        "print the table and write it to JSON",
    )
    _common(fit, fit_defaults.stage1)
    fit.set_defaults(func=cmd_fit)

    evaluate = subparsers.add_parser("eval", help="PSNR/SSIM/LPIPS of an avatar on a subject's held-out frames")
    evaluate.add_argument("avatar")
    evaluate.add_argument("subject_dir")
    evaluate.add_argument("--split", default="test")
    evaluate.add_argument("--report", default=None, help="JSON report path (default: AVATAR.eval.json)")
    evaluate.add_argument("--strip", default=None, help="PNG strip path (default: AVATAR.eval.png)")
    evaluate.add_argument("--true-poses", action="store_true", help="render with a synthetic subject's exact poses")
    evaluate.add_argument(
        "--refine-poses",
        type=STEPS,
        default=0,
        metavar="STEPS",
        help="first fit each evaluated frame's pose to its image for STEPS steps, the avatar frozen "
        "(test-time pose refinement, for estimated poses such as a capture's); 0: off (default %(default)s)",
    )
    evaluate.add_argument(
        "--fit-poses",
        action="store_true",
        help="render with the poses the avatar's fit learned for its video: the training frames' corrections; "
        "on held-out frames, those the fit aligned to their images after training (a capture's, counted in the "
        "report), else the training frames' interpolated",
    )
    evaluate.add_argument(
        "--background",
        type=parse_colour,
        default=WHITE,
        help="behind render and ground truth: white (default, the paper's), black, r,g,b in [0, 1] or #rrggbb",
    )
    evaluate.add_argument("--body-model-path", default=None)
    add_device_option(evaluate)
    evaluate.set_defaults(func=cmd_eval)


QUIET_LOGGERS = ("anny",)
"""Libraries whose info lines (the body model's cache loads) are not pghm's to print."""


def _logging() -> None:
    logging.basicConfig(level=logging.INFO, format="pghm: %(message)s", stream=sys.stderr)
    for name in QUIET_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)


def cmd_train_prior(args: argparse.Namespace) -> int:
    from pghm.train.prior import train_prior

    check_output(args.out, inputs=[args.data_dir, args.body_model_path])
    device = rendering_device(args.device)
    _logging()
    model = ModelConfig(uv_resolution=args.uv_resolution, latent_channels=args.latent_channels, head=args.head)
    loop = LoopConfig(
        steps=args.steps,
        shards=args.shards,
        images_per_shard=args.images,
        seed=args.seed,
        checkpoint_every=args.checkpoint_every,
        decay=args.decay,
        coarse=args.coarse,
        loss=LossWeights(pose_prior=args.pose_prior, silhouette=args.silhouette),
        background=args.background,
    )
    config = PriorConfig(
        model=model,
        loop=loop,
        network_lr=args.lr,
        refine_poses=not args.no_pose_refinement,
        lpips=not args.no_lpips,
        body_model_path=args.body_model_path,
        max_identities=args.identities,
    )
    avatar = train_prior(args.data_dir, args.out, config, resume=args.resume, device=device)
    print(
        f"wrote {args.out}: {avatar.metadata['identities']} identities, "
        f"{avatar.metadata['steps']} steps, {avatar.metadata['seconds']} s"
    )
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    from pghm.train.fit import fit
    from pghm.train.profile import profiled

    check_output(args.out, inputs=[args.subject_dir, args.prior, args.body_model_path])
    if args.profile is not None:
        check_output(args.profile, inputs=[args.subject_dir, args.prior, args.body_model_path], option="--profile")
        if Path(args.profile).resolve() == Path(args.out).resolve():
            raise PghmError(f"--out and --profile are the same file ({args.out}); give two names")
    device = rendering_device(args.device)
    _logging()
    stages = [
        LoopConfig(
            steps=steps,
            images_per_shard=images,
            seed=args.seed,
            checkpoint_every=args.checkpoint_every,
            decay=decay,
            coarse=coarse,
            loss=LossWeights(pose_prior=args.pose_prior, silhouette=args.silhouette),
            background=args.background,
        )
        for steps, images, decay, coarse in (
            (args.stage1_steps, args.stage1_images, args.stage1_decay, args.stage1_coarse),
            (args.stage2_steps, args.stage2_images, args.stage2_decay, args.stage2_coarse),
        )
    ]
    detail = FitConfig().detail  # its schedule; the options above set the rest as stage 2's
    config = FitConfig(
        stage1=stages[0],
        stage2=stages[1],
        refine_poses=not args.no_pose_refinement,
        pose_smoothing=args.pose_smoothing,
        track_steps=args.track_steps,
        early_track_steps=args.early_track_steps,
        held_out_steps=args.held_out_steps,
        uv_resolution=args.uv_resolution,
        detail=replace(stages[1], steps=args.detail_steps, decay=detail.decay, coarse=detail.coarse),
        detail_validation=args.detail_validation,
        lpips=not args.no_lpips,
        body_model_path=args.body_model_path,
        minutes=args.minutes,
        precision=args.precision,
    )
    prior = ModelConfig() if args.prior == "scratch" else args.prior
    with all_or_none() as outputs:  # the avatar and its profile, both or neither
        run = dict(resume=args.resume, device=device, outputs=outputs)
        if args.profile is None:
            avatar = fit(args.subject_dir, prior, args.out, config, **run)
        else:
            with profiled() as timing:
                avatar = fit(args.subject_dir, prior, args.out, config, **run)
            print(timing.table(), file=sys.stderr)
            outputs.write_bytes(args.profile, json.dumps(timing.record(), indent=2).encode())
    print(f"wrote {args.out}: {avatar.metadata['steps']} steps, {avatar.metadata['seconds']} s")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from pghm.train.evaluate import evaluate

    report = args.report or f"{args.avatar}.eval.json"
    strip = args.strip or f"{args.avatar}.eval.png"
    inputs = [args.avatar, args.subject_dir, args.body_model_path]
    check_output(report, inputs=inputs, option="--report")
    check_output(strip, inputs=inputs, option="--strip", suffixes=PNG_SUFFIXES)
    if Path(report).resolve() == Path(strip).resolve():
        raise PghmError(f"--report and --strip are the same file ({report}); give two names")
    device = rendering_device(args.device)
    result = evaluate(
        args.avatar,
        args.subject_dir,
        report,
        strip,
        split=args.split,
        body_model_path=args.body_model_path,
        true_poses=args.true_poses,
        background=args.background,
        refine_poses=args.refine_poses,
        fit_poses=args.fit_poses,
        device=device,
    )
    print(json.dumps(result.summary()))
    print(f"wrote {report} and {strip}")
    return 0
