"""Why the prior does not beat scratch here (issue 6): how well a prior fits the people it
was trained on, and where personalised avatars lose on the held-out subject.

1. The prior on its own training identities: PSNR of every identity's decoded map on its
   training and held-out images (a prior that cannot reproduce its own people cannot
   hand a new one a better start than random weights).
2. Each avatar on the held-out subject: training-frame PSNR (fit) against novel-pose PSNR
   (generalisation), the novel poses split into the walk continued and the other motion.
3. A picture: ground truth | render | error of the first novel-pose frames, per avatar.

    python benchmarks/diagnose_prior.py --prior assets/prior.pt --data DATA --subject SUBJECT \\
        --avatar "prior + fit"=assets/avatar.pt --avatar scratch=WORK/scratch.pt

Writes docs/prior_diagnosis.md and docs/prior_diagnosis.png.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from common import DOCS, setup_threads
from PIL import Image

from pghm.io.avatar import Avatar, load_avatar
from pghm.train.data import TrainingData
from pghm.train.evaluate import evaluate

TRAIN_STRIDE = 5
"""Evaluate every this-many-th training image (the fit is measured, not every frame)."""
STRIP_ROWS = 2
"""Novel-pose frames shown per avatar in the picture."""


def split_psnr(avatar: Avatar, subject: Path, split: str, stride: int = 1) -> list[float]:
    """Per-image PSNR of ``avatar`` on every ``stride``-th image of ``split`` (exact poses)."""
    indices = [int(i) for i in TrainingData(subject, split=split).images[0]][::stride]
    return evaluate(avatar, subject, split=split, true_poses=True, images=indices).psnr


def prior_rows(prior: Avatar, data: Path) -> list[str]:
    subjects = sorted(p for p in data.iterdir() if (p / "cameras.npz").is_file())
    rows, train_all, test_all = [], [], []
    for index in range(prior.model.num_identities):
        member = prior.member(index)
        train = float(np.mean(split_psnr(member, subjects[index], "train", TRAIN_STRIDE)))
        test = float(np.mean(split_psnr(member, subjects[index], "test")))
        train_all.append(train)
        test_all.append(test)
        rows.append(f"| {subjects[index].name} | {train:.2f} | {test:.2f} |")
    rows.append(f"| **mean** | **{np.mean(train_all):.2f}** | **{np.mean(test_all):.2f}** |")
    return rows


def avatar_row(label: str, avatar: Avatar, subject: Path) -> tuple[str, np.ndarray]:
    train = float(np.mean(split_psnr(avatar, subject, "train", TRAIN_STRIDE)))
    with tempfile.TemporaryDirectory() as tmp:
        strip = Path(tmp) / "strip.png"
        novel = evaluate(avatar, subject, strip=strip, split="test_novel_pose", true_poses=True).psnr
        picture = np.asarray(Image.open(strip))
    half = len(novel) // 2
    row = (
        f"| {label} | {avatar.metadata.get('steps')} | {train:.2f} | {np.mean(novel):.2f} | "
        f"{np.mean(novel[:half]):.2f} | {np.mean(novel[half:]):.2f} | {train - np.mean(novel):.2f} |"
    )
    rows_high = picture.shape[0] // min(len(novel), 6)
    return row, picture[: STRIP_ROWS * rows_high]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prior", required=True, type=Path)
    parser.add_argument("--data", required=True, type=Path, help="the prior's training data")
    parser.add_argument("--subject", required=True, type=Path, help="the held-out monocular subject")
    parser.add_argument("--avatar", action="append", default=[], help="LABEL=PATH, repeatable")
    args = parser.parse_args()
    setup_threads()
    prior = load_avatar(args.prior)
    lines = [
        "# Why the prior does not help yet",
        "",
        "Produced by `python benchmarks/diagnose_prior.py "
        f"--prior {args.prior} --data {args.data} --subject {args.subject} "
        + " ".join(f'--avatar "{a}"' for a in args.avatar)
        + "` (whole images on white, exact poses).",
        "",
        f"## 1. The prior on its own training identities ({prior.metadata.get('steps')} steps)",
        "",
        f"PSNR of each identity's decoded map: every {TRAIN_STRIDE}th training image, and the held-out frames.",
        "",
        "| identity | train | held out |",
        "|---|---|---|",
        *prior_rows(prior, args.data),
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
