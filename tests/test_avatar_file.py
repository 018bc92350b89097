"""avatar.pt: round trip, and one clear error for every kind of bad file."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import absolute_paths

from pghm.errors import AvatarFileError
from pghm.io.avatar import Avatar, avatar_payload, load_avatar, recorded_path, save_avatar
from pghm.io.torch_file import ZIP_MAGIC
from pghm.model import PGHM, ModelConfig

SMALL = ModelConfig(
    uv_resolution=32,
    latent_channels=4,
    encoder_channels=(4, 6, 8),
    decoder_channels=(6, 4),
    condition_channels=(2, 2, 4),
)


def make_avatar(kind: str = "avatar") -> Avatar:
    torch.manual_seed(0)
    model = PGHM(SMALL, num_identities=3 if kind == "prior" else 0)
    for p in model.parameters():
        p.data.normal_()
    latent = torch.randn(1, 4, 32, 32) if kind == "avatar" else None
    return Avatar(
        model=model,
        kind=kind,
        body_name="anny",
        shape=torch.full((6,), 0.5),
        shapes=torch.rand(3, 6) if kind == "prior" else None,
        latent=latent,
        metadata={"steps": 12, "data": "synthetic", "metrics": {"psnr": 30.5}},
    )


@pytest.mark.parametrize("kind", ["avatar", "prior"])
def test_round_trip(tmp_path, kind):
    avatar = make_avatar(kind)
    path = tmp_path / "a.pt"
    save_avatar(path, avatar)
    loaded = load_avatar(path)
    assert loaded.kind == kind and loaded.body_name == "anny" and loaded.metadata == avatar.metadata
    assert loaded.model.config == SMALL
    for (name, a), (_, b) in zip(avatar.model.state_dict().items(), loaded.model.state_dict().items()):
        assert torch.equal(a, b), name
    if kind == "avatar":
        assert torch.equal(loaded.latent, avatar.latent)
    else:
        assert torch.equal(loaded.shapes, avatar.shapes) and loaded.latent is None
        # Same mode as the loaded model: eval lays the convs out channels-last, which rounds differently.
        torch.testing.assert_close(loaded.identity_map(2), avatar.model.eval().decode_identity(2))
    assert not list(tmp_path.glob(".*tmp"))  # no temporary file left behind


def write_payload(path, **changes):
    payload = avatar_payload(make_avatar())
    for key, value in changes.items():
        if value is KeyError:
            del payload[key]
        else:
            payload[key] = value
    torch.save(payload, path)
    return path


def expect_error(path, match):
    with pytest.raises(AvatarFileError, match=match) as info:
        load_avatar(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


def test_missing_file(tmp_path):
    expect_error(tmp_path / "none.pt", "not found")


def test_truncated_file(tmp_path):
    path = tmp_path / "a.pt"
    save_avatar(path, make_avatar())
    data = path.read_bytes()
    for cut in (10, len(data) // 2, len(data) - 20):
        path.write_bytes(data[:cut])
        expect_error(path, "truncated or corrupted")


def test_random_bytes(tmp_path):
    """Random blobs, bare and behind a real zip header, and a real file's bytes shuffled past it."""
    rng = np.random.default_rng(7)
    path = tmp_path / "a.pt"
    save_avatar(path, make_avatar())
    real = path.read_bytes()
    for trial in range(200):
        blob = rng.bytes(int(rng.integers(1, 8192)))
        if trial % 3 == 1:
            blob = ZIP_MAGIC + blob
        elif trial % 3 == 2:
            cut = int(rng.integers(64, len(real) - 256))
            blob = real[:cut] + bytes(rng.permutation(np.frombuffer(real[cut:], np.uint8)))
        path.write_bytes(blob)
        expect_error(path, "avatar file")


def test_foreign_tensor_file(tmp_path):
    path = tmp_path / "a.pt"
    torch.save(torch.zeros(3), path)
    expect_error(path, "not a pghm avatar file")


def test_wrong_version(tmp_path):
    expect_error(write_payload(tmp_path / "a.pt", version=99), "format version 99")


def test_missing_keys(tmp_path):
    expect_error(write_payload(tmp_path / "a.pt", latent=KeyError), "missing keys: latent")


def test_wrong_shapes_dtypes_and_nan(tmp_path):
    payload = avatar_payload(make_avatar())
    good_latent = payload["latent"]
    cases = {
        "latent_shape": ({"latent": good_latent[:, :2]}, "'latent' has shape"),
        "latent_dtype": ({"latent": good_latent.long()}, "dtype torch.int64"),
        "latent_nan": ({"latent": good_latent.clone().fill_(float("nan"))}, "non-finite"),
        "shape_nan": ({"body": {"name": "anny", "shape": torch.full((6,), float("inf"))}}, "body.shape"),
    }
    for name, (change, match) in cases.items():
        expect_error(write_payload(tmp_path / f"{name}.pt", **change), match)
    weights = dict(payload["weights"])
    key = next(k for k in weights if k.endswith("head.weight"))
    weights[key] = weights[key][:1]
    expect_error(write_payload(tmp_path / "w.pt", weights=weights), f"weights.{key}' has shape")
    weights = dict(payload["weights"])
    weights[key] = weights[key].clone().fill_(float("nan"))
    expect_error(write_payload(tmp_path / "n.pt", weights=weights), "non-finite")
    weights = dict(payload["weights"])
    del weights[key]
    expect_error(write_payload(tmp_path / "m.pt", weights=weights), "do not match")


def good_track() -> dict:
    return {
        "frames": torch.tensor([0, 1, 3]),
        "bones": torch.tensor([2, 5]),
        "rotations": torch.randn(3, 2, 3),
        "translation": torch.randn(3, 3),
        "poses": "0" * 64,
    }


def test_pose_track_round_trip_and_bad_tracks(tmp_path):
    """A fit's pose track comes back as saved; every malformed one is one line naming it."""
    track = good_track()
    loaded = load_avatar(write_payload(tmp_path / "a.pt", pose_track=track)).pose_track
    for name in ("frames", "bones", "rotations", "translation"):
        assert torch.equal(getattr(loaded, name), track[name])
    assert loaded.poses == track["poses"] and load_avatar(write_payload(tmp_path / "b.pt")).pose_track is None
    assert loaded.aligned.tolist() == []  # a track saved before the fit aligned held-out frames: none are
    aligned = load_avatar(write_payload(tmp_path / "c.pt", pose_track={**track, "aligned": track["frames"][1:2]}))
    assert aligned.pose_track.aligned.tolist() == track["frames"][1:2].tolist()
    cases = {
        "not_a_dict": ([1, 2], "must hold frames"),
        "missing": ({k: v for k, v in track.items() if k != "bones"}, "must hold frames"),
        "descending": ({**track, "frames": torch.tensor([3, 1, 0])}, "ascending"),
        "repeated": ({**track, "frames": torch.tensor([0, 1, 1])}, "distinct"),
        "float_frames": ({**track, "frames": torch.tensor([0.0, 1.0, 3.0])}, "int64"),
        "negative_bone": ({**track, "bones": torch.tensor([-1, 5])}, "non-negative"),
        "rotations_shape": ({**track, "rotations": torch.randn(3, 3, 3)}, "pose_track.rotations' has shape"),
        "translation_nan": ({**track, "translation": torch.full((3, 3), float("nan"))}, "non-finite"),
        # The physical ranges of poses.npz and motion files (pghm.motion.motion), just past them.
        "rotations_absurd": ({**track, "rotations": torch.full((3, 2, 3), 1.01e3)}, "rotations' has values beyond"),
        "translation_absurd": ({**track, "translation": torch.full((3, 3), -1.01e4)}, "translation' has values"),
        "digest": ({**track, "poses": 7}, "digest"),
        "aligned_unknown": ({**track, "aligned": track["frames"][-1:] + 1}, "aligned' lists frames the track has no"),
        "aligned_float": ({**track, "aligned": torch.tensor([0.0])}, "pose_track.aligned' is not"),
    }
    for name, (value, match) in cases.items():
        expect_error(write_payload(tmp_path / f"{name}.pt", pose_track=value), match)


class RunsCode:
    """Unpickling this object would create a marker file."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_code_in_the_pickle_never_runs(tmp_path):
    marker = tmp_path / "pwned"
    path = write_payload(tmp_path / "evil.pt", metadata={"x": RunsCode(str(marker))})
    assert not marker.exists()
    expect_error(path, "refusing to load")
    assert not marker.exists()


def test_cli_style_failure_in_a_subprocess(tmp_path):
    """Loading a bad file from a fresh interpreter prints no traceback when handled by the CLI runner."""
    path = tmp_path / "bad.pt"
    path.write_bytes(b"garbage")
    code = (
        "import sys; from pghm.cli.main import run; from pghm.io.avatar import load_avatar;"
        f"sys.exit(run(lambda a: load_avatar({str(path)!r}), None))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "pghm: error:" in result.stderr


def test_member_of_a_prior_is_that_identity():
    """A prior's member i renders as identity i: its decoded map and its own shape, not identity 0's."""
    from pghm.io.avatar import avatar_geometry

    prior = make_avatar("prior")
    member = prior.member(2)
    assert member.kind == "avatar" and member.shapes is None
    assert torch.equal(member.identity_map(), prior.identity_map(2))
    assert torch.equal(member.shape_of(), prior.shapes[2]) and not torch.equal(prior.shapes[2], prior.shapes[0])
    assert torch.equal(avatar_geometry(member).shape, prior.shapes[2])
    with pytest.raises(Exception, match="outside the prior's 3 identities"):
        prior.member(3)
    with pytest.raises(Exception, match="this is an avatar"):
        member.member(0)


ASSETS = sorted((Path(__file__).resolve().parent.parent / "assets").glob("*.pt"))


@pytest.mark.parametrize("path", ASSETS, ids=[p.name for p in ASSETS])
def test_shipped_files_record_no_absolute_path(path):
    """No metadata string is, or contains, an absolute path of the machine that made the file."""
    metadata = torch.load(path, weights_only=True)["metadata"]
    assert metadata["data"] and metadata["command"]
    assert absolute_paths(metadata) == []


def test_recorded_path_is_relative_inside_the_working_directory_else_a_name(tmp_path, monkeypatch):
    (tmp_path / "data" / "subject_000").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "data")
    assert recorded_path(tmp_path / "data" / "subject_000") == "subject_000"
    assert recorded_path("subject_000/../subject_000") == "subject_000"
    monkeypatch.chdir(tmp_path / "data" / "subject_000")
    assert recorded_path(tmp_path / "data" / "prior.pt") == "prior.pt"


def test_load_avatar_at_the_top_of_the_package(tmp_path):
    import pghm
    from pghm import load_avatar as top_level

    assert top_level is load_avatar and "load_avatar" in pghm.__all__
    save_avatar(tmp_path / "a.pt", make_avatar())
    assert top_level(tmp_path / "a.pt").kind == "avatar"
    with pytest.raises(AttributeError, match="no attribute 'load_avatr'"):
        pghm.load_avatr  # noqa: B018
