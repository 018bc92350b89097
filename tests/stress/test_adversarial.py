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
    """Every file under ``folder`` (hidden ones included) -> sha256 of its bytes ('dir' for folders)."""
    found = {}
    for path in sorted(folder.rglob("*")):
        key = str(path.relative_to(folder))
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


def bad_outputs(output: tuple[str, str], work: Path, an_input: Path | None) -> dict[str, str]:
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
    failures, passed = [], 0
    for name, value in bad_outputs((path[0], dest), tmp_path, an_input).items():
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
        f"pghm {' '.join(path)} {option}: unwritable, folder/file, under a file, /dev/full, the input, a symlink to it",
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


def test_bad_file_contents_are_refused_at_the_loader(world, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    for name, (argv, words) in file_cases(world, work).items():
        before = snapshot(work)
        result = cli(*argv, cwd=tmp_path)
        ok, observed = holds_contract(result, before, snapshot(work))
        check(
            "adversarial: file contents",
            name,
            f"exit 2, one line naming the file and '{words}', nothing written",
            observed,
            ok and words in result.stderr,
        )


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


# ---------------------------------------------------------------------------------- Ctrl-C


@pytest.mark.parametrize(
    "point,argv",
    [
        ("startup", ["motion", "make", "walk", "--out", "m.npz"]),
        ("render-frame", ["render", "AVATAR", "--frames", "3", "--out", "frames", "--backend", "cpu", "--size", "8x6"]),
        ("synth-subjects", ["synth", "--out", "data", "--workers", "1", "--quiet"]),
    ],
)
def test_ctrl_c_leaves_nothing(point, argv, world, tmp_path):
    argv = [str(world["avatar"]) if a == "AVATAR" else a for a in argv]
    result = cli(*argv, cwd=tmp_path, env={TEST_INTERRUPT_VARIABLE: point})
    lines = [line for line in result.error_lines if "Loading cached" not in line]
    left = sorted(p.name for p in tmp_path.iterdir())
    check(
        "adversarial: Ctrl-C",
        f"SIGINT at '{point}' (test hook): pghm {' '.join(argv[:2])} ...",
        "exit 130, one line 'pghm: interrupted', no traceback, no file or folder left (staged outputs removed)",
        f"exit {result.code}: {' | '.join(lines)[-160:]}; left: {left or 'nothing'}",
        result.code == 128 + signal.SIGINT and lines == ["pghm: interrupted"] and not left,
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
