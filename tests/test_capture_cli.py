"""``pghm capture`` on bad inputs: one line naming the file (and frames), exit status 2, nothing written."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from capture_videos import real_frames, truncated_video, write_video

from pghm.cli.main import main
from pghm.errors import EXIT_USER_ERROR

def run_capture(tmp_path, capsys, input_path, *options) -> tuple[int, list[str]]:
    """Run ``pghm capture INPUT --out tmp/out``; the exit status and the lines printed on stderr."""
    code = main(["capture", str(input_path), "--out", str(tmp_path / "out" / "subject"), "--quiet", *options])
    return code, [line for line in capsys.readouterr().err.splitlines() if line.strip()]


def assert_refused(tmp_path, code: int, lines: list[str], *fragments: str) -> None:
    assert code == EXIT_USER_ERROR
    assert len(lines) == 1, lines
    for fragment in fragments:
        assert fragment in lines[0]
    out = tmp_path / "out"
    assert not out.exists() or list(out.iterdir()) == [], "a half-written subject (or its temporary folder) was left"


def mediapipe_required():
    pytest.importorskip("mediapipe", reason="the capture extra (pip install 'pghm[capture]') is not installed")


def test_not_a_video(tmp_path, capsys):
    path = tmp_path / "holiday.mp4"
    path.write_text("not a video")
    assert_refused(tmp_path, *run_capture(tmp_path, capsys, path), "holiday.mp4: not a readable video")


def test_missing_input(tmp_path, capsys):
    assert_refused(tmp_path, *run_capture(tmp_path, capsys, tmp_path / "nowhere.mp4"), "nowhere.mp4: no such file")


def test_truncated_video(tmp_path, capsys):
    mediapipe_required()
    cut = truncated_video(tmp_path)
    assert_refused(tmp_path, *run_capture(tmp_path, capsys, cut), "cut.mp4: truncated or corrupt video")


def test_video_without_a_person(tmp_path, capsys):
    mediapipe_required()
    frames = np.random.default_rng(1).integers(0, 256, (10, 64, 96, 3), np.uint8)
    path = write_video(tmp_path / "noise.mp4", frames)
    assert_refused(tmp_path, *run_capture(tmp_path, capsys, path), "noise.mp4: no person found in any of the 10 frame(s)")


def test_too_few_frames_with_the_person(tmp_path, capsys):
    mediapipe_required()
    frames = real_frames(5)
    frames[1] = 128
    path = write_video(tmp_path / "short.mp4", frames)
    assert_refused(
        tmp_path,
        *run_capture(tmp_path, capsys, path),
        "short.mp4: the person was found in 4 of 5 frame(s) read (not found in frames 1)",
        "at least 8",
    )


def test_one_frame_video(tmp_path, capsys):
    mediapipe_required()
    path = write_video(tmp_path / "still.mp4", real_frames(1))
    assert_refused(tmp_path, *run_capture(tmp_path, capsys, path), "still.mp4: the person was found in 1 of 1 frame(s)")


def test_existing_output_is_kept(tmp_path, capsys):
    (tmp_path / "out" / "subject").mkdir(parents=True)
    code, lines = run_capture(tmp_path, capsys, tmp_path / "any.mp4")
    assert code == EXIT_USER_ERROR and len(lines) == 1 and "already exists" in lines[0]
    assert list((tmp_path / "out").iterdir()) == [tmp_path / "out" / "subject"]


@pytest.mark.parametrize("options, fragment", [(["--every", "0"], "--every"), (["--fov", "200"], "--fov")])
def test_bad_options(tmp_path, capsys, options, fragment):
    path = tmp_path / "any.mp4"
    path.write_text("x")
    assert_refused(tmp_path, *run_capture(tmp_path, capsys, path, *options), fragment)


def test_without_mediapipe_says_how_to_install(tmp_path, capsys, monkeypatch):
    for name in [name for name in sys.modules if name == "mediapipe" or name.startswith("mediapipe.")] + ["mediapipe"]:
        monkeypatch.setitem(sys.modules, name, None)  # import mediapipe now raises ImportError
    path = write_video(tmp_path / "clip.mp4", np.zeros((2, 32, 32, 3), np.uint8))
    assert_refused(tmp_path, *run_capture(tmp_path, capsys, path), "pip install 'pghm[capture]'")
