"""Every command against a hostile user, one mechanism per class of bad input.

The cases are generated from the parsers where they can be, so a command added tomorrow is
tried by adding nothing but one row to :data:`BASE`:

- numeric options: every option whose ``type`` is a declared range (pghm/cli/options.py) gets
  values below and above it, NaN, infinities and a non-number; a bare ``int`` / ``float`` is a
  failure in itself;
- outputs: every output option (``--out``, ``--report``, ``--strip``, ``--plot``) gets an
  unwritable place, an existing folder (or file, for folder outputs), a path under a file, the
  command's own input, a symlink to it, and ``/dev/full``;
- file contents, sizes and memory, Ctrl-C, training on nothing: one test each.

Each case asserts the error contract: exit status 2 (130 for Ctrl-C), exactly one stderr line,
no traceback, nothing left in the working folder, every input byte-identical afterwards.
Refusals happen before any heavy work, so the file takes seconds: parser cases run in-process,
the others in forked children of the CLI server (stress_kit.cli).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
from capture_videos import write_video
from conftest import SMALL_MODEL, TINY_MODEL
from stress_kit import ROOT, check, cli, one_error_line

from pghm._fault_injection import TEST_INTERRUPT_VARIABLE
from pghm.cli.main import build_parser, main
from pghm.cli.options import Integer, Real, Size
from pghm.io.avatar import save_avatar
from pghm.subject import npz_bytes
from viewer.demo import development_avatar

BVH = (ROOT / "tests" / "data" / "two_bone.bvh").read_text()
OUTPUT_DESTS = ("out", "report", "strip", "plot")
"""Option destinations that name an output."""
FOLDER_OUTPUTS = {("synth", "out"), ("capture", "out")}
"""(command, dest) of outputs that are new folders (render's folder form: test_ctrl_c_leaves_nothing)."""
RESULT_FOLDERS = {("bench", "out")}
"""(command, dest) of folders that results are added to (they may exist and hold files)."""

TINY_RUN = {
    "train": ["--steps", "1", "--uv-resolution", "32", "--latent-channels", "4"],
    "fit": ["--stage1-steps", "1", "--stage2-steps", "1"],
    "bench": ["--gaussians", "10", "--resolution", "8", "--repeats", "1"],
}
"""Options that keep a base command to seconds should a case fail to be refused (it then runs)."""

# ------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def world(tmp_path_factory, tiny_dataset):
    """Inputs every command can use: an avatar, a prior-shaped file, a motion, a BVH, a subject."""
    from pghm.body import load_body
    from pghm.motion.motion import Motion

    root = tmp_path_factory.mktemp("adversarial_inputs")
    avatar = development_avatar(SMALL_MODEL, seed=3)
    save_avatar(root / "avatar.pt", avatar)
    body = load_body()
    Motion(np.zeros((3, body.num_bones, 3)), np.zeros((3, 3)), 30.0, "anny", list(body.bone_names)).save(
        root / "motion.npz"
    )
    (root / "clip.bvh").write_text(BVH)
    subject = Path(shutil.copytree(tiny_dataset / "subject_000", root / "subject"))
    video = write_video(root / "video.mp4", np.full((2, 32, 32, 3), 128, np.uint8))  # refusals come before reading it
    return {
        "avatar": root / "avatar.pt",
        "motion": root / "motion.npz",
        "bvh": root / "clip.bvh",
        "subject": subject,
        "video": video,
    }


@pytest.fixture(scope="module")
def tiny_prior(tmp_path_factory, tiny_dataset) -> Path:
    """A one-step prior of TINY_MODEL: fits from it take a second."""
    from pghm.model import ModelConfig
    from pghm.train.loop import LoopConfig
    from pghm.train.prior import PriorConfig, train_prior

    path = tmp_path_factory.mktemp("adversarial_prior") / "prior.pt"
    config = PriorConfig(model=ModelConfig(**TINY_MODEL), loop=LoopConfig(steps=1, images_per_shard=2), lpips=False)
    train_prior(tiny_dataset, path, config)
    return path


def base_commands(world: dict, out: Path) -> dict[tuple[str, ...], list[str]]:
    """A valid command line per (sub)command, writing under ``out``: the row each case perturbs."""
    a, s = str(world["avatar"]), str(world["subject"])
    return {
        ("synth",): ["synth", "--out", str(out / "synth_out"), "--quiet", "--workers", "1"],
        ("data", "check"): ["data", "check", s],
        ("data", "sheet"): ["data", "sheet", s, "--out", str(out / "sheet.png")],
        ("motion", "import"): ["motion", "import", str(world["bvh"]), "--out", str(out / "m.npz")],
        ("motion", "make"): ["motion", "make", "walk", "--frames", "5", "--out", str(out / "m.npz")],
        ("motion", "info"): ["motion", "info", str(world["motion"])],
        ("motion", "preview"): ["motion", "preview", "walk", "--out", str(out / "p.png")],
        ("train-prior",): [
            "train-prior",
            str(world["subject"].parent),
            "--out",
            str(out / "p.pt"),
            "--no-lpips",
            *TINY_RUN["train"],
        ],
        ("fit",): ["fit", s, "--prior", a, "--out", str(out / "a.pt"), "--no-lpips", *TINY_RUN["fit"]],
        ("eval",): ["eval", a, s, "--report", str(out / "r.json"), "--strip", str(out / "r.png")],
        ("export",): ["export", a, "--out", str(out / "x.ply")],
        ("bench",): [
            "bench",
            "splat",
            "--out",
            str(out / "bench"),
            "--plot",
            str(out / "plot.png"),
            *TINY_RUN["bench"],
        ],
        ("render",): ["render", a, "--out", str(out / "v.png"), "--backend", "cpu", "--size", "32x24"],
        ("capture",): ["capture", str(world["video"]), "--out", str(out / "captured"), "--quiet"],
    }


BASE = base_commands({"avatar": "A", "subject": Path("S/s"), "motion": "M", "bvh": "B", "video": "V"}, Path("O"))
"""The rows (for the coverage test; the real paths come from the fixture)."""

# ------------------------------------------------------------------------------ running


def run_in_process(argv: list[str]):
    """``pghm ARGV`` in this process (for refusals that happen in the parser): (exit status, stderr)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exit_request:
            code = exit_request.code
    return code, err.getvalue()


def snapshot(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (hidden ones included) -> sha256 of its bytes ('dir' for folders,
    the target for symlinks)."""
    found = {}
    for path in sorted(folder.rglob("*")):
        key = str(path.relative_to(folder))
        if path.is_symlink():  # dangling links and loops included
            found[key] = f"link to {path.readlink()}"
        else:
            found[key] = "dir" if path.is_dir() else hashlib.sha256(path.read_bytes()).hexdigest()
    return found


def holds_contract(result, before: dict, after: dict, code: int = 2, progress: bool = False) -> tuple[bool, str]:
    """Exit ``code``, one stderr line, no traceback, nothing created and no input changed. With
    ``progress`` (a training run that got going), earlier lines may be its progress bars and
    warnings: the error must then be the last line."""
    if progress and result.code == code and result.error_lines:
        last = result.error_lines[-1]
        ok, observed = last.startswith("pghm: error: "), f"exit {result.code}: {last[-200:]}"
    elif code == 2:
        ok, observed = one_error_line(result)
    else:
        lines = result.error_lines
        ok = result.code == code and len(lines) == 1
        observed = f"exit {result.code}: {' | '.join(lines)[-200:]}"
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    if changed:
        ok, observed = False, observed + f"; FILES CHANGED OR LEFT: {changed[:4]}"
    if "Traceback" in result.stderr:
        ok = False
    return ok, observed


# ------------------------------------------------------------------------- numeric options


def walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, action) of every option of every (sub)parser."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from walk(sub, (*path, name))
        else:
            yield path, action


def bad_values(kind) -> dict[str, str]:
    """Values outside a declared range, non-finite values and a non-number."""
    if isinstance(kind, Size):
        return {"side 0": "0x10", "side past the limit": f"{kind.max_side + 1}x10", "not WxH": "10", "NaN": "nanx10"}
    values = {"NaN": "nan", "infinity": "inf", "-infinity": "-inf", "overflow": "1e400", "not a number": "ten"}
    if kind.low is not None:
        margin = 1 if isinstance(kind, Integer) else max(abs(kind.low) * 1e-6, 1e-9)
        values["below the range"] = str(kind.low - margin)
        if getattr(kind, "open_low", False):
            values["the open bound"] = str(kind.low)
    if kind.high is not None:
        values["above the range"] = str(kind.high + 1) if isinstance(kind, Integer) else f"{kind.high * 10 + 1:g}"
    if isinstance(kind, Integer):
        values["a fraction"] = "1.5"
    return values


NUMERIC = [
    (path, action)
    for path, action in walk(build_parser())
    if action.option_strings and isinstance(action.type, (Integer, Real, Size))
]


def test_every_numeric_option_declares_a_range():
    bare = [
        f"pghm {' '.join(path)} {action.option_strings[-1]}"
        for path, action in walk(build_parser())
        if action.type in (int, float)
        or (action.type is None and isinstance(action.default, (int, float)) and not isinstance(action.default, bool))
    ]
    check(
        "adversarial: numeric options",
        "every numeric option of every command (walked from the parser)",
        "a declared range and finiteness (pghm.cli.options), no bare int or float",
        f"{len(NUMERIC)} ranged options; bare: {bare or 'none'}",
        not bare and len(NUMERIC) > 30,
    )


@pytest.mark.parametrize("path,action", NUMERIC, ids=[f"{'-'.join(p)}{a.option_strings[-1]}" for p, a in NUMERIC])
def test_numeric_option_out_of_range(path, action, world, tmp_path):
    argv = base_commands(world, tmp_path)[path]
    option = action.option_strings[-1]
    failures = []
    for name, value in bad_values(action.type).items():
        before = snapshot(tmp_path)
        code, err = run_in_process([*argv, option, value])
        lines = [line for line in err.splitlines() if line.strip()]
        ok = code == 2 and len(lines) == 1 and lines[0].startswith("pghm: error: ") and option in lines[0]
        if not ok or snapshot(tmp_path) != before:
            failures.append(f"{name} ({value}): exit {code}, {err.strip()[-120:]}")
    kind = action.type
    check(
        "adversarial: numeric options",
        f"pghm {' '.join(path)} {option} out of {getattr(kind, 'range', 'WxH')}, NaN, inf, not a number",
        "exit 2 at the parser, one line naming the option and its range, nothing written",
        "; ".join(failures) if failures else f"{len(bad_values(kind))} values refused",
        not failures,
    )


# ---------------------------------------------------------------------------------- outputs

OUTPUTS = [
    (path, action.dest)
    for path, action in walk(build_parser())
    if action.option_strings and action.dest in OUTPUT_DESTS and path in BASE
]


def test_every_command_has_a_row():
    paths = {path for path, _ in walk(build_parser()) if path}
    commands = {p for p in paths if not any(q[: len(p)] == p and q != p for q in paths)}  # leaves only
    missing = sorted(" ".join(p) for p in commands - set(BASE))
    check(
        "adversarial: outputs",
        "every (sub)command of the parser has a valid command line in the table",
        "none missing (a new command must add its row)",
        f"{len(commands)} commands; missing: {missing or 'none'}",
        not missing,
    )


def _replace_option(argv: list[str], option: str, value: str) -> list[str]:
    argv = list(argv)
    if option in argv:
        argv[argv.index(option) + 1] = value
    else:
        argv += [option, value]
    return argv


def bad_outputs(
    output: tuple[str, str], work: Path, an_input: Path | None, a_folder: Path | None = None
) -> dict[str, str]:
    """Bad values for the output ``(command, dest)``: name -> path."""
    afile = work / "afile.txt"
    afile.write_text("a file\n")
    existing = work / "existing"
    existing.mkdir(exist_ok=True)
    (existing / "keep.txt").write_text("not to be lost\n")
    cases = {
        "unwritable place (/sys)": "/sys/pghm_adversarial.out",
        "under a file": str(afile / "x.out"),
        "a device (/dev/full)": "/dev/full",
    }
    if output in FOLDER_OUTPUTS:
        cases["an existing file"] = str(afile)
        cases["a non-empty folder"] = str(existing)
    elif output not in RESULT_FOLDERS:
        cases["an existing folder"] = str(existing)
    if an_input is not None and an_input.is_file():
        link = work / "link_to_input"
        if not link.exists():
            link.symlink_to(an_input)
        cases["the command's input"] = str(an_input)
        cases["a symlink to the input"] = str(link)
    if a_folder is not None:
        cases["inside the input folder"] = str(a_folder / "inside" / "output.png")
    return cases


def _fingerprint(world: dict) -> dict:
    """Every input's bytes, hashed (folders file by file)."""
    return {k: snapshot(v) if v.is_dir() else hashlib.sha256(v.read_bytes()).hexdigest() for k, v in world.items()}


@pytest.mark.parametrize("path,dest", OUTPUTS, ids=[f"{'-'.join(p)}--{d}" for p, d in OUTPUTS])
def test_output_refused_before_work(path, dest, world, tmp_path):
    argv = base_commands(world, tmp_path)[path]
    if (path, dest) == (("bench",), "report"):  # the stress benchmark's report (refused before the suite runs)
        argv = ["bench", "stress", "--fuzz-seconds", "0"]
    option = f"--{dest}"
    an_input = next((Path(a) for a in argv[len(path) :] if Path(a).is_file()), None)
    a_folder = next((Path(a) for a in argv[len(path) :] if Path(a).is_dir()), None)
    failures, passed = [], 0
    for name, value in bad_outputs((path[0], dest), tmp_path, an_input, a_folder).items():
        inputs = _fingerprint(world)
        before = snapshot(tmp_path)
        result = cli(*_replace_option(argv, option, value), cwd=tmp_path)
        ok, observed = holds_contract(result, before, snapshot(tmp_path))
        unchanged = inputs == _fingerprint(world)
        if ok and unchanged:
            passed += 1
        else:
            failures.append(f"{name}: {observed}" + ("" if unchanged else "; AN INPUT CHANGED"))
    check(
        "adversarial: outputs",
        f"pghm {' '.join(path)} {option}: unwritable, folder/file, under a file, /dev/full, the input, a symlink "
        "to it, inside an input folder",
        "exit 2 before any work, one line naming the option, nothing written, inputs unchanged",
        "; ".join(failures)[:300] if failures else f"{passed} bad outputs refused",
        not failures,
    )


# --------------------------------------------------------------------------- file contents


def _subject_with(world: dict, work: Path, damage) -> Path:
    folder = Path(shutil.copytree(world["subject"], work / "damaged_subject"))
    with np.load(folder / "cameras.npz", allow_pickle=False) as data:
        cameras = {key: data[key].copy() for key in data.files}
    with np.load(folder / "poses.npz", allow_pickle=False) as data:
        poses = {key: data[key].copy() for key in data.files}
    damage(cameras, poses)
    (folder / "cameras.npz").write_bytes(npz_bytes(cameras))
    (folder / "poses.npz").write_bytes(npz_bytes(poses))
    return folder


def _motion_with(work: Path, name: str, rotation: float = 0.0, translation: float = 0.0) -> Path:
    from pghm.body import load_body

    body = load_body()
    rotations = np.zeros((3, body.num_bones, 3))
    rotations[1, 2, 0] = rotation
    trans = np.zeros((3, 3))
    trans[2, 1] = translation
    path = work / name
    np.savez(
        path,
        rotations=rotations,
        translation=trans,
        fps=np.float64(30.0),
        body=np.str_("anny"),
        bone_names=np.array(body.bone_names),
        source=np.str_("hostile"),
    )
    return path


def _zero_rotation(cameras, poses):
    cameras["world_to_camera"][1, :3, :3] = 0.0


def _nan_k(cameras, poses):
    cameras["K"][0, 1, 2] = np.nan


def _huge_pose(cameras, poses):
    poses["rotations"][2, 3, 1] = 1e20


def _far_camera(cameras, poses):
    cameras["world_to_camera"][0, 2, 3] = 1e30  # finite in float32, far beyond any scene


def _empty(work: Path, name: str) -> Path:
    path = work / name
    path.write_bytes(b"")
    return path


def file_cases(world: dict, work: Path) -> dict[str, tuple[list[str], str]]:
    """name -> (argv, words the one error line must contain)."""
    a = str(world["avatar"])
    huge_rotation = _motion_with(work, "huge_rotation.npz", rotation=1e20)
    huge_bvh = work / "huge.bvh"
    huge_bvh.write_text(BVH.replace("1 91 2 90", "1e40 91 2 90"))
    cases = {
        "motion .npz with a rotation of 1e20 rad -> export --pose": (
            ["export", a, "--pose", str(huge_rotation), "--out", str(work / "x.ply")],
            "'rotations' at frame 1",
        ),
        "motion .npz with a rotation of 1e20 rad -> render --motion": (
            ["render", a, "--motion", str(huge_rotation), "--out", str(work / "v.png"), "--backend", "cpu"],
            "not a finite number within",
        ),
        "motion .npz with a translation of 1e40 m -> motion info": (
            ["motion", "info", str(_motion_with(work, "far.npz", translation=1e40))],
            "'translation' at frame 2",
        ),
        "BVH with a position of 1e40 -> motion import": (
            ["motion", "import", str(huge_bvh), "--out", str(work / "m.npz")],
            "line",
        ),
        "empty .npz -> motion info": (["motion", "info", str(_empty(work, "empty.npz"))], "empty.npz"),
        "empty .bvh -> render --motion": (
            ["render", a, "--motion", str(_empty(work, "empty.bvh")), "--out", str(work / "v.png"), "--backend", "cpu"],
            "empty",
        ),
        "empty avatar .pt -> export": (
            ["export", str(_empty(work, "empty.pt")), "--out", str(work / "x.ply")],
            "empty.pt",
        ),
        "a folder named like an avatar -> export": (
            ["export", str(Path(shutil.copytree(world["subject"], work / "folder.pt"))), "--out", str(work / "x.ply")],
            "folder.pt",
        ),
    }
    for name, damage, words in (
        ("camera rotation all zeros", _zero_rotation, "not a rigid transform"),
        ("NaN in K", _nan_k, "'K' is not finite"),
        ("a pose rotation of 1e20 rad", _huge_pose, "beyond"),
        ("a camera 1e30 m away", _far_camera, "beyond"),
    ):
        subject = _subject_with(world, work / name.replace(" ", "_"), damage)
        cases[f"subject with {name} -> fit"] = (
            ["fit", str(subject), "--prior", "scratch", "--out", str(work / "a.pt"), "--no-lpips"],
            words,
        )
        cases[f"subject with {name} -> eval"] = (
            ["eval", a, str(subject), "--report", str(work / "r.json"), "--strip", str(work / "r.png")],
            words,
        )
    return cases


def refuse_each(area, cases: dict[str, tuple[list[str], str]], world: dict, tmp_path: Path) -> None:
    """Run every case (name -> (argv, words)): exit 2, one line holding its words, nothing written under
    ``tmp_path``/work, every input unchanged. ``area`` is the report's section, or a function of the name."""
    work = tmp_path / "work"
    for name, (argv, words) in cases.items():
        inputs = _fingerprint(world)
        before = snapshot(work)
        result = cli(*argv, cwd=tmp_path)
        ok, observed = holds_contract(result, before, snapshot(work))
        check(
            area(name) if callable(area) else area,
            name,
            f"exit 2, one line with '{words}', nothing written, inputs unchanged",
            observed,
            ok and words in result.stderr and inputs == _fingerprint(world),
        )


def test_bad_file_contents_are_refused_at_the_loader(world, tmp_path):
    (tmp_path / "work").mkdir()
    refuse_each("adversarial: file contents", file_cases(world, tmp_path / "work"), world, tmp_path)


def test_data_check_lists_bad_values_and_truncated_pngs(world, tmp_path):
    subject = _subject_with(world, tmp_path, lambda c, p: (_zero_rotation(c, p), _huge_pose(c, p)))
    image = subject / "images" / "000002.png"
    image.write_bytes(image.read_bytes()[: len(image.read_bytes()) // 2])
    result = cli("data", "check", subject)
    expected = [
        "not a rigid transform (its rotation is not a rotation) for image(s) 1",
        "'rotations' is beyond",
        "images/000002.png: unreadable",
    ]
    found = [words for words in expected if words in result.stdout]
    check(
        "adversarial: file contents",
        "pghm data check: camera rotation of zeros, pose rotation of 1e20, a truncated image PNG",
        "exit 2, each listed (image pixels are decoded, not only headers)",
        f"exit {result.code}; found {len(found)} of {len(expected)}: {result.stdout.strip().splitlines()[:4]}",
        result.code == 2 and found == expected,
    )


# ------------------------------------------------------------------------- sizes and memory


def test_sizes_beyond_gl_and_memory(world, tmp_path):
    a = str(world["avatar"])
    cases = {
        "render --size 16385x16 through GL (llvmpipe: 16,384)": (
            ["render", a, "--size", "16385x16", "--out", str(tmp_path / "x.png"), "--backend", "gl"],
            ("GL_MAX", "16384"),
        ),
        "render --size 20000x20000 on the CPU (400 M pixels)": (
            ["render", a, "--size", "20000x20000", "--out", str(tmp_path / "x.png"), "--backend", "cpu"],
            ("pixels",),
        ),
        "fit --stage1-images 10000 (about 300 GB)": (
            [
                "fit",
                str(world["subject"]),
                "--prior",
                a,
                "--out",
                str(tmp_path / "a.pt"),
                "--stage1-images",
                "10000",
                "--no-lpips",
            ],
            ("GB", "fewer images"),
        ),
    }
    for name, (argv, words) in cases.items():
        before = snapshot(tmp_path)
        result = cli(*argv, cwd=tmp_path)
        ok, observed = holds_contract(result, before, snapshot(tmp_path))
        check(
            "adversarial: sizes and memory",
            name,
            f"exit 2 before allocating, one line with the limit ({', '.join(words)})",
            observed,
            ok and all(w in result.stderr for w in words),
        )


# --------------------------------------------------------------------------------- training


def test_training_refuses_a_result_of_nothing(world, tmp_path):
    from pghm.errors import PghmError
    from pghm.train.loop import LoopState, check_trained

    subject = Path(shutil.copytree(world["subject"], tmp_path / "truncated"))
    for png in (subject / "images").glob("*.png"):
        png.write_bytes(png.read_bytes()[:200])  # headers parse, pixels do not
    before = snapshot(tmp_path)
    result = cli(
        "fit", subject, "--prior", "scratch", "--out", tmp_path / "a.pt", "--stage1-steps", "1",
        "--stage2-steps", "1", "--no-lpips", "--checkpoint-every", "0", cwd=tmp_path,
    )  # fmt: skip
    ok, observed = holds_contract(result, before, snapshot(tmp_path), progress=True)
    check(
        "adversarial: training on nothing",
        "pghm fit on a subject whose images are all truncated PNGs",
        "exit 2, the error as the last line after the warnings; no avatar written (was: written with final {})",
        observed,
        ok and "a.pt" in result.stderr,
    )
    nan = float("nan")
    states = {
        "no step at all": [LoopState()],
        "every step skipped as non-finite": [LoopState(step=3, skipped_steps=3, history=[{"loss": nan}] * 3)],
        "no finite loss in any step": [LoopState(step=2, skipped_steps=1, history=[{"loss": nan}, {"loss": nan}])],
        "no step saw an image": [LoopState(step=4)],
    }
    for name, state in states.items():
        try:
            check_trained(state, tmp_path / "x.pt")
            observed, ok = "accepted", False
        except PghmError as error:
            observed, ok = str(error), "not written" in str(error)
        check("adversarial: training on nothing", f"check_trained: {name}", "PghmError, nothing written", observed, ok)
    check_trained([LoopState(step=2, history=[{"loss": 0.2}, {"loss": 0.1}])], tmp_path / "x.pt")
    # A last step skipped by the guard leaves the parameters of the step before: written.
    check_trained([LoopState(step=2, skipped_steps=1, history=[{"loss": 0.2}, {"loss": nan}])], tmp_path / "x.pt")


def test_checkpoint_is_gone_after_success_and_prior_kinds(world, tiny_dataset, tiny_prior, tmp_path):
    out = tmp_path / "a.pt"
    result = cli(
        "fit", world["subject"], "--prior", tiny_prior, "--out", out, "--stage1-steps", "1", "--stage2-steps", "1",
        "--no-lpips", "--checkpoint-every", "1", cwd=tmp_path,
    )  # fmt: skip
    leftovers = sorted(p.name for p in tmp_path.iterdir() if p != out)
    check(
        "adversarial: training on nothing",
        "pghm fit --checkpoint-every 1 that succeeds",
        "exit 0, the avatar written, no a.pt.ckpt (nor anything else) left",
        f"exit {result.code}; avatar {out.is_file()}; left: {leftovers or 'nothing'}",
        result.code == 0 and out.is_file() and not leftovers,
    )
    cases = {
        "fit with an avatar as --prior": (
            ["fit", world["subject"], "--prior", out, "--out", tmp_path / "b.pt", "--no-lpips"],
            "not a prior",
        ),
        "eval on a data-set folder": (["eval", out, tiny_dataset, "--report", tmp_path / "r.json"], "subject_001"),
        "export --identity 2 of an avatar": (
            ["export", out, "--identity", "2", "--out", tmp_path / "x.ply"],
            "personalised avatar",
        ),
        "render --identity 2 of an avatar": (
            ["render", out, "--identity", "2", "--out", tmp_path / "x.png", "--backend", "cpu"],
            "personalised avatar",
        ),
    }
    for name, (argv, words) in cases.items():
        before = snapshot(tmp_path)
        result = cli(*argv, cwd=tmp_path)
        ok, observed = holds_contract(result, before, snapshot(tmp_path))
        check("adversarial: misc", name, f"exit 2, one line with '{words}'", observed, ok and words in result.stderr)


# ------------------------------------------------------------------------ Ctrl-C and SIGTERM


INTERRUPTED_RUNS = [
    ("startup", ["motion", "make", "walk", "--out", "m.npz"]),
    ("render-frame", ["render", "AVATAR", "--frames", "3", "--out", "frames", "--backend", "cpu", "--size", "8x6"]),
    ("render-frame", ["render", "AVATAR", "--frames", "3", "--out", "v.mp4", "--backend", "cpu", "--size", "8x6"]),
    ("synth-subjects", ["synth", "--out", "data", "--workers", "1", "--quiet"]),
]
"""(test-hook point, command) of the runs interrupted at a chosen moment (pghm/_fault_injection.py)."""
SIGNALS = {"SIGINT": ("Ctrl-C", "interrupted"), "SIGTERM": ("SIGTERM", "terminated")}
"""Signal -> (report area, the one line's word): SIGTERM must unwind as Ctrl-C does."""


@pytest.mark.parametrize("signal_name", list(SIGNALS))
@pytest.mark.parametrize("point,argv", INTERRUPTED_RUNS)
def test_interrupt_leaves_nothing(signal_name, point, argv, world, tmp_path):
    area, word = SIGNALS[signal_name]
    argv = [str(world["avatar"]) if a == "AVATAR" else a for a in argv]
    result = cli(*argv, cwd=tmp_path, env={TEST_INTERRUPT_VARIABLE: f"{point}:{signal_name}"})
    lines = [line for line in result.error_lines if "Loading cached" not in line]
    left = sorted(p.name for p in tmp_path.iterdir())
    code = 128 + signal.Signals[signal_name]
    check(
        f"adversarial: {area}",
        f"{signal_name} at '{point}' (test hook): pghm {' '.join(argv[:2])} ... {argv[argv.index('--out') + 1]}",
        f"exit {code}, one line 'pghm: {word}', no traceback, no file or folder left (staged outputs removed)",
        f"exit {result.code}: {' | '.join(lines)[-160:]}; left: {left or 'nothing'}",
        result.code == code and lines == [f"pghm: {word}"] and not left,
    )


def test_viewer_options_refused_before_a_window(world):
    """pghm-view's entry (no display needed: the parser refuses first)."""
    from viewer.app import build_parser as viewer_parser
    from viewer.app import main as viewer_main

    ranged = [action for _, action in walk(viewer_parser()) if isinstance(action.type, (Integer, Real, Size))]
    failures = []
    for action in ranged:
        for name, value in bad_values(action.type).items():
            err = io.StringIO()
            with contextlib.redirect_stderr(err):
                code = viewer_main([str(world["avatar"]), action.option_strings[-1], value])
            lines = [line for line in err.getvalue().splitlines() if line.strip()]
            if not (code == 2 and len(lines) == 1 and lines[0].startswith("pghm-view: error: ")):
                failures.append(f"{action.option_strings[-1]} {name}: exit {code}, {lines}")
    check(
        "adversarial: numeric options",
        f"pghm-view {', '.join(a.option_strings[-1] for a in ranged)}: 0, past the limit, not WxH, NaN",
        "exit 2, one line 'pghm-view: error: ...', before any window",
        "; ".join(failures) if failures else f"{len(ranged)} option(s) refused every bad value",
        ranged and not failures,
    )


# ------------------------------------------------------------------- the classes of bad input


def _png_folder(folder: Path, count: int = 3) -> Path:
    from PIL import Image

    folder.mkdir(parents=True)
    for index in range(count):
        Image.fromarray(np.full((32, 48, 3), 40 * index, np.uint8)).save(folder / f"{index:03d}.png")
    return folder


def _avatar_with_shape(world: dict, path: Path, value: float) -> Path:
    import torch

    payload = torch.load(world["avatar"], weights_only=True)
    payload["body"]["shape"][0] = value
    torch.save(payload, path)
    return path


def _rewrite_subject(world: dict, folder: Path, change) -> Path:
    """A copy of the subject with ``change(folder)`` applied to its files."""
    folder = Path(shutil.copytree(world["subject"], folder))
    change(folder)
    return folder


def _set_poses(folder: Path, **values) -> None:
    with np.load(folder / "poses.npz", allow_pickle=False) as data:
        poses = {key: data[key].copy() for key in data.files}
    for key, value in values.items():
        poses[key] = np.asarray(value, poses[key].dtype) if key != "body" else np.str_(value)
    (folder / "poses.npz").write_bytes(npz_bytes(poses))


def _empty_train(folder: Path) -> None:
    splits = json.loads((folder / "splits.json").read_text())
    (folder / "splits.json").write_text(json.dumps({"train": [], "test": splits["test"]}))


def _set_camera(folder: Path, key: str, index: tuple, value: float) -> None:
    with np.load(folder / "cameras.npz", allow_pickle=False) as data:
        cameras = {key: data[key].copy() for key in data.files}
    cameras[key][index] = value
    (folder / "cameras.npz").write_bytes(npz_bytes(cameras))


def _break_two_images(folder: Path) -> None:
    """The first two training images: a dangling link and a corrupt PNG."""
    first, second = json.loads((folder / "splits.json").read_text())["train"][:2]
    dangling = folder / "images" / f"{first:06d}.png"
    dangling.unlink()
    dangling.symlink_to(folder / "nowhere.png")
    (folder / "images" / f"{second:06d}.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)


def leak_cases(world: dict, work: Path) -> dict[str, tuple[list[str], str]]:
    """One row per class of the leaks closed by mechanism: name -> (argv, words the one error line must contain)."""
    a, video = str(world["avatar"]), str(world["video"])
    frames = _png_folder(work / "frames")
    damaged = _png_folder(work / "damaged_frames")
    (damaged / "005.png").symlink_to(work / "nowhere.png")
    (damaged / "006.png").symlink_to(damaged / "006.png")
    (damaged / "007.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)
    (damaged / "notes.txt").write_text("not an image, not read\n")
    smplx = _rewrite_subject(world, work / "smplx_subject", lambda f: _set_poses(f, body="smplx"))
    bare = _rewrite_subject(world, work / "no_cameras", lambda f: (f / "cameras.npz").unlink())
    broken = _rewrite_subject(world, work / "broken_images", _break_two_images)
    return {
        "physical range: capture --focal 1e-300 (a 180-degree field of view on 32x32 frames)": (
            ["capture", video, "--out", str(work / "S"), "--focal", "1e-300", "--quiet"],
            "field of view of 180 degrees",
        ),
        "physical range: capture --focal 1e6 (a 0.002-degree field of view on 32x32 frames)": (
            ["capture", video, "--out", str(work / "S"), "--focal", "1e6", "--quiet"],
            "1 to 179 degrees",
        ),
        "output inside an input: capture FRAMES --out FRAMES/subject": (
            ["capture", str(frames), "--out", str(frames / "subject"), "--quiet"],
            "inside the input folder",
        ),
        "unreadable inputs: a frame folder with a dangling link, a link loop and a corrupt PNG": (
            ["capture", str(damaged), "--out", str(work / "S"), "--quiet"],
            "3 of its 6 image file(s) cannot be read (005.png, 006.png, 007.png)",
        ),
        "unreadable inputs: fit on a subject with a dangling image link and a corrupt PNG": (
            ["fit", str(broken), "--prior", "scratch", "--out", str(work / "a.pt"), "--no-lpips"],
            "2 file(s) of its 'train' images and masks cannot be opened",
        ),
        "value outside its domain: export of an avatar whose body.shape holds 1e6 (phenotypes: [0, 1])": (
            ["export", str(_avatar_with_shape(world, work / "tall.pt", 1e6)), "--out", str(work / "x.ply")],
            "'body.shape' holds 1e+06",
        ),
        "value outside its domain: render of an avatar whose body.shape holds -0.5": (
            ["render", str(_avatar_with_shape(world, work / "short.pt", -0.5)), "--out", str(work / "v.png")],
            "lie in [0, 1]",
        ),
        "checks that agree: eval of an anny avatar on a subject of the smplx body": (
            ["eval", a, str(smplx), "--report", str(work / "r.json"), "--strip", str(work / "r.png")],
            "poses of the 'smplx' body",
        ),
        "the file at fault: fit on a subject without cameras.npz": (
            ["fit", str(bare), "--prior", "scratch", "--out", str(work / "a.pt"), "--no-lpips"],
            "cameras.npz: missing",
        ),
        "cheap refusal first: render --size 1x1 to an MP4, of a corrupt avatar file (the size is refused first)": (
            ["render", str(_empty(work, "corrupt.pt")), "--size", "1x1", "--out", str(work / "v.mp4")],
            "even width and height",
        ),
    }


def test_each_leak_class_is_closed(world, tmp_path):
    (tmp_path / "work").mkdir()
    refuse_each("adversarial: leak classes", leak_cases(world, tmp_path / "work"), world, tmp_path)


SUBJECT_DAMAGE = {
    "an empty train split": (_empty_train, "splits.json: split 'train' is empty"),
    "an anny body shape of 2.0 (phenotypes: [0, 1])": (
        lambda folder: _set_poses(folder, shape=np.full(6, 2.0)),
        "poses.npz: 'shape' holds 2",
    ),
    "a frame_index of -1": (
        lambda folder: _set_camera(folder, "frame_index", (1,), -1),
        "'frame_index' must be in 0..999999 for image(s) 1",
    ),
    "a focal length of 1e-300 px (a 180-degree field of view)": (
        lambda folder: _set_camera(folder, "K", (2, 0, 0), 1e-300),
        "K's focal length is outside a field of view of 1 to 179 degrees for image(s) 2",
    ),
    "no cameras.npz": (lambda folder: (folder / "cameras.npz").unlink(), "cameras.npz: missing"),
}
"""Damage to a subject -> the problem data check lists and every reader names (one validator)."""


@pytest.mark.parametrize("damage", list(SUBJECT_DAMAGE))
def test_data_check_and_the_readers_run_one_validator(damage, world, tmp_path):
    change, words = SUBJECT_DAMAGE[damage]
    subject = _rewrite_subject(world, tmp_path / "subject", change)
    a = str(world["avatar"])
    checked = cli("data", "check", subject)
    readers = {
        "fit": ["fit", subject, "--prior", "scratch", "--out", tmp_path / "a.pt", "--no-lpips"],
        "eval": ["eval", a, subject, "--report", tmp_path / "r.json", "--strip", tmp_path / "r.png"],
        "data sheet": ["data", "sheet", subject, "--out", tmp_path / "sheet.png"],
    }
    failures = [] if checked.code == 2 and words in checked.stdout else [f"data check: exit {checked.code}"]
    for name, argv in readers.items():
        before = snapshot(tmp_path)
        ok, observed = holds_contract(cli(*argv, cwd=tmp_path), before, snapshot(tmp_path))
        if not ok or words not in observed:
            failures.append(f"{name}: {observed}")
    check(
        "adversarial: leak classes",
        f"a subject with {damage}: data check, fit, eval, data sheet",
        f"data check lists '{words}' (exit 2); each reader refuses with that line (exit 2, nothing written)",
        "; ".join(failures) if failures else "all four agree",
        not failures,
    )


# ---------------------------------------------------------------- commands not attacked before


def _synth_config(work: Path, name: str, text: str) -> str:
    path = work / name
    path.write_text(text)
    return str(path)


def unattacked_cases(world: dict, work: Path, tiny_dataset: Path) -> dict[str, tuple[list[str], str]]:
    """name -> (argv, words the one error line must contain), for synth, train-prior, bench, data sheet, motion make."""
    out = str(work / "out")
    listing_a_ghost = work / "ghost_dataset"
    listing_a_ghost.mkdir()
    (listing_a_ghost / "meta.json").write_text('{"format": "pghm-dataset", "subjects": ["subject_009"]}')
    empty_dataset = work / "empty_dataset"
    empty_dataset.mkdir()
    (empty_dataset / "meta.json").write_text('{"format": "pghm-dataset", "subjects": []}')
    no_cameras = Path(shutil.copytree(tiny_dataset, work / "dataset_without_cameras"))
    (no_cameras / "subject_001" / "cameras.npz").unlink()
    synth = ["synth", "--out", out, "--quiet", "--workers", "1", "--config"]
    prior = ["train-prior", "--out", str(work / "p.pt"), "--no-lpips", "--steps", "1", "--uv-resolution", "64"]
    return {
        "synth: a config of invalid JSON": ([*synth, _synth_config(work, "a.json", "{identities: 2")], "a.json"),
        "synth: a config that is a list": ([*synth, _synth_config(work, "b.json", "[1, 2]")], "JSON object"),
        "synth: an unknown field": ([*synth, _synth_config(work, "c.json", '{"idents": 2}')], "unknown field"),
        "synth: fps Infinity": ([*synth, _synth_config(work, "d.json", '{"fps": Infinity}')], "'fps' must be finite"),
        "synth: 1e9 identities": ([*synth, _synth_config(work, "e.json", '{"identities": 1e9}')], "1 to 10000"),
        "synth: camera_distance [1] (one number)": (
            [*synth, _synth_config(work, "f.json", '{"camera_distance": [1]}')],
            "two numbers",
        ),
        "synth: camera_distance of strings": (
            [*synth, _synth_config(work, "g.json", '{"camera_distance": ["a", "b"]}')],
            "two numbers",
        ),
        "synth: a camera 1e300 m away": (
            [*synth, _synth_config(work, "h.json", '{"camera_distance": [1, 1e300]}')],
            "h.json: camera_distance",
        ),
        "synth: width as a string": ([*synth, _synth_config(work, "i.json", '{"width": "64"}')], "must be a number"),
        "synth: a preset that does not exist": ([*synth, "huge"], "neither a preset"),
        "train-prior: a data set listing a missing subject": (
            [*prior[:1], str(listing_a_ghost), *prior[1:]],
            "subject_009",
        ),
        "train-prior: a data set listing no subjects": ([*prior[:1], str(empty_dataset), *prior[1:]], "no subjects"),
        "train-prior: a data set whose second subject lacks cameras.npz": (
            [*prior[:1], str(no_cameras), *prior[1:]],
            "subject_001/cameras.npz: missing",
        ),
        "train-prior: --resume without a checkpoint": (
            [*prior[:1], str(tiny_dataset), *prior[1:], "--resume"],
            "no checkpoint",
        ),
        "bench: an unknown benchmark": (["bench", "nosuch"], "unknown benchmark"),
        "bench: splat --plot p.txt (refused before the sweep)": (
            ["bench", "splat", "--out", out, "--plot", str(work / "p.txt"), *TINY_RUN["bench"]],
            "must end in",
        ),
        "data sheet: a folder that is neither a subject nor a data set": (
            ["data", "sheet", str(listing_a_ghost.parent / "out_of_nothing"), "--out", str(work / "s.png")],
            "out_of_nothing",
        ),
        "data sheet: --out sheet.jpg (a PNG under another name)": (
            ["data", "sheet", str(world["subject"]), "--out", str(work / "sheet.jpg")],
            "must end in .png",
        ),
        "data sheet: --mono of a missing folder": (
            ["data", "sheet", str(world["subject"]), "--out", str(work / "s.png"), "--mono", str(work / "gone")],
            "gone",
        ),
        "motion make: --body smplx without its model file": (
            ["motion", "make", "walk", "--body", "smplx", "--out", str(work / "m.npz")],
            "--body-model-path",
        ),
        "motion make: an unknown name": (["motion", "make", "moonwalk", "--out", str(work / "m.npz")], "moonwalk"),
    }


def test_commands_not_attacked_before(world, tiny_dataset, tmp_path):
    (tmp_path / "work").mkdir()
    cases = unattacked_cases(world, tmp_path / "work", tiny_dataset)
    refuse_each(lambda name: f"adversarial: {name.split(':')[0]}", cases, world, tmp_path)


TWO_WRITERS_CONFIG = (
    '{"identities": 1, "views": 1, "frames": 2, "test_frames": 1, "width": 16, "height": 16, "texture_size": 32}'
)
"""The smallest synthetic data set: two synth runs of it race for one output folder."""


def test_two_writers_of_one_folder_interleaved(tmp_path):
    """The mechanism the race below meets, made deterministic: both writers build, the first commits."""
    from pghm.errors import PghmError
    from pghm.io.outputs import staged_folder

    out = tmp_path / "data"
    first, second = staged_folder(out), staged_folder(out)
    building = [first.__enter__(), second.__enter__()]
    for k, folder in enumerate(building):
        (folder / "meta.json").write_text(f"writer {k}\n")
    first.__exit__(None, None, None)
    try:
        second.__exit__(None, None, None)
        observed = "the second commit was accepted"
    except PghmError as error:
        observed = str(error)
    left = sorted(p.name for p in tmp_path.iterdir())
    kept = (out / "meta.json").read_text() if (out / "meta.json").is_file() else None
    check(
        "adversarial: concurrent writers",
        "two staged writers of one output folder, interleaved (both build, then both commit)",
        "the first's folder kept whole; the second refused ('appeared while it was being built'), its staging removed",
        f"{observed}; kept: {kept!r}; left: {left}",
        "appeared while it was being built" in observed and kept == "writer 0\n" and left == ["data"],
    )


@pytest.mark.slow
def test_two_synth_runs_writing_one_output(tmp_path):
    import threading

    from stress_kit import _Server

    from pghm.subject import check as check_data

    config = _synth_config(tmp_path, "small.json", TWO_WRITERS_CONFIG)
    argv = ["synth", "--config", config, "--out", str(tmp_path / "data"), "--quiet", "--workers", "1"]
    servers = [_Server(), _Server()]
    results = [None, None]

    def run(k: int) -> None:
        results[k] = servers[k].run(argv, tmp_path, {})

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    try:
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    finally:
        for server in servers:
            server.close()
    codes = sorted(result.code for result in results)
    loser = next((result for result in results if result.code != 0), None)
    one_line = loser is not None and one_error_line(loser)[0]
    left = sorted(p.name for p in tmp_path.iterdir() if p.name not in ("data", "small.json"))
    problems = check_data(tmp_path / "data") if (tmp_path / "data").is_dir() else ["no output"]
    check(
        "adversarial: concurrent writers",
        "two pghm synth runs started at once on one --out",
        "one writes a valid data set (exit 0); the other exits 2 in one line; no staging folder left",
        f"exits {codes}; loser: {one_error_line(loser)[1] if loser else 'none'}; left: {left or 'nothing'}; "
        f"data check: {len(problems)} problem(s)",
        codes == [0, 2] and one_line and not left and not problems,
    )


# --------------------------------------------------------------------------------- SIGTERM


def test_sigterm_during_fit_leaves_a_resumable_checkpoint(world, tiny_prior, tmp_path):
    out = tmp_path / "a.pt"
    argv = [
        "fit", world["subject"], "--prior", tiny_prior, "--out", out, "--stage1-steps", "2", "--stage2-steps", "1",
        "--no-lpips", "--checkpoint-every", "1",
    ]  # fmt: skip
    stopped = cli(*argv, cwd=tmp_path, env={TEST_INTERRUPT_VARIABLE: "train-step:SIGTERM"})
    checkpoint = out.with_name(out.name + ".ckpt")
    after_stop = sorted(p.name for p in tmp_path.iterdir())
    resumed = cli(*argv, "--resume", cwd=tmp_path)
    left = sorted(p.name for p in tmp_path.iterdir())
    last = stopped.error_lines[-1] if stopped.error_lines else ""
    check(
        "adversarial: SIGTERM",
        "SIGTERM after fit's first step (test hook), then pghm fit --resume",
        "exit 143, last line 'pghm: terminated', only a.pt.ckpt left; the resumed run exits 0, a.pt alone left",
        f"exit {stopped.code}: {last}; left: {after_stop}; resumed: exit {resumed.code}, left: {left}",
        stopped.code == 128 + signal.SIGTERM
        and last == "pghm: terminated"
        and after_stop == [checkpoint.name]
        and resumed.code == 0
        and left == [out.name],
    )


# ------------------------------------------------- work lost, refusals that came late, pose tracks

PHASE_SIGNALS = {"early settling": "SIGINT", "held-out poses": "SIGTERM", "detail": "SIGINT"}
"""Each phase after a stage that once kept no checkpoint, and the signal sent once its work is done."""


@pytest.mark.parametrize("phase", list(PHASE_SIGNALS))
def test_a_signal_in_any_phase_of_a_fit_leaves_a_checkpoint_that_resumes(phase, world, tiny_prior, tmp_path):
    """The fit's own test hook (``fit PHASE``) signals it once the phase has run; the checkpoint of
    the stage before it is kept, named, and --resume finishes the fit (that the resumed avatar is
    the uninterrupted one bit for bit is tests/test_train.py's)."""
    signal_name = PHASE_SIGNALS[phase]
    out = tmp_path / "a.pt"
    argv = [
        "fit", world["subject"], "--prior", tiny_prior, "--out", out, "--no-lpips", "--stage1-steps", "1",
        "--stage2-steps", "1", "--early-track-steps", "1", "--held-out-steps", "1", "--detail-steps", "1",
        "--detail-validation", "0", "--checkpoint-every", "0",
    ]  # fmt: skip
    stopped = cli(*argv, cwd=tmp_path, env={TEST_INTERRUPT_VARIABLE: f"fit {phase}:{signal_name}"})
    checkpoint = out.with_name(out.name + ".ckpt")
    after_stop = sorted(p.name for p in tmp_path.iterdir())
    resumed = cli(*argv, "--resume", cwd=tmp_path)
    left = sorted(p.name for p in tmp_path.iterdir())
    named = any(f"interrupted in {phase}: checkpoint saved to {checkpoint}" in line for line in stopped.error_lines)
    code = 128 + signal.Signals[signal_name]
    check(
        "adversarial: interrupted phases",
        f"{signal_name} in the fit's {phase} (test hook), then pghm fit --resume",
        f"exit {code}, the checkpoint named, only a.pt.ckpt left; the resumed run exits 0, a.pt alone left",
        f"exit {stopped.code}, named: {named}; left: {after_stop}; resumed: exit {resumed.code}, left: {left}",
        stopped.code == code and named and after_stop == [checkpoint.name] and resumed.code == 0 and left == [out.name],
    )


def test_a_resume_from_a_diverged_checkpoint_is_refused(world, tiny_prior, tmp_path):
    """A checkpoint whose latent is NaN (a run that diverged before it was saved): --resume is one
    line naming the tensor, and no avatar is written from it."""
    import torch

    work = tmp_path / "work"
    work.mkdir()
    out = work / "a.pt"
    argv = [
        "fit", world["subject"], "--prior", tiny_prior, "--out", out, "--no-lpips", "--stage1-steps", "1",
        "--stage2-steps", "1", "--early-track-steps", "1", "--held-out-steps", "1", "--detail-steps", "0",
        "--checkpoint-every", "0",
    ]  # fmt: skip
    cli(*argv, cwd=tmp_path, env={TEST_INTERRUPT_VARIABLE: "fit early settling:SIGINT"})
    checkpoint = out.with_name(out.name + ".ckpt")
    payload = torch.load(checkpoint, weights_only=True)
    payload["objective"]["latent"].fill_(float("nan"))
    torch.save(payload, checkpoint)
    cases = {"fit --resume from a checkpoint whose latent is NaN": ([*map(str, argv), "--resume"], "non-finite values")}
    refuse_each("adversarial: interrupted phases", cases, world, tmp_path)


def test_a_lens_whose_crop_the_checker_refuses_is_refused_before_the_images(world, tmp_path):
    """capture --fov 1 (inside the option's range) on the real video's frames: the person's crop
    would see less than the subject checker's 1 degree, so capture refuses it before writing."""
    from capture_videos import real_frames, require_mediapipe

    require_mediapipe()
    clip = write_video(tmp_path / "clip.mp4", real_frames(10))
    (tmp_path / "work").mkdir()
    argv = ["capture", str(clip), "--out", str(tmp_path / "work" / "me"), "--fov", "1", "--quiet"]
    cases = {"capture --fov 1: a crop the subject checker would refuse": (argv, "give --fov")}
    refuse_each("adversarial: late refusals", cases, world, tmp_path)


def _twice_the_size(folder: Path) -> None:
    """Image 1 (and its mask) at twice the others' size, its camera scaled to match: consistent
    alone, but a subject of two sizes."""
    from PIL import Image

    for kind in ("images", "masks"):
        path = folder / kind / "000001.png"
        if path.exists():
            image = Image.open(path)
            image.resize((2 * image.width, 2 * image.height), Image.NEAREST).save(path)
    with np.load(folder / "cameras.npz", allow_pickle=False) as data:
        cameras = {key: data[key].copy() for key in data.files}
    cameras["K"][1, :2] *= 2
    cameras["width"][1] *= 2
    cameras["height"][1] *= 2
    (folder / "cameras.npz").write_bytes(npz_bytes(cameras))


def _avatar_with_track(world: dict, path: Path, **absurd: float) -> Path:
    """The world's avatar with a pose track whose fields in ``absurd`` hold that value throughout."""
    import torch

    payload = torch.load(world["avatar"], weights_only=True)
    track = {
        "frames": torch.tensor([0, 1]),
        "bones": torch.tensor([0, 1]),
        "rotations": torch.zeros(2, 2, 3),
        "translation": torch.zeros(2, 3),
        "poses": "0" * 64,
    }
    payload["pose_track"] = {**track, **{k: torch.full_like(track[k], v) for k, v in absurd.items()}}
    torch.save(payload, path)
    return path


def test_what_can_be_refused_before_the_work_is(world, tiny_prior, tiny_dataset, tmp_path):
    """Option combinations, a subject of two image sizes, more identities than the data hold, and
    avatar files whose pose track is absurd: one line before any step (refuse_each)."""
    work = tmp_path / "work"
    work.mkdir()
    fit = ["fit", str(world["subject"]), "--prior", str(tiny_prior), "--out", str(work / "a.pt"), "--no-lpips"]
    two_sizes = _rewrite_subject(world, work / "two_sizes", _twice_the_size)
    huge_translation = _avatar_with_track(world, work / "far.pt", translation=1e20)
    huge_rotation = _avatar_with_track(world, work / "spun.pt", rotations=1e20)
    cases = {
        "fit --uv-resolution 1024: a detail layer past the largest atlas, before stage 1": (
            [*fit, "--uv-resolution", "1024", "--detail-validation", "0"],
            "a detail layer needs 2L <= 1024",
        ),
        "fit on a subject whose image 1 is twice the others' size (its camera scaled to match)": (
            ["fit", str(two_sizes), "--prior", str(tiny_prior), "--out", str(work / "b.pt"), "--no-lpips"],
            "a subject's images must all have one size",
        ),
        "train-prior --identities 99 on a data set of two": (
            ["train-prior", str(tiny_dataset), "--out", str(work / "p.pt"), "--identities", "99", "--no-lpips"],
            "the data set holds 2",
        ),
        "eval --fit-poses of an avatar whose pose track translates by 1e20 m": (
            ["eval", str(huge_translation), str(world["subject"]), "--fit-poses", "--report", str(work / "r.json")],
            "pose_track.translation' has values",
        ),
        "export of an avatar whose pose track rotates by 1e20 rad": (
            ["export", str(huge_rotation), "--out", str(work / "x.ply")],
            "pose_track.rotations' has values beyond",
        ),
    }
    refuse_each("adversarial: late refusals", cases, world, tmp_path)
