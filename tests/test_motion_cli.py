"""``pghm motion``: the subcommands run end to end and report user errors in one line."""

from __future__ import annotations

from pathlib import Path

from pghm.cli.main import main
from pghm.errors import EXIT_USER_ERROR
from pghm.motion.motion import Motion
from pghm.motion.procedural import procedural_motion

WALK_BVH = Path(__file__).resolve().parent.parent / "assets" / "motion" / "mixamo_walk_69f.bvh"


def test_make_then_info(tmp_path, capsys, body):
    out = tmp_path / "walk.npz"
    assert main(["motion", "make", "walk", "--out", str(out), "--frames", "12", "--fps", "24"]) == 0
    motion = Motion.load(out)
    assert (motion.num_frames, motion.fps, motion.body, motion.source) == (12, 24.0, "anny", "procedural:walk")
    assert main(["motion", "info", str(out)]) == 0
    assert "12 frames at 24 fps (0.46 s), body anny (104 bones)" in capsys.readouterr().out


def test_import_resamples_and_info_reads_bvh(tmp_path, capsys, body):
    out = tmp_path / "clip.npz"
    assert main(["motion", "import", str(WALK_BVH), "--out", str(out), "--fps", "15"]) == 0
    motion = Motion.load(out)
    assert motion.num_frames == 35 and motion.fps == 15.0 and motion.source.startswith("bvh:mixamo_walk_69f.bvh")
    assert main(["motion", "info", str(WALK_BVH)]) == 0
    printed = capsys.readouterr().out
    assert "69 frames at 30 fps" in printed and "rig mixamo" in printed


def test_user_errors_exit_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n")
    assert main(["motion", "import", str(bad), "--out", str(tmp_path / "x.npz")]) == EXIT_USER_ERROR
    error = capsys.readouterr().err
    assert error.startswith("pghm: error: ") and "missing MOTION" in error and error.count("\n") == 1
    assert main(["motion", "info", str(tmp_path / "none.npz")]) == EXIT_USER_ERROR
    assert "not found" in capsys.readouterr().err
    assert not (tmp_path / "x.npz").exists()


def test_unknown_motion_name_is_an_argparse_error(tmp_path, capsys):
    assert main(["motion", "make", "dance", "--out", str(tmp_path / "x.npz")]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 1 and "invalid choice: 'dance'" in errors[0]


def test_preview_writes_an_image(tmp_path, body):
    clip = tmp_path / "squat.npz"
    procedural_motion("squat", body, frames=3).save(clip)
    out = tmp_path / "sheet.png"
    assert main(["motion", "preview", str(clip), "--out", str(out), "--frames-per-clip", "1", "--dpi", "20"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
