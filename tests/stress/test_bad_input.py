"""Bad input from strangers, through the real command lines: one clear line and exit status 2.

Every kind of broken ``avatar.pt`` goes through each command that opens one (export, render,
eval, fit --prior) and the viewer's open action; broken motion files through ``pghm motion``,
``render --motion`` and ``export --pose``; broken subject folders through ``pghm data check``,
``train-prior`` and ``fit``. The error contract (pghm/errors.py): exit status 2 and exactly
one stderr line ``pghm: error: ...`` naming the problem, no traceback, no output file, and a
pickle that would run code never runs it. tests/test_avatar_file.py, test_bvh.py and
test_motion_file.py check the library's messages case by case; this file checks what users see.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import SMALL_MODEL
from PIL import Image
from stress_kit import bad_avatar_files, check, cli, one_error_line, unsafe_load_runs_code

from pghm.io.avatar import save_avatar
from pghm.subject import npz_bytes
from viewer.demo import development_avatar

BVH = (Path(__file__).parent.parent / "data" / "two_bone.bvh").read_text()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A valid small avatar and every kind of bad one made from it."""
    directory = tmp_path_factory.mktemp("bad_avatars")
    good = directory / "good.pt"
    save_avatar(good, development_avatar(SMALL_MODEL, seed=1))
    marker = directory / "code_ran"
    from pghm.body import load_body
    from pghm.motion.motion import Motion

    body = load_body()
    Motion(np.zeros((2, body.num_bones, 3)), np.zeros((2, 3)), 30.0, "anny", list(body.bone_names)).save(
        directory / "seed_motion.npz"
    )
    return good, marker, bad_avatar_files(good, directory / "bad", marker)


@pytest.fixture(scope="module")
def unsafe_load_ran_code(files) -> bool:
    """Whether an unsafe load of the very file the commands get creates the marker (checked before
    any command sees it, and the marker removed): "the marker never appears" means something only then."""
    _, marker, bad = files
    return unsafe_load_runs_code(bad["pickle that runs code"][0], marker)


def test_the_code_pickle_runs_code_when_loaded_unsafely(files, unsafe_load_ran_code):
    check(
        "bad avatar.pt",
        "positive control: torch.load(weights_only=False) of the pickle that runs code (child process)",
        "its marker file is created (so its absence after the commands below is meaningful)",
        f"marker created: {unsafe_load_ran_code}",
        unsafe_load_ran_code,
    )


COMMANDS = {
    "pghm export": lambda bad, out, subject: ["export", bad, "--out", out / "x.ply"],
    "pghm render": lambda bad, out, subject: [
        "render",
        bad,
        "--out",
        out / "x.png",
        "--backend",
        "cpu",
        "--size",
        "64x48",
    ],
    "pghm eval": lambda bad, out, subject: ["eval", bad, subject, "--report", out / "r.json", "--strip", out / "s.png"],
    "pghm fit --prior": lambda bad, out, subject: [
        "fit",
        subject,
        "--prior",
        bad,
        "--out",
        out / "a.pt",
        "--stage1-steps",
        "1",
        "--stage2-steps",
        "1",
        "--no-lpips",
    ],
}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_bad_avatar_through_every_command(command, files, unsafe_load_ran_code, tiny_dataset, tmp_path):
    _, marker, bad = files
    for kind, (path, words) in bad.items():
        out = tmp_path / kind.replace(" ", "_")
        out.mkdir()
        result = cli(*COMMANDS[command](path, out, tiny_dataset / "subject_000"))
        ok, observed = one_error_line(result)
        named = ok and words in result.stderr and str(path) in result.stderr
        nothing_written = not any(out.iterdir())
        check(
            "bad avatar.pt",
            f"{command}: {kind}",
            f"exit 2, one line naming the file and '{words}', no output",
            observed + ("" if nothing_written else "; AN OUTPUT FILE WAS WRITTEN"),
            named and nothing_written,
        )
    check(
        "bad avatar.pt",
        f"{command}: the pickle's code",
        "never runs (its marker file is never created; an unsafe load of the same file creates it)",
        f"marker {'CREATED' if marker.exists() else 'absent'}; unsafe load created it: {unsafe_load_ran_code}",
        unsafe_load_ran_code and not marker.exists(),
    )


def test_viewer_shows_the_error_and_keeps_the_avatar(files):
    """The viewer's open action (what its file field calls), without a window."""
    from viewer.viewer import Viewer

    good, marker, bad = files
    viewer = Viewer(good)
    scene = viewer.scene
    for kind, (path, words) in bad.items():
        opened = viewer.try_action(viewer.open_avatar, path)
        error = viewer.error or ""
        ok = not opened and "\n" not in error and str(path) in error and words in error and viewer.scene is scene
        check(
            "bad avatar.pt",
            f"viewer open: {kind}",
            "error shown in one line, current avatar kept",
            f"error line: {error[len(str(path)) + 2 :][:90]}" if ok else f"opened={opened}, error={error!r}",
            ok,
        )
    assert not marker.exists()
    assert viewer.try_action(viewer.open_avatar, good) and viewer.error is None


# ------------------------------------------------------------------------ motion files


def _replace(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new, 1)


def _million_rows() -> str:
    header = _replace(BVH, "Frames: 2", "Frames: 1000000").split("MOTION")[0]
    return header + "MOTION\nFrames: 1000000\nFrame Time: 0.04\n" + "0 90 0 0 0 0 0 0 0\n" * 1_000_000


BAD_BVH = {
    "missing MOTION section": (lambda: BVH.split("MOTION")[0], "missing MOTION"),
    "wrong channel count in a row": (lambda: _replace(BVH, "1 91 2 90 0 0 0 30 0", "1 91 2 90 0 0 0 30"), "8 values"),
    "CHANNELS count disagrees with names": (lambda: _replace(BVH, "CHANNELS 3", "CHANNELS 2"), "channel names"),
    "non-numeric value": (lambda: _replace(BVH, "1 91 2 90", "1 91 two 90"), "'two' is not a number"),
    "zero frames": (lambda: _replace(BVH, "Frames: 2", "Frames: 0"), "zero frames"),
    "10^6 frames claimed": (lambda: _replace(BVH, "Frames: 2", "Frames: 1000000"), "more than"),
    "10^6 frame rows": (_million_rows, "more than"),
    "denormal frame time (fuzzer find)": (
        lambda: _replace(BVH, "Frame Time: 0.04", "Frame Time: 5e-324"),
        "frame time",
    ),
}


def test_malformed_bvh_through_motion_import_and_render(files, tmp_path):
    good, _, _ = files
    for kind, (make, words) in BAD_BVH.items():
        path = tmp_path / f"{kind.split()[0]}_{len(kind)}.bvh"
        path.write_text(make())
        result = cli("motion", "import", path, "--out", tmp_path / "m.npz")
        ok, observed = one_error_line(result)
        check(
            "bad motion file",
            f"pghm motion import: {kind}",
            f"exit 2, one line naming '{words}'",
            observed,
            ok and words in result.stderr and not (tmp_path / "m.npz").exists(),
        )
    # The same reader behind render --motion (one case: the path is shared).
    path = tmp_path / "no_motion.bvh"
    path.write_text(BVH.split("MOTION")[0])
    result = cli("render", good, "--motion", path, "--out", tmp_path / "v.png", "--backend", "cpu", "--size", "32x32")
    ok, observed = one_error_line(result)
    check(
        "bad motion file",
        "pghm render --motion: missing MOTION section",
        "exit 2, one line",
        observed,
        ok and "missing MOTION" in result.stderr and not (tmp_path / "v.png").exists(),
    )


def test_npz_with_wrong_keys(files, tmp_path):
    good, _, _ = files
    path = tmp_path / "wrong_keys.npz"
    np.savez(path, poses=np.zeros((3, 10, 3)), trans=np.zeros((3, 3)))
    for name, argv in {
        "pghm motion info": ["motion", "info", path],
        "pghm export --pose": ["export", good, "--pose", path, "--out", tmp_path / "x.ply"],
        "pghm render --motion": ["render", good, "--motion", path, "--out", tmp_path / "x.png", "--backend", "cpu"],
    }.items():
        result = cli(*argv)
        ok, observed = one_error_line(result)
        check(
            "bad motion file",
            f"{name}: npz with wrong keys",
            "exit 2, one line naming the missing keys",
            observed,
            ok and "missing rotations" in result.stderr,
        )


# ----------------------------------------------------------------------------- datasets


def _break(subject: Path, kind: str) -> str:
    """Break one thing in a subject folder; returns words the error must contain."""
    if kind == "missing image":
        (subject / "images" / "000001.png").unlink()
        return "000001.png"
    if kind == "image of the wrong size":
        Image.new("RGB", (32, 24), "white").save(subject / "images" / "000001.png")
        return "000001.png"
    with np.load(subject / "cameras.npz", allow_pickle=False) as data:
        arrays = {key: data[key].copy() for key in data.files}
    arrays["K"][1, 0, 0] = np.nan
    (subject / "cameras.npz").write_bytes(npz_bytes(arrays))
    return "not finite for image(s) 1"


@pytest.mark.parametrize("kind", ["missing image", "image of the wrong size", "NaN camera"])
def test_broken_subject_through_check_train_prior_and_fit(kind, tiny_dataset, files, tmp_path):
    good, _, _ = files
    data = Path(shutil.copytree(tiny_dataset, tmp_path / "data"))
    words = _break(data / "subject_000", kind)
    result = cli("data", "check", data / "subject_000")
    listed = [line for line in result.stdout.splitlines() if words in line]
    check(
        "bad dataset",
        f"pghm data check: {kind}",
        "exit 2, the problem listed with its file",
        f"exit {result.code}: {listed[0] if listed else result.stdout[:120]}",
        result.code == 2 and len(listed) == 1,
    )
    runs = {
        "pghm train-prior": [
            "train-prior",
            data,
            "--out",
            tmp_path / "p.pt",
            "--steps",
            "1",
            "--uv-resolution",
            "64",
            "--no-lpips",
        ],
        "pghm fit": [
            "fit",
            data / "subject_000",
            "--prior",
            good,
            "--out",
            tmp_path / "a.pt",
            "--stage1-steps",
            "1",
            "--stage2-steps",
            "1",
            "--no-lpips",
        ],
    }
    for name, argv in runs.items():
        result = cli(*argv)
        ok, observed = one_error_line(result)
        check(
            "bad dataset",
            f"{name}: {kind}",
            "exit 2 before training, one line naming the file",
            observed,
            ok and words in result.stderr and not list(tmp_path.glob("*.pt")),
        )


# ----------------------------------------------------------- what the fuzzer found, kept fixed


def _deflate_damaged_npz(path: Path) -> None:
    """A motion file whose first member's deflate stream is garbage (zlib.error when read)."""
    from pghm.body import load_body
    from pghm.motion.motion import Motion

    body = load_body()
    Motion(np.zeros((2, body.num_bones, 3)), np.zeros((2, 3)), 30.0, "anny", list(body.bone_names)).save(path)
    data = bytearray(path.read_bytes())
    name_length, extra_length = int.from_bytes(data[26:28], "little"), int.from_bytes(data[28:30], "little")
    start = 30 + name_length + extra_length  # the first member's compressed bytes
    data[start : start + 4] = b"\xff\xff\xff\xff"
    path.write_bytes(bytes(data))


def _broken_header_npz(path: Path) -> None:
    """A motion file whose fps.npy header is cut inside its dict (numpy's tokenizer raises TokenError)."""
    import zipfile

    from pghm.body import load_body
    from pghm.motion.motion import Motion

    body = load_body()
    Motion(np.zeros((2, body.num_bones, 3)), np.zeros((2, 3)), 30.0, "anny", list(body.bone_names)).save(path)
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    header = b"{'descr': '<f8', 'fortran_order': False, 'shape': ("
    header += b" " * (63 - len(header)) + b"\n"
    members["fps.npy"] = b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + b"\x00" * 8
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)


def test_fuzzer_findings_stay_fixed(files, tmp_path):
    """Each input here once escaped a loader as a non-PghmError (benchmarks/fuzz_loaders.py found them)."""
    import io
    import time

    import torch

    from pghm.errors import PghmError
    from pghm.io.avatar import load_avatar
    from pghm.motion.motion import Motion

    good, _, _ = files
    payload = torch.load(good, weights_only=True)

    def avatar_with(**config) -> Path:
        changed = {**payload, "config": {**payload["config"], **config}}
        path = tmp_path / f"config_{len(list(tmp_path.iterdir()))}.pt"
        buffer = io.BytesIO()
        torch.save(changed, buffer)
        path.write_bytes(buffer.getvalue())
        return path

    cases = {
        "avatar config asking for 10^9 latent channels (was: a 100 GB allocation error)": (
            lambda: load_avatar(avatar_with(latent_channels=10**9)),
            "latent_channels",
        ),
        "avatar config with a NaN base scale (was: NaN Gaussians from a loaded avatar)": (
            lambda: load_avatar(avatar_with(base_scale_factor=float("nan"))),
            "base_scale_factor",
        ),
        "avatar config with scale range 0 (was: ValueError math domain error)": (
            lambda: load_avatar(avatar_with(scale_factor_range=0.0)),
            "scale_factor_range",
        ),
        "avatar config with an offset bound '0.1' as text (was: TypeError)": (
            lambda: load_avatar(avatar_with(max_static_offset="0.1")),
            "max_static_offset",
        ),
    }
    damaged = tmp_path / "damaged.npz"
    _deflate_damaged_npz(damaged)
    cases["motion .npz with a damaged deflate stream (was: zlib.error)"] = (lambda: Motion.load(damaged), "unreadable")
    two_bodies = tmp_path / "two_bodies.npz"
    with np.load(files[0].parent / "seed_motion.npz", allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    np.savez(two_bodies, **{**arrays, "body": np.array(["x" * 100, "y" * 100])})
    cases["motion .npz naming two long bodies (was: a PghmError printed over two lines)"] = (
        lambda: Motion.load(two_bodies),
        "must be one string",
    )
    broken = tmp_path / "broken_header.npz"
    _broken_header_npz(broken)
    cases["motion .npz with an .npy header cut mid-dict (was: tokenize.TokenError)"] = (
        lambda: Motion.load(broken),
        "unreadable",
    )
    for name, (load, words) in cases.items():
        started = time.perf_counter()
        try:
            load()
            observed, ok = "loaded", False
        except PghmError as error:
            observed, ok = f"{type(error).__name__}: {error}", words in str(error) and "\n" not in str(error)
        except Exception as error:  # noqa: BLE001 - the regression this guards against
            observed, ok = f"UNEXPECTED {type(error).__name__}: {error}", False
        seconds = time.perf_counter() - started
        check(
            "found and fixed",
            name,
            "one PghmError line (the time is shown, not judged: it depends on the machine)",
            f"{observed[-110:]} ({seconds:.2f} s)",
            ok,
        )


def test_fuzzer_findings_in_subject_folders(tiny_dataset, tmp_path):
    from pghm.errors import DatasetError
    from pghm.subject import Subject
    from pghm.subject import check as check_subject

    def text_for_k(folder: Path) -> None:
        with np.load(folder / "cameras.npz", allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
        arrays["K"] = np.array(["x" * 10] * len(arrays["K"]))
        (folder / "cameras.npz").write_bytes(npz_bytes(arrays))

    def nested_splits(folder: Path) -> None:
        (folder / "splits.json").write_text('{"train": [[0], 1], "test": [[0], 1]}')

    def no_images(folder: Path) -> None:
        for name in ("cameras.npz", "poses.npz"):
            with np.load(folder / name, allow_pickle=False) as data:
                arrays = {
                    key: data[key][:0] if data[key].ndim and key not in ("bone_names", "shape") else data[key]
                    for key in data.files
                }
            (folder / name).write_bytes(npz_bytes(arrays))

    for name, (damage, words) in {
        "text where cameras.npz's K should be (fuzzer; was: ValueError)": (text_for_k, "'K' must hold numbers"),
        "lists nested in splits.json (fuzzer; was: TypeError: unhashable type)": (nested_splits, "split 'train'"),
        "a subject of zero images (review; was: ValueError from a reshape)": (no_images, "describes no images"),
    }.items():
        folder = Path(shutil.copytree(tiny_dataset / "subject_000", tmp_path / name.split()[1]))
        damage(folder)
        try:
            problems = [str(p) for p in check_subject(folder)]
            listed = [p for p in problems if words in p]
            observed, ok = f"{len(problems)} problem(s): {listed[0] if listed else problems}", bool(listed)
        except Exception as error:  # noqa: BLE001 - the regression this guards against
            observed, ok = f"UNEXPECTED {type(error).__name__}: {error}", False
        try:
            Subject.open(folder)
            opened, opened_ok = "opened", False
        except DatasetError as error:
            opened, opened_ok = str(error), words in str(error) or "index outside" in str(error)
        check(
            "found and fixed",
            f"pghm data check and Subject.open: {name}",
            "listed as a problem; opening raises one DatasetError",
            f"{observed[:100]}; open: {opened[-80:]}",
            ok and opened_ok,
        )
