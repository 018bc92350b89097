"""``pghm capture`` on bad inputs: one line naming the file (and frames), exit status 2, nothing written."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from capture_videos import real_frames, require_mediapipe, truncated_video, write_flat_hdr_video, write_video

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
    require_mediapipe()


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
    code, lines = run_capture(tmp_path, capsys, path)
    assert_refused(tmp_path, code, lines, "noise.mp4: no person found in any of the 10 frame(s)")


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
    """A subject folder that holds anything is refused before the input is even read (pghm.io.outputs)."""
    earlier = tmp_path / "out" / "subject" / "meta.json"
    earlier.parent.mkdir(parents=True)
    earlier.write_text("an earlier capture")
    code, lines = run_capture(tmp_path, capsys, tmp_path / "any.mp4")
    assert code == EXIT_USER_ERROR and len(lines) == 1 and "not empty" in lines[0]
    assert list((tmp_path / "out").iterdir()) == [earlier.parent] and list(earlier.parent.iterdir()) == [earlier]
    assert earlier.read_text() == "an earlier capture"


@pytest.mark.parametrize("options, fragment", [(["--every", "0"], "--every"), (["--fov", "200"], "--fov")])
def test_bad_options(tmp_path, capsys, options, fragment):
    path = tmp_path / "any.mp4"
    path.write_text("x")
    assert_refused(tmp_path, *run_capture(tmp_path, capsys, path, *options), fragment)


def test_a_lens_whose_crop_the_checker_would_refuse_is_refused_before_the_images():
    """--fov 1 (the option's lowest) on 1280 x 720 frames and a 300 x 600 crop: the crop would see
    0.47 degrees (tan(fov' / 2) = tan(0.5 deg) 600 / 1280), which the subject's checker refuses;
    the least --fov named keeps the crop's camera inside the checker's rule."""
    from pghm.capture.config import CaptureConfig
    from pghm.capture.crop import Region, crop_intrinsics
    from pghm.errors import PghmError
    from pghm.subject.format import focal_range

    frames, crop = (1280, 720), (300, 600)
    with pytest.raises(PghmError) as refused:
        CaptureConfig(fov_deg=1.0).validate().check_crop_camera(*crop, *frames)
    message = str(refused.value)
    assert message.startswith("--fov 1: the person's crop (300x600 of the 1280x720 frames) would see 0.469 degrees")
    least = float(message.split("give --fov ")[1].split()[0])
    assert least == pytest.approx(2.14)
    for fov, accepted in ((least, True), (least - 0.02, False)):
        config = CaptureConfig(fov_deg=fov).validate()
        K = crop_intrinsics(config.source_intrinsics(*frames), Region(0, 0, *crop), (512, 256))
        assert (K[0, 0] / 512 <= focal_range(1.0)[1]) == accepted  # the checker's rule on the crop
        if accepted:
            config.check_crop_camera(*crop, *frames)
    CaptureConfig(fov_deg=1.0).validate().check_crop_camera(*frames, *frames)  # the whole frame: the lens's 1 degree
    with pytest.raises(PghmError, match="--focal 1e[+]06: .* at most 3.438e[+]04 pixels"):
        CaptureConfig(focal_px=1e6).validate().check_crop_camera(*crop, *frames)


def test_without_mediapipe_says_how_to_install(tmp_path, capsys, monkeypatch):
    for name in [name for name in sys.modules if name == "mediapipe" or name.startswith("mediapipe.")] + ["mediapipe"]:
        monkeypatch.setitem(sys.modules, name, None)  # import mediapipe now raises ImportError
    path = write_video(tmp_path / "clip.mp4", np.zeros((2, 32, 32, 3), np.uint8))
    assert_refused(tmp_path, *run_capture(tmp_path, capsys, path), "pip install 'pghm[capture]'")


def small_fit():
    from pghm.capture.config import BodyFitConfig

    return BodyFitConfig(steps=(2, 2, 2))  # the writer is under test here, not the fit's accuracy


def test_capture_writes_a_subject_that_data_check_accepts(tmp_path):
    mediapipe_required()
    import json

    from pghm.capture import CaptureConfig, capture
    from pghm.subject import Subject, check

    frames = real_frames(10)
    frames[4] = 128  # one frame without the person
    warnings = []
    config = CaptureConfig(progress=False, test_every=4, focal_px=1500.0, body=small_fit())
    out = capture(write_video(tmp_path / "clip.mp4", frames), tmp_path / "me", config, on_warning=warnings.append)
    assert out == tmp_path / "me"
    assert check(out) == []
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary folder left
    assert len(warnings) == 1 and "(4)" in warnings[0]
    subject = Subject.open(out)
    assert len(subject) == 9
    kept = [0, 1, 2, 3, 5, 6, 7, 8, 9]
    assert subject.arrays.frame_index.tolist() == kept
    assert json.loads((out / "splits.json").read_text()) == {"train": [0, 1, 2, 4, 5, 6, 8], "test": [3, 7]}
    meta = json.loads((out / "meta.json").read_text())
    assert meta["input"] == "clip.mp4" and str(tmp_path) not in (out / "meta.json").read_text()
    assert meta["fps"] == 10.0  # write_video's rate, read from the container
    assert meta["options"]["every"] == 1 and meta["hdr_transfer"] is None
    counts = {"frames_read": 10, "person_found": 9, "dropped": 1, "dropped_frames": [4], "cut_frames": []}
    assert meta["counts"] == counts
    # The focal length given in full-frame pixels, carried through the crop and the resize.
    crop = meta["crop"]
    scale = subject.arrays.width[0] / crop["width"]
    np.testing.assert_allclose(subject.arrays.K[0, 0, 0], 1500.0 * scale, rtol=1e-4)
    frame = subject[0]
    assert (frame.image[frame.mask == 0] == 1.0).all()  # composited on white through the mask
    assert not (out / "masks.npy").exists()


def test_interrupted_capture_leaves_nothing(tmp_path, monkeypatch):
    mediapipe_required()
    import pghm.capture.bodyfit

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pghm.capture.bodyfit, "fit_body", interrupted)
    video = write_video(tmp_path / "clip.mp4", real_frames(8))
    code = main(["capture", str(video), "--out", str(tmp_path / "out" / "me"), "--quiet"])
    assert code == 130
    assert list((tmp_path / "out").iterdir()) == []


@pytest.mark.parametrize(
    ("options", "mirror_pass", "pose_prior"),
    [((), True, True), (("--no-mirror-pass",), False, True), (("--no-pose-prior",), True, False)],
)
def test_switches_reach_the_config(tmp_path, capsys, monkeypatch, options, mirror_pass, pose_prior):
    """The mirrored pass and the learned pose prior are on by default; each --no-... turns one off."""
    import pghm.capture.pipeline

    seen = []
    monkeypatch.setattr(pghm.capture.pipeline, "capture", lambda input, out, config: seen.append(config) or out)
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"")  # never read: capture is replaced
    code, _ = run_capture(tmp_path, capsys, video, *options)
    assert code == 0 and len(seen) == 1
    assert seen[0].mirror_pass is mirror_pass and seen[0].pose_prior is pose_prior


def test_polish_needs_a_prior(tmp_path, capsys):
    """--polish is checked before the video is read: a missing file or an avatar (not a prior) is one line."""
    from pathlib import Path

    video = tmp_path / "clip.mp4"
    video.write_bytes(b"")  # never read: the prior is refused first
    code, lines = run_capture(tmp_path, capsys, video, "--polish", str(tmp_path / "nowhere.pt"))
    assert_refused(tmp_path, code, lines, "--polish", "nowhere.pt: no such prior file")
    avatar = Path(__file__).resolve().parent.parent / "assets" / "avatar.pt"
    code, lines = run_capture(tmp_path, capsys, video, "--polish", str(avatar))
    assert_refused(tmp_path, code, lines, "avatar.pt: a personalised avatar, not a prior")


def test_polish_reaches_the_config(tmp_path, capsys, monkeypatch):
    import pghm.capture.pipeline

    seen = []
    monkeypatch.setattr(pghm.capture.pipeline, "capture", lambda input, out, config: seen.append(config) or out)
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"")  # never read: capture is replaced
    prior = tmp_path / "prior.pt"
    prior.write_bytes(b"")
    assert run_capture(tmp_path, capsys, video)[0] == 0 and seen[-1].polish is None
    assert run_capture(tmp_path, capsys, video, "--polish", str(prior))[0] == 0 and seen[-1].polish == str(prior)


def test_hdr_video_without_tone_mapping_is_named_once(tmp_path, capsys, monkeypatch):
    """An ffmpeg without zscale (imageio-ffmpeg's builds differ) cannot map HDR to SDR: one warning says so."""
    mediapipe_required()
    monkeypatch.setattr("pghm.capture.video.has_filter", lambda name: False)
    path = write_flat_hdr_video(tmp_path / "iphone.mov", [0.5] * 10, "HLG")
    code, lines = run_capture(tmp_path, capsys, path)
    assert code == EXIT_USER_ERROR  # flat grey: no person
    assert len(lines) == 2, lines
    assert "iphone.mov: an HDR (HLG) video, and this ffmpeg has no zscale filter" in lines[0]
    assert "iphone.mov: no person found" in lines[1]
