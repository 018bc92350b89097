"""Outputs on a full disk: one line naming the file and the space left, exit status 2, and a command
with several outputs leaves all or none of them; a video the encoder could not write is refused,
not left empty. Runs on a real full filesystem (a tmpfs this test mounts and fills), skipped where
the machine does not let it mount one."""

from __future__ import annotations

import contextlib
import os
import subprocess
from pathlib import Path

import pytest
from conftest import TINY_MODEL
from stress_kit import check

from pghm.cli.main import main
from pghm.model import ModelConfig
from pghm.train.loop import LoopConfig
from pghm.train.prior import PriorConfig, train_prior

AREA = "adversarial: full disk"
SUBJECT = "subject_000"
FULL_BYTES = 256 * 1024
"""Size of the full filesystem: a few pages, filled by one file before each command."""


def mount_full(directory: Path) -> bool:
    """Mount a tmpfs of :data:`FULL_BYTES` at ``directory`` and fill it; False where mounting is refused."""
    directory.mkdir()
    if os.geteuid() != 0:
        return False
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={FULL_BYTES}", "tmpfs", str(directory)], capture_output=True
    )
    if mounted.returncode != 0:
        return False
    with contextlib.suppress(OSError), open(directory / "filler", "wb") as filler:
        while True:
            filler.write(b"\0" * 4096)
            filler.flush()
    return True


@pytest.fixture
def full(tmp_path):
    directory = tmp_path / "full"
    if not mount_full(directory):
        pytest.skip("cannot mount a tmpfs here (needs root and CAP_SYS_ADMIN)")
    yield directory
    subprocess.run(["umount", str(directory)], check=True)


@pytest.fixture(scope="module")
def avatar_file(tiny_dataset, tmp_path_factory):
    folder = tmp_path_factory.mktemp("full_disk")
    loop = LoopConfig(steps=1, images_per_shard=2, checkpoint_every=0, progress=False)
    train_prior(tiny_dataset, folder / "prior.pt", PriorConfig(model=ModelConfig(**TINY_MODEL), loop=loop))
    args = ["fit", str(tiny_dataset / SUBJECT), "--prior", str(folder / "prior.pt"), "--out", str(folder / "a.pt")]
    assert main([*args, "--stage1-steps", "1", "--stage2-steps", "1", "--detail-steps", "0", "--no-lpips"]) == 0
    return folder / "a.pt"


def expect_full(capsys, status: int, path: Path, case: str, nothing_left: bool) -> None:
    """A recorded case: exit 2 and one line naming ``path``, the reason and the space left, and
    (``nothing_left``) none of the command's outputs written."""
    lines = capsys.readouterr().err.strip().splitlines()
    last = lines[-1] if lines else ""
    check(
        AREA,
        case,
        f"exit 2, one line '{path.name}: no space left on device (N MB free)', none of its outputs left",
        f"exit {status}: {last.split(': error: ')[-1][-160:]}; outputs left: {'none' if nothing_left else 'some'}",
        status == 2
        and last.startswith(f"pghm: error: {path}: no space left on device (")
        and last.endswith(" MB free)")
        and "Traceback" not in "\n".join(lines)
        and nothing_left,
    )


def test_eval_writes_both_outputs_or_neither(tiny_dataset, avatar_file, full, tmp_path, capsys):
    report, strip = tmp_path / "r.json", full / "s.png"
    args = ["eval", str(avatar_file), str(tiny_dataset / SUBJECT), "--report", str(report), "--strip", str(strip)]
    status = main(args)
    left = report.exists() or strip.exists() or list(tmp_path.glob(".r.json*")) or len(list(full.iterdir())) > 1
    expect_full(capsys, status, strip, "eval --report r.json --strip FULL/s.png", not left)


def test_fit_writes_the_avatar_and_its_profile_or_neither(tiny_dataset, avatar_file, full, tmp_path, capsys):
    prior = avatar_file.with_name("prior.pt")
    out, profile = tmp_path / "a.pt", full / "p.json"
    args = ["fit", str(tiny_dataset / SUBJECT), "--prior", str(prior), "--out", str(out), "--profile", str(profile)]
    status = main([*args, "--stage1-steps", "1", "--stage2-steps", "1", "--detail-steps", "0", "--no-lpips"])
    case = "fit --out a.pt --profile FULL/p.json (the avatar and its profile)"
    expect_full(capsys, status, profile, case, not out.exists() and not profile.exists())


def test_a_fit_or_prior_that_the_disk_cannot_hold_is_refused_before_its_first_step(
    tiny_dataset, avatar_file, full, capsys, monkeypatch
):
    from pghm.train import loop

    def no_step(name: str) -> None:
        raise AssertionError("a step ran before the output's room was checked")

    monkeypatch.setattr(loop, "interrupt_point", no_step)
    prior = avatar_file.with_name("prior.pt")
    for args in (
        ["fit", str(tiny_dataset / SUBJECT), "--prior", str(prior), "--out", str(full / "a.pt"), "--no-lpips"],
        ["train-prior", str(tiny_dataset), "--out", str(full / "p.pt"), "--steps", "1", "--no-lpips"],
    ):
        status = main(args)
        lines = capsys.readouterr().err.strip().splitlines()
        check(
            AREA,
            f"{args[0]} --out FULL/{Path(args[args.index('--out') + 1]).name}, before its first step",
            "exit 2, one line 'OUT: needs about N MB, M MB free', no step run, nothing written",
            f"exit {status}: {' | '.join(lines)[-160:]}",
            status == 2
            and len(lines) == 1
            and "needs about" in lines[0]
            and lines[0].endswith("write elsewhere")
            and [p.name for p in full.iterdir()] == ["filler"],
        )


def test_an_avatar_on_a_full_disk_is_one_line(tiny_dataset, avatar_file, full, capsys):
    out = full / "posed.ply"
    status = main(["export", str(avatar_file), "--pose", "walk", "--frame", "1", "--out", str(out)])
    expect_full(capsys, status, out, "export --out FULL/posed.ply", not out.exists())


def test_a_web_page_on_a_full_disk_is_one_line(avatar_file, full, capsys):
    out = full / "walk.html"
    status = main(["export", str(avatar_file), "--web", str(out)])
    expect_full(capsys, status, out, "export --web FULL/walk.html", not out.exists())


@pytest.mark.gl
def test_a_video_the_encoder_could_not_write_is_refused(avatar_file, full, capsys):
    out = full / "a.mp4"
    args = ["render", str(avatar_file), "--motion", "walk", "--frames", "3", "--size", "64x48", "--out", str(out)]
    status = main(args)
    lines = capsys.readouterr().err.strip().splitlines()
    last = lines[-1] if lines else ""
    check(
        AREA,
        "render --out FULL/a.mp4 (ffmpeg cannot write the video)",
        "exit 2, one line 'a.mp4: the video encoder failed (... MB free)', no empty video left",
        f"exit {status}: {' | '.join(lines)[-160:]}",
        status == 2
        and lines == [f"pghm: error: {out}: the video encoder failed ({last.split('(')[-1]}"]
        and last.endswith(" MB free)")
        and not out.exists()
        and [p.name for p in full.iterdir()] == ["filler"],
    )
