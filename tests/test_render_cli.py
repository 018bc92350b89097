"""``pghm render`` end to end: GL (EGL offscreen) and CPU backends, MP4, PNG, PNG sequences.

The two backends render the same Gaussians and cameras, so their 8-bit frames may differ
only by rounding: the float images agree to 2e-3 (tests/test_gl_vs_cpu_avatar.py), which
moves a channel by at most one level after rounding, except where a float difference
straddles a rounding boundary, also one level. Tolerance: every channel within 1 level.
The MP4 is H.264 (lossy), so it is checked for its frame count, size and closeness to the
PNG frames (mean abs difference < 3 levels), not equality.
"""

from __future__ import annotations

import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from conftest import SMALL_MODEL as SMALL

from pghm.cli.main import main
from pghm.io.avatar import save_avatar
from pghm.render import RenderJob, frame_points, orbit_camera, plan_frames, render_video
from viewer.demo import development_avatar

pytestmark = pytest.mark.gl

SIZE = "160x120"
MP4_MEAN_LEVELS = 3.0
"""H.264 at imageio-ffmpeg quality 8: mean abs difference to the lossless frames, in 8-bit levels."""


@pytest.fixture(scope="module")
def avatar_file(tmp_path_factory):
    torch.set_num_threads(2)
    path = tmp_path_factory.mktemp("render") / "avatar.pt"
    save_avatar(path, development_avatar(SMALL, seed=2))
    return path


@pytest.fixture(scope="module")
def prior_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("render") / "prior.pt"
    save_avatar(path, development_avatar(SMALL, kind="prior", num_identities=3, seed=4))
    return path


def frames_of(directory) -> list[np.ndarray]:
    return [iio.imread(path) for path in sorted(directory.glob("frame_*.png"))]


def read_mp4(path) -> list[np.ndarray]:
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    return [np.frombuffer(frame, np.uint8).reshape(height, width, 3) for frame in reader]


def test_gl_and_cpu_backends_write_matching_png_sequences(avatar_file, tmp_path):
    args = [str(avatar_file), "--motion", "walk", "--orbit", "--frames", "4", "--size", SIZE]
    assert main(["render", *args, "--out", str(tmp_path / "gl"), "--backend", "gl"]) == 0
    assert main(["render", *args, "--out", str(tmp_path / "cpu"), "--backend", "cpu"]) == 0
    gl, cpu = frames_of(tmp_path / "gl"), frames_of(tmp_path / "cpu")
    assert len(gl) == len(cpu) == 4
    for k, (a, b) in enumerate(zip(gl, cpu)):
        assert a.shape == (120, 160, 3)
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1, f"frame {k}"
    assert not np.array_equal(gl[0], gl[2]), "the walk and the orbit change the frames"


def test_mp4_is_written_and_readable(avatar_file, tmp_path, capsys):
    def squat(out) -> list[str]:
        options = ["--motion", "squat", "--frames", "6", "--fps", "24", "--size", SIZE]
        return ["render", str(avatar_file), *options, "--out", str(out)]

    out = tmp_path / "clip.mp4"
    assert main(squat(out)) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    video = read_mp4(out)
    assert len(video) == 6 and video[0].shape == (120, 160, 3)
    assert main(squat(tmp_path / "png")) == 0
    for encoded, lossless in zip(video, frames_of(tmp_path / "png")):
        assert np.abs(encoded.astype(float) - lossless).mean() < MP4_MEAN_LEVELS


def test_single_png_and_options(prior_file, tmp_path):
    out = tmp_path / "still.png"
    assert (
        main(
            [
                "render",
                str(prior_file),
                "--identity",
                "2",
                "--static",
                "--background",
                "0,0,0",
                "--size",
                SIZE,
                "--out",
                str(out),
            ]
        )
        == 0
    )
    image = iio.imread(out)
    assert image.shape == (120, 160, 3) and (image[0, 0] == 0).all()
    assert (image.max(axis=-1) > 40).mean() > 0.05, "the body is in the frame"


def test_frames_follow_the_motion_clock(avatar_file, tmp_path):
    """Frame k samples the motion at start + k / fps; an orbit turns once over the video."""
    from pghm.body import load_body
    from pghm.motion.open_motion import open_motion

    motion = open_motion("walk", load_body("anny"))
    job = RenderJob(avatar=avatar_file, out=tmp_path / "x", motion="walk", fps=15.0, orbit=True, start=0.5)
    specs = plan_frames(job, motion)
    assert len(specs) == int((motion.duration - 0.5) * 15) + 1
    assert [s.motion_frame for s in specs[:3]] == [15, 17, 19]  # 30 fps clip sampled at 15 fps from 0.5 s
    assert specs[0].yaw == 0.0 and specs[len(specs) // 2].yaw == pytest.approx(180.0, abs=360 / len(specs))


def test_user_errors_are_one_line_with_status_2(avatar_file, tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"garbage")
    cases = [
        ([str(avatar_file), "--motion", "nonsense", "--out", str(tmp_path / "b.png")], "nonsense"),
        ([str(avatar_file), "--frames", "3", "--out", str(tmp_path / "c.png")], "one frame"),
        ([str(avatar_file), "--out", str(tmp_path / "d.gif")], ".gif"),
        ([str(avatar_file), "--size", "161x120", "--frames", "2", "--out", str(tmp_path / "e.mp4")], "even"),
    ]
    for args, needle in cases:
        assert main(["render", *args]) == 2, args
        lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
        assert len(lines) == 1 and needle in lines[0] and lines[0].startswith("pghm: error:"), (args, lines)
    # The installed command, as a user runs it: exit status and one line.
    code = "import sys; from pghm.cli.main import main; sys.exit(main(sys.argv[1:]))"
    result = subprocess.run(
        [sys.executable, "-c", code, "render", str(bad), "--out", str(tmp_path / "a.png")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and len(lines) == 1 and str(bad) in lines[0], result.stderr


def test_orbit_camera_conventions():
    """Yaw 0 looks at the body's front (camera on +z), 90 from its left (+x); pitch 90 from above."""
    for yaw, pitch, expected in ((0, 0, (0, 0, 2)), (90, 0, (2, 0, 0)), (0, 90, (0, 2, 0)), (180, -90, (0, -2, 0))):
        camera = orbit_camera((0.0, 0.0, 0.0), yaw, pitch, 2.0, 40.0, 64, 48)
        np.testing.assert_allclose(camera.centre.numpy(), expected, atol=1e-5)
        forward = camera.world_to_camera[2, :3].numpy()
        np.testing.assert_allclose(forward, -np.array(expected) / 2, atol=1e-5)  # looks at the target
    framing = frame_points(np.array([[-0.5, -0.8, -0.1], [0.5, 0.8, 0.3]]), 40.0, 4 / 3)
    assert framing.target == pytest.approx((0.0, 0.0, 0.1))
    camera = orbit_camera(framing.target, 0.0, 0.0, framing.distance, 40.0, 640, 480)
    top = camera.fy * (0.8 - 0.0) / (framing.distance - 0.2)  # the box's front face, 0.8 m above the target
    assert top == pytest.approx(0.85 * 240, rel=1e-6), "the box fills 85% of the height"


def test_render_video_reports_backend_and_stage_times(avatar_file, tmp_path):
    summary = render_video(RenderJob(avatar=avatar_file, out=tmp_path / "s.png", size=(96, 64)), log=lambda _: None)
    assert summary.frames == 1 and summary.backend == "gl" and "OpenGL" in summary.driver
    assert set(summary.timings) == {"model_ms", "skinning_ms", "render_ms", "write_ms"}


def test_auto_backend_falls_back_to_the_cpu_without_egl(avatar_file, tmp_path, monkeypatch):
    import pghm.render.frames as frames_module
    from pghm.errors import DisplayError

    def no_egl():
        raise DisplayError("cannot create a headless OpenGL 3.3 context through EGL (test)")

    monkeypatch.setattr(frames_module, "GLFrames", no_egl)  # where frame_renderer looks it up
    notes = []
    summary = render_video(RenderJob(avatar=avatar_file, out=tmp_path / "s.png", size=(96, 64)), log=notes.append)
    assert summary.backend == "cpu" and len(notes) == 1 and "CPU splatter" in notes[0]
    with pytest.raises(DisplayError):
        render_video(RenderJob(avatar=avatar_file, out=tmp_path / "t.png", size=(96, 64), backend="gl"))


def test_a_looping_motion_evaluates_each_pose_once_and_repeats_it_exactly(avatar_file, tmp_path):
    """Two loops of the walk at 6 fps: the second loop's frames come from the frame cache, so
    the model runs once per distinct motion frame and repeated frames are pixel-identical."""
    from pghm.body import load_body
    from pghm.motion.open_motion import open_motion

    motion = open_motion("walk", load_body("anny"))
    fps = 6.0
    per_loop = int(motion.duration * fps)
    job = RenderJob(
        avatar=avatar_file, out=tmp_path / "loops", motion="walk", fps=fps, frames=2 * per_loop, size=(96, 64)
    )
    distinct = {spec.motion_frame for spec in plan_frames(job, motion)}
    assert len(distinct) < 2 * per_loop, "the plan repeats motion frames"
    summary = render_video(job, log=lambda _: None)
    assert summary.frames == 2 * per_loop and summary.evaluated == len(distinct)
    frames = frames_of(tmp_path / "loops")
    specs = plan_frames(job, motion)
    first = {}
    for spec, image in zip(specs, frames):
        if spec.motion_frame in first:
            assert np.array_equal(first[spec.motion_frame], image)
        first.setdefault(spec.motion_frame, image)
