"""Motion ``.npz`` files: a round trip, and every malformed file raising one MotionFileError."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from pghm.errors import MotionFileError
from pghm.motion.motion import MAX_FRAMES, MOTION_KEYS, Motion

BONES = ["root", "spine", "head"]


def small_motion(frames: int = 4) -> Motion:
    rng = np.random.default_rng(0)
    return Motion(
        rotations=rng.normal(size=(frames, len(BONES), 3)),
        translation=rng.normal(size=(frames, 3)),
        fps=24.0,
        body="anny",
        bone_names=BONES,
        source="test",
    )


def fields(motion: Motion) -> dict[str, np.ndarray]:
    return {
        "rotations": motion.rotations,
        "translation": motion.translation,
        "fps": np.float64(motion.fps),
        "body": np.str_(motion.body),
        "bone_names": np.array(motion.bone_names),
        "source": np.str_(motion.source),
    }


def write(path, **arrays) -> None:
    np.savez(path, **arrays)


def test_round_trip_is_exact(tmp_path):
    motion = small_motion()
    motion.save(tmp_path / "m.npz")
    loaded = Motion.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(loaded.rotations, motion.rotations)  # float32 both ways
    np.testing.assert_array_equal(loaded.translation, motion.translation)
    assert (loaded.fps, loaded.body, loaded.bone_names, loaded.source) == (24.0, "anny", BONES, "test")
    assert loaded.duration == pytest.approx(3 / 24)


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"rotations": None}, "missing rotations"),
        ({"fps": None, "source": None}, "missing fps, source"),
        ({"rotations": np.zeros((4, 2, 3))}, "'rotations' has shape (4, 2, 3)"),
        ({"rotations": np.zeros((4, 3))}, "'rotations' has shape (4, 3)"),
        ({"translation": np.zeros((5, 3))}, "'translation' has shape (5, 3), expected (4, 3)"),
        ({"rotations": np.zeros((0, 3, 3)), "translation": np.zeros((0, 3))}, "no frames"),
        ({"rotations": np.full((4, 3, 3), np.nan)}, "'rotations' at frame 0"),
        ({"translation": np.full((4, 3), np.inf)}, "'translation' at frame 0"),
        ({"fps": np.float64(0.0)}, "'fps' must be a positive number"),
        ({"fps": np.float64(np.nan)}, "'fps' must be a positive number"),
        ({"fps": np.array([24.0, 30.0])}, "malformed motion file"),
        ({"rotations": np.array([["a", "b", "c"]] * 3)}, "malformed motion file"),
        ({"rotations": np.array([None, 1], dtype=object)}, "unreadable motion file"),
    ],
)
def test_malformed_npz_raises_one_clear_error(tmp_path, change, expected):
    arrays = fields(small_motion())
    for key, value in change.items():
        if value is None:
            del arrays[key]
        else:
            arrays[key] = value
    path = tmp_path / "bad.npz"
    write(path, **arrays)
    with pytest.raises(MotionFileError) as info:
        Motion.load(path)
    message = str(info.value)
    assert expected in message and message.startswith(f"{path}: ") and "\n" not in message, message


def test_too_many_frames_are_refused(tmp_path):
    arrays = fields(small_motion())
    arrays["rotations"] = np.zeros((MAX_FRAMES + 1, 1, 3), dtype=np.float32)
    arrays["translation"] = np.zeros((MAX_FRAMES + 1, 3), dtype=np.float32)
    arrays["bone_names"] = np.array(["root"])
    write(tmp_path / "long.npz", **arrays)
    with pytest.raises(MotionFileError, match=f"more than the {MAX_FRAMES}"):
        Motion.load(tmp_path / "long.npz")


@pytest.mark.parametrize(
    ("content", "expected"),
    [(b"", "unreadable"), (b"not a zip at all", "unreadable"), (b"PK\x03\x04" + bytes(40), "unreadable")],
)
def test_non_npz_files_raise(tmp_path, content, expected):
    path = tmp_path / "m.npz"
    path.write_bytes(content)
    with pytest.raises(MotionFileError, match=expected):
        Motion.load(path)


def test_truncated_file_raises(tmp_path):
    buffer = io.BytesIO()
    np.savez(buffer, **fields(small_motion()))
    path = tmp_path / "cut.npz"
    path.write_bytes(buffer.getvalue()[: len(buffer.getvalue()) // 2])
    with pytest.raises(MotionFileError):
        Motion.load(path)


def test_missing_file_and_foreign_skeleton(tmp_path):
    with pytest.raises(MotionFileError, match="not found"):
        Motion.load(tmp_path / "none.npz")
    with pytest.raises(MotionFileError, match="re-import or re-generate"):
        small_motion().check_skeleton("smplx", BONES)
    assert set(MOTION_KEYS) == set(fields(small_motion()))


def test_a_subject_folder_is_its_videos_motion(tiny_dataset, tmp_path, body):
    """The tiny subject (frames 0, 1, 2, two views each) plays as 3 poses, each frame's first
    image's, at 30 fps; frame numbers two apart (``--every 2``) play at 15; a folder that is no
    subject is one error naming it."""
    import shutil

    from pghm.errors import DatasetError
    from pghm.motion.open_motion import SUBJECT_FPS, open_motion

    subject = tiny_dataset / "subject_000"
    poses, cameras = np.load(subject / "poses.npz"), np.load(subject / "cameras.npz")
    motion = open_motion(subject, body)
    first = [int(np.flatnonzero(cameras["frame_index"] == f)[0]) for f in (0, 1, 2)]
    assert motion.num_frames == 3 and motion.fps == SUBJECT_FPS
    np.testing.assert_array_equal(motion.rotations, poses["rotations"][first].astype(np.float32))
    np.testing.assert_array_equal(motion.translation, poses["translation"][first].astype(np.float32))
    strided = shutil.copytree(subject, tmp_path / "strided")
    np.savez(strided / "cameras.npz", **{**cameras, "frame_index": cameras["frame_index"] * 2})
    assert open_motion(strided, body).fps == SUBJECT_FPS / 2
    with pytest.raises(DatasetError, match="meta.json"):
        open_motion(tmp_path, body)
    meta = json.loads((strided / "meta.json").read_text())
    (strided / "meta.json").write_text(json.dumps({**meta, "fps": 25.0}))
    assert open_motion(strided, body).fps == 12.5  # the video's rate, stated, over the frame step


def test_a_subject_folder_replays_with_the_pose_track_of_an_avatar_fitted_on_it(tiny_dataset, body):
    """A track of corrections linear in time, c_f = f v, known at frames 0 and 2: the replay adds
    each trained frame's own and frame 1 exactly v, on the track's bones only; a track learned
    on other poses (another digest) leaves the stored poses."""
    import torch

    from pghm.io.avatar import PoseTrack
    from pghm.motion.open_motion import open_motion
    from pghm.subject import Subject

    subject = tiny_dataset / "subject_000"
    stored = open_motion(subject, body)
    bones = torch.tensor([1, 4, 7])
    v_rot, v_trans = torch.randn(3, 3) * 0.05, torch.tensor([0.01, -0.02, 0.03])
    digest = Subject.open(subject).arrays.poses_digest()
    track = PoseTrack(
        torch.tensor([0, 2]),
        bones,
        torch.stack([0 * v_rot, 2 * v_rot]),
        torch.stack([0 * v_trans, 2 * v_trans]),
        digest,
    )
    replay = open_motion(subject, body, track=track)
    expected = stored.rotations.copy()
    for frame in (0, 1, 2):
        expected[frame, bones.numpy()] += frame * v_rot.numpy()
    np.testing.assert_allclose(replay.rotations, expected, atol=1e-6)
    np.testing.assert_allclose(replay.translation - stored.translation, np.outer([0, 1, 2], v_trans.numpy()), atol=1e-6)
    track.poses = "another video"
    np.testing.assert_array_equal(open_motion(subject, body, track=track).rotations, stored.rotations)
