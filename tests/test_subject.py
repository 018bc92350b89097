"""The subject format: writer, lazy reader, and a checker that names every injected defect.

Each defect test copies a valid generated subject, breaks one thing, and asserts the
checker reports exactly that (one line naming the file and the problem), and that
``pghm data check`` exits with status 2.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pghm.cli.main import main as cli_main
from pghm.errors import DatasetError
from pghm.subject import Dataset, Subject, SubjectArrays, check, image_name, npz_bytes, write_image, write_subject
from pghm.synth import generate, load_config


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("subject") / "tiny"
    generate(load_config("tiny"), seed=4, out=out, workers=1, progress=False)
    return out


@pytest.fixture
def subject_dir(dataset, tmp_path) -> Path:
    """A private copy of one valid subject to break."""
    return Path(shutil.copytree(dataset / "subject_000", tmp_path / "subject"))


def _rewrite_npz(path: Path, **changes: np.ndarray) -> None:
    with np.load(path, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    arrays.update(changes)
    path.write_bytes(npz_bytes(arrays))


def _array(path: Path, key: str) -> np.ndarray:
    with np.load(path, allow_pickle=False) as data:
        return data[key].copy()


def _problems(directory: Path) -> list[str]:
    return [str(problem) for problem in check(directory)]


def _cli_check(directory: Path, capsys) -> tuple[int, list[str]]:
    status = cli_main(["data", "check", str(directory)])
    return status, capsys.readouterr().out.strip().splitlines()


# ----------------------------------------------------------------- checker


def test_valid_subject_and_dataset_pass(dataset, capsys):
    assert check(dataset) == []
    assert check(dataset / "subject_001") == []
    status, lines = _cli_check(dataset, capsys)
    assert status == 0 and lines == [f"{dataset}: ok (2 subject(s), 12 images)"]


def test_check_names_a_missing_image(subject_dir, capsys):
    (subject_dir / "images" / image_name(3)).unlink()
    assert _problems(subject_dir) == ["images/000003.png: missing"]
    status, lines = _cli_check(subject_dir, capsys)
    assert status == 2 and lines == ["images/000003.png: missing"]


def test_check_names_an_image_of_the_wrong_size(subject_dir, capsys):
    Image.new("RGB", (60, 64), "white").save(subject_dir / "images" / image_name(2))
    assert _problems(subject_dir) == ["images/000002.png: size 60x64, cameras.npz says 64x64"]
    assert _cli_check(subject_dir, capsys)[0] == 2


def test_images_of_two_sizes_are_refused_by_the_check_and_the_loader(subject_dir, capsys):
    """Frame 1 at 128 x 128 among 64 x 64 frames, its camera scaled to match and its files that size:
    each image agrees with its camera, but a training step renders a subject's images as one batch,
    so ``data check`` and the loader every training command reads through refuse it, in one line."""
    from pghm.train.data import TrainingData

    cameras = subject_dir / "cameras.npz"
    width, height, K = _array(cameras, "width"), _array(cameras, "height"), _array(cameras, "K")
    width[1], height[1], K[1, :2] = 128, 128, 2 * K[1, :2]
    _rewrite_npz(cameras, width=width, height=height, K=K)
    Image.new("RGB", (128, 128), "white").save(subject_dir / "images" / image_name(1))
    Image.new("L", (128, 128), 255).save(subject_dir / "masks" / image_name(1))
    message = "the images have 2 sizes (64x64, 128x128); a subject's images must all have one size"
    assert _problems(subject_dir) == [f"cameras.npz: {message}"]
    assert _cli_check(subject_dir, capsys)[0] == 2
    with pytest.raises(DatasetError, match=message.replace("(", r"\(").replace(")", r"\)")):
        TrainingData(subject_dir)


def test_check_names_a_non_finite_pose(subject_dir, capsys):
    rotations = _array(subject_dir / "poses.npz", "rotations")
    rotations[4, 10, 1] = np.nan
    _rewrite_npz(subject_dir / "poses.npz", rotations=rotations)
    assert _problems(subject_dir) == ["poses.npz: 'rotations' is not finite for image(s) 4"]
    assert _cli_check(subject_dir, capsys)[0] == 2


def test_check_names_a_malformed_pose_noise(subject_dir, capsys):
    meta = json.loads((subject_dir / "meta.json").read_text())
    meta["pose_noise"] = {"rotation_std_deg": "high", "translation_std_m": 0.05}
    (subject_dir / "meta.json").write_text(json.dumps(meta))
    (problem,) = _problems(subject_dir)
    assert problem.startswith("meta.json: 'pose_noise' must give numbers >= 0 rotation_std_deg and translation_std_m")
    assert _cli_check(subject_dir, capsys)[0] == 2


def test_check_names_malformed_aligned_frames(subject_dir, capsys):
    meta = json.loads((subject_dir / "meta.json").read_text())
    (subject_dir / "meta.json").write_text(json.dumps({**meta, "aligned_frames": [3, 11]}))
    assert _problems(subject_dir) == [] and Subject.open(subject_dir).aligned_frames() == {3, 11}
    for wrong in ([3, -1], [2.0], "3"):
        (subject_dir / "meta.json").write_text(json.dumps({**meta, "aligned_frames": wrong}))
        (problem,) = _problems(subject_dir)
        assert problem.startswith("meta.json: 'aligned_frames' must be a list of frame numbers >= 0")
        with pytest.raises(DatasetError, match="meta.json: 'aligned_frames'"):
            Subject.open(subject_dir).aligned_frames()
    assert _cli_check(subject_dir, capsys)[0] == 2


def test_check_names_a_non_finite_camera(subject_dir, capsys):
    K = _array(subject_dir / "cameras.npz", "K")
    K[2, 0, 0] = np.nan
    _rewrite_npz(subject_dir / "cameras.npz", K=K)
    assert _problems(subject_dir) == ["cameras.npz: 'K' is not finite for image(s) 2"]
    assert _cli_check(subject_dir, capsys)[0] == 2


def test_a_soft_matte_passes_the_check_and_reads_back_as_its_fraction(subject_dir, capsys):
    path = subject_dir / "masks" / image_name(1)
    mask = np.asarray(Image.open(path)).copy()
    mask[mask == 255] = 200
    Image.fromarray(mask).save(path)
    assert _problems(subject_dir) == []
    read = Subject.open(subject_dir)[1].mask
    np.testing.assert_array_equal(read, mask.astype(np.float32) / 255)


def test_check_names_a_camera_turned_away(subject_dir, capsys):
    E = _array(subject_dir / "cameras.npz", "world_to_camera")
    # Turn camera 3 half way round about its own y axis: it now faces away from the body.
    turn = np.diag([-1.0, 1.0, -1.0, 1.0]).astype(E.dtype)
    E[3] = turn @ E[3]
    _rewrite_npz(subject_dir / "cameras.npz", world_to_camera=E)
    (problem,) = _problems(subject_dir)
    assert problem.startswith("cameras.npz: camera of image 3 looks away from the subject")
    assert _cli_check(subject_dir, capsys)[0] == 2


def test_check_reports_problems_inside_a_dataset_with_the_subject_prefix(dataset, tmp_path):
    copy = Path(shutil.copytree(dataset, tmp_path / "data"))
    (copy / "subject_001" / "masks" / image_name(0)).unlink()
    shutil.rmtree(copy / "subject_000")
    assert _problems(copy) == ["subject_000: subject folder missing", "subject_001/masks/000000.png: missing"]


def test_check_decodes_every_image_and_mask(subject_dir, monkeypatch):
    """Every PNG's pixels are decoded (a truncated file has a valid header), one file at a time."""
    decoded = []
    original = Image.Image.load

    def spy(self):
        decoded.append(getattr(self, "filename", ""))
        return original(self)

    monkeypatch.setattr(Image.Image, "load", spy)
    assert check(subject_dir) == []
    files = [name for name in decoded if name]  # converted copies have no file name
    expected = {f"{folder}/{image_name(i)}" for folder in ("images", "masks") for i in range(6)}
    assert {f"{Path(name).parent.name}/{Path(name).name}" for name in files} == expected


# ----------------------------------------------------------------- reader


def test_reader_is_lazy_and_returns_frame_records(subject_dir):
    subject = Subject.open(subject_dir)
    assert len(subject) == 6 and subject.split_names == ["test", "train"]
    # Opening read no image: removing one now only breaks that frame.
    (subject_dir / "images" / image_name(5)).unlink()
    train = subject.split("train")
    assert len(train) == 4 and [f.index for f in train] == [0, 1, 2, 3]
    frame = train[1]
    assert frame.image.dtype == np.float32 and frame.image.shape == (64, 64, 3)
    assert 0.0 <= frame.image.min() and frame.image.max() <= 1.0
    assert 0.0 <= frame.mask.min() and frame.mask.max() == 1.0
    assert frame.K.shape == (3, 3) and frame.world_to_camera.shape == (4, 4)
    assert frame.rotations.shape == (len(subject.arrays.bone_names), 3) and frame.translation.shape == (3,)
    assert (frame.frame_index, frame.view_index) == (0, 1)
    assert frame.rotations_true is not None
    with pytest.raises(DatasetError, match="000005.png"):
        subject[5]
    with pytest.raises(DatasetError, match="no split 'val'"):
        subject.split("val")


def test_dataset_reader_lists_subjects(dataset):
    data = Dataset.open(dataset)
    assert len(data) == 2 and data.names == ["subject_000", "subject_001"]
    assert len(data[1]) == 6


def test_open_names_a_structural_problem(subject_dir):
    _rewrite_npz(subject_dir / "poses.npz", translation=np.zeros((5, 3), np.float32))
    with pytest.raises(DatasetError, match=r"'translation' has shape \(5, 3\), expected \(6, 3\)"):
        Subject.open(subject_dir)


# ----------------------------------------------------------------- writer


def _arrays(n: int = 2, bones: int = 3) -> SubjectArrays:
    E = np.repeat(np.eye(4)[None], n, 0)
    E[:, 2, 3] = 3.0
    return SubjectArrays(
        K=np.repeat(np.array([[40.0, 0, 16], [0, 40.0, 12], [0, 0, 1]])[None], n, 0),
        world_to_camera=E,
        height=np.full(n, 24),
        width=np.full(n, 32),
        rotations=np.zeros((n, bones, 3)),
        translation=np.zeros((n, 3)),
        shape=np.full(6, 0.5),
        body="anny",
        bone_names=["root", "a", "b"],
        splits={"train": [0], "test": [1]},
    )


def test_writer_round_trip_and_reproducible_bytes(tmp_path):
    for folder in ("one", "two"):
        write_subject(tmp_path / folder, _arrays(), {"source": "test"})
        for index in range(2):
            rgb = np.full((24, 32, 3), 255, np.uint8)
            mask = np.zeros((24, 32), np.uint8)
            mask[5:10, 8:20] = 255
            rgb[mask > 0] = (200, 30, 30)
            write_image(tmp_path / folder, index, rgb, mask)
    for name in ("cameras.npz", "poses.npz", "splits.json", "meta.json", "images/000001.png"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes()
    assert check(tmp_path / "one") == []
    frame = Subject.open(tmp_path / "one")[1]
    assert frame.image[7, 10].tolist() == pytest.approx([200 / 255, 30 / 255, 30 / 255])
    assert frame.mask.sum() == 5 * 12 and frame.rotations_true is None


def test_writer_rejects_a_split_index_out_of_range(tmp_path):
    arrays = _arrays()
    arrays.splits = {"train": [0, 2]}
    with pytest.raises(DatasetError, match="split 'train'"):
        write_subject(tmp_path, arrays, {})
