"""Whether a prior can help: how well a prior fits the people it was trained on,
and where personalised avatars gain or lose on the held-out subject.

1. The prior on its own training identities: PSNR of every identity's decoded map on its
   training and held-out images (a prior that cannot reproduce its own people cannot
   hand a new one a better start than random weights).
2. Each avatar on the held-out subject: training-frame PSNR (fit) against novel-pose PSNR
   (generalisation), the novel poses split into the walk continued and the other motion.
3. A picture: ground truth | render | error of the first novel-pose frames, per avatar.

    python benchmarks/diagnose_prior.py --prior "3k steps"=assets/prior.pt --data DATA --subject SUBJECT \\
        --avatar "prior + fit"=assets/avatar.pt --avatar scratch=WORK/scratch.pt

Writes docs/prior_diagnosis.md and docs/prior_diagnosis.png.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from common import DOCS, setup_threads
from PIL import Image, ImageDraw

from pghm.io.avatar import Avatar, load_avatar, recorded_path
from pghm.subject import Subject
from pghm.train.evaluate import STRIP_FRAMES, evaluate

TRAIN_STRIDE = 5
"""Evaluate every this-many-th training image (the fit is measured, not every frame)."""
STRIP_ROWS = 1
"""Novel-pose frames shown per avatar in the picture."""


def split_psnr(avatar: Avatar, subject: Path, split: str, stride: int = 1) -> list[float]:
    """Per-image PSNR of ``avatar`` on every ``stride``-th image of ``split`` (exact poses)."""
    indices = [int(i) for i in Subject.open(subject).split(split).indices][::stride]
    return evaluate(avatar, subject, split=split, true_poses=True, images=indices).psnr


def prior_table(priors: dict[str, Avatar], data: Path) -> list[str]:
    """Rows: identities; columns: train and held-out PSNR under each prior ("-" past its bank)."""
    subjects = sorted(p for p in data.iterdir() if (p / "cameras.npz").is_file())
    columns = {
        label: [
            (
                float(np.mean(split_psnr(prior.member(i), subjects[i], "train", TRAIN_STRIDE))),
                float(np.mean(split_psnr(prior.member(i), subjects[i], "test"))),
            )
            for i in range(prior.model.num_identities)
        ]
        for label, prior in priors.items()
    }
    header = " | ".join(f"{label}: train | {label}: held out" for label in priors)
    lines = [f"| identity | {header} |", "|---" * (1 + 2 * len(priors)) + "|"]
    for i in range(max(len(c) for c in columns.values())):
        cells = " | ".join(f"{c[i][0]:.2f} | {c[i][1]:.2f}" if i < len(c) else "- | -" for c in columns.values())
        lines.append(f"| {subjects[i].name} | {cells} |")
    means = " | ".join(
        f"**{np.mean([t for t, _ in c]):.2f}** | **{np.mean([h for _, h in c]):.2f}**" for c in columns.values()
    )
    lines.append(f"| **mean of its identities** | {means} |")
    return lines


def avatar_row(label: str, avatar: Avatar, subject: Path) -> tuple[str, np.ndarray]:
    train = float(np.mean(split_psnr(avatar, subject, "train", TRAIN_STRIDE)))
    with tempfile.TemporaryDirectory() as tmp:
        strip = Path(tmp) / "strip.png"
        novel = evaluate(avatar, subject, strip=strip, split="test_novel_pose", true_poses=True).psnr
        picture = np.asarray(Image.open(strip))
    half = len(novel) // 2
    steps = avatar.metadata.get("steps", {})
    row = (
        f"| {label} | {steps.get('stage1', 0)} + {steps.get('stage2', 0)} | {train:.2f} | {np.mean(novel):.2f} | "
        f"{np.mean(novel[:half]):.2f} | {np.mean(novel[half:]):.2f} | {train - np.mean(novel):.2f} |"
    )
    rows_high = picture.shape[0] // min(len(novel), STRIP_FRAMES)
    labelled = Image.fromarray(picture[: STRIP_ROWS * rows_high])
    ImageDraw.Draw(labelled).text((8, 8), label, fill=(0, 0, 0))
    return row, np.asarray(labelled)


def recorded_spec(spec: str) -> str:
    """A ``LABEL=PATH`` option as the report names it: the path through :func:`recorded_path`."""
    label, _, path = spec.partition("=")
    return f"{label}={recorded_path(path)}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prior", action="append", required=True, help="LABEL=PATH of a prior, repeatable")
    parser.add_argument("--data", required=True, type=Path, help="the prior's training data")
    parser.add_argument("--subject", required=True, type=Path, help="the held-out monocular subject")
    parser.add_argument("--avatar", action="append", required=True, help="LABEL=PATH of an avatar, repeatable")
    args = parser.parse_args()
    setup_threads()
    priors = {label: load_avatar(path) for label, _, path in (spec.partition("=") for spec in args.prior)}
    lines = [
        "# What the priors learn, and what they hand on",
        "",
        "Produced by `python benchmarks/diagnose_prior.py "
        + " ".join(f'--prior "{recorded_spec(p)}"' for p in args.prior)
        + f" --data {recorded_path(args.data)} --subject {recorded_path(args.subject)} "
        + " ".join(f'--avatar "{recorded_spec(a)}"' for a in args.avatar)
        + "` (whole images on white, exact poses).",
        "",
        "## 1. Priors on their own training identities",
        "",
        f"PSNR of each identity's decoded map: every {TRAIN_STRIDE}th training image, and the held-out frames.",
        "",
        *prior_table(priors, args.data),
        "",
        "## 2. Avatars on the held-out subject",
        "",
        f"Training frames (every {TRAIN_STRIDE}th) against the novel poses: the first half continues the walk,",
        "the second half is another motion.",
        "",
        "| avatar | steps | train | novel poses | walk continued | other motion | train - novel |",
        "|---|---|---|---|---|---|---|",
    ]
    pictures = []
    for spec in args.avatar:
        label, _, path = spec.partition("=")
        row, picture = avatar_row(label, load_avatar(path), args.subject)
        lines.append(row)
        pictures.append(picture)
    lines += ["", "![ground truth | render | error, first novel-pose frames per avatar](prior_diagnosis.png)", ""]
    Image.fromarray(np.concatenate(pictures)).save(DOCS / "prior_diagnosis.png")
    (DOCS / "prior_diagnosis.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
