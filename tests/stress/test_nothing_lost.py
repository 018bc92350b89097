"""Nothing lost: every save is atomic, and kill -9 at any moment leaves the last complete file.

1. Every writer of pghm and the viewer, run under a spy on ``open``/``os.open``/``os.fsync``/
   ``os.replace``: the destination is never opened for writing, only a hidden temporary beside
   it, which is fsynced and then renamed over it. A static scan of pghm/ and viewer/ finds no
   other write call.
2. A child process saves two versions of an avatar, a 50 MB .ply, a PNG and a motion file
   over and over; it is killed with SIGKILL while it overwrites one of them, in each state a
   save can be interrupted in (temporary file created, written, renamed). Every file must
   then load and equal the old or the new version, never a mix, and the one being saved must
   hold exactly the version that state implies.
3. ``pghm train-prior`` and ``pghm fit`` (real subprocesses, tiny data set, 64 x 64 UV maps,
   a checkpoint every step) are killed with SIGKILL between two checkpoint saves and in the
   middle of one; the checkpoint on disk loads at exactly the step the kill point implies,
   and ``--resume`` finishes the run with the parameters an uninterrupted run reaches.

Every kill lands at a point the test chooses, on any machine at any load: the writer's
fault-injection hook (``PGHM_TEST_PAUSE_SAVE``, :mod:`pghm._fault_injection`) makes the child create
a marker file and sleep at the chosen point of the chosen save, and the test kills it once
the marker exists. Nothing here waits for a moment it hopes to catch.
"""

from __future__ import annotations

import ast
import builtins
import contextlib
import io
import os
import signal
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import SMALL_MODEL
from stress_kit import HERE, ROOT, check, output_versions

# ------------------------------------------------------------------ 1. writers are atomic


class WriteSpy:
    """Records every path opened for writing, every fsync and every rename, through the real functions."""

    def __init__(self, monkeypatch) -> None:
        self.opened: list[Path] = []
        self.synced: list[Path] = []
        self.renames: list[tuple[Path, Path, int]] = []
        """(source, destination, how many fsyncs came before the rename)."""
        self.descriptors: dict[int, Path] = {}
        real_open, real_os_open, real_replace, real_fsync = builtins.open, os.open, os.replace, os.fsync

        def spy_open(file, mode="r", *args, **kwargs):
            if isinstance(file, (str, bytes, os.PathLike)) and any(flag in mode for flag in "wax+"):
                self.opened.append(Path(os.fsdecode(file)))
            return real_open(file, mode, *args, **kwargs)

        def spy_os_open(path, flags, *args, **kwargs):
            if flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC):
                self.opened.append(Path(os.fsdecode(path)))
            fd = real_os_open(path, flags, *args, **kwargs)
            self.descriptors[fd] = Path(os.fsdecode(path))
            return fd

        def spy_fsync(fd):
            if fd in self.descriptors:
                self.synced.append(self.descriptors[fd])
            return real_fsync(fd)

        def spy_replace(source, destination, *args, **kwargs):
            self.renames.append((Path(os.fsdecode(source)), Path(os.fsdecode(destination)), len(self.synced)))
            return real_replace(source, destination, *args, **kwargs)

        monkeypatch.setattr(builtins, "open", spy_open)
        monkeypatch.setattr(io, "open", spy_open)
        monkeypatch.setattr(os, "open", spy_os_open)
        monkeypatch.setattr(os, "fsync", spy_fsync)
        monkeypatch.setattr(os, "replace", spy_replace)

    def _final(self, path: Path) -> Path:
        """Where ``path`` ended up: a file renamed into a staged folder moves with the folder's rename."""
        for source, destination, _ in self.renames:
            if path != source and path.is_relative_to(source):
                return destination / path.relative_to(source)
        return path

    def _synced_before_rename(self, output: Path) -> bool:
        """Whether the file renamed to ``output`` was fsynced before that rename (else a crash
        right after the rename could leave an empty or partial file under the final name)."""
        return any(
            self._final(destination).resolve() == output.resolve()
            and source.resolve() in {p.resolve() for p in self.synced[:synced_before]}
            for source, destination, synced_before in self.renames
        )

    def verdict(self, outputs: list[Path], root: Path) -> tuple[bool, str]:
        """Whether ``outputs`` were written atomically and nothing under ``root`` was written in place
        (files elsewhere, such as the native kernel's build lock, are not outputs)."""
        direct = [p for p in self.opened if p.resolve() in {o.resolve() for o in outputs}]
        inside = [p for p in self.opened if p.resolve().is_relative_to(root.resolve())]
        not_temporary = [p for p in inside if not (p.name.startswith(".") and ".tmp" in p.name)]
        missing = [o for o in outputs if not o.is_file()]
        renamed = {self._final(destination).resolve() for _, destination, _ in self.renames}
        unrenamed = [o for o in outputs if o.resolve() not in renamed]
        unsynced = [o for o in outputs if not self._synced_before_rename(o)]
        ok = not (direct or not_temporary or missing or unrenamed or unsynced)
        if ok:
            return True, f"{len(outputs)} file(s), each written to a .tmp sibling, fsynced, then renamed"
        return (
            False,
            f"direct writes {direct}, non-temporary {not_temporary}, missing {missing}, not renamed {unrenamed}, "
            f"not fsynced before the rename {unsynced}",
        )


def _writers(tmp: Path, tiny_dataset: Path) -> dict[str, tuple[callable, list[Path]]]:
    """Writer name -> (run it into ``tmp``, the files it must produce)."""
    from benchmarks.splat_measure import write_json
    from pghm.body import load_body
    from pghm.io.atomic import save_figure
    from pghm.io.avatar import save_avatar
    from pghm.io.ply import write_ply
    from pghm.motion.motion import Motion
    from pghm.render import PngFileSink, PngSequenceSink
    from pghm.subject import Subject, write_dataset_meta, write_image, write_subject
    from pghm.synth.sheet import contact_sheet
    from pghm.train.evaluate import evaluate
    from pghm.train.loop import LoopState, save_checkpoint
    from viewer.demo import development_avatar
    from viewer.recording import save_png

    body = load_body()
    avatar = development_avatar(SMALL_MODEL, seed=2)
    subject = Subject.open(tiny_dataset / "subject_000")
    image = np.full((16, 16, 3), 128, np.uint8)

    def checkpoint(path):
        module = torch.nn.Linear(3, 2)
        save_checkpoint(path, module, torch.optim.Adam(module.parameters()), LoopState(), {"stage": 1})

    def eval_report(report, strip):
        import pghm.train.evaluate as evaluate_module

        real, evaluate_module.load_lpips = evaluate_module.load_lpips, lambda: None  # its weights take 15 s to load
        try:
            evaluate(avatar, tiny_dataset / "subject_000", report, strip)
        finally:
            evaluate_module.load_lpips = real

    def atlas_cache(directory):
        import pghm.uv.atlas as atlas_module

        os.environ["PGHM_CACHE_DIR"] = str(directory)
        saved = dict(atlas_module._MEMORY_CACHE)
        atlas_module._MEMORY_CACHE.clear()
        try:
            atlas_module.build_atlas(body, 32)
        finally:
            atlas_module._MEMORY_CACHE.update(saved)
            del os.environ["PGHM_CACHE_DIR"]

    def figure(path):
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=(1, 1))
        save_figure(fig, path)
        plt.close(fig)

    motion = Motion(np.zeros((2, body.num_bones, 3)), np.zeros((2, 3)), 30.0, "anny", list(body.bone_names))
    atlas_dir = tmp / "cache"
    return {
        "avatar file (save_avatar)": (lambda: save_avatar(tmp / "a.pt", avatar), [tmp / "a.pt"]),
        "training checkpoint": (lambda: checkpoint(tmp / "c.ckpt"), [tmp / "c.ckpt"]),
        "motion .npz": (lambda: motion.save(tmp / "m.npz"), [tmp / "m.npz"]),
        ".ply export": (
            lambda: write_ply(tmp / "g.ply", torch.zeros(4, 3), torch.ones(4), torch.zeros(4, 3), torch.ones(4)),
            [tmp / "g.ply"],
        ),
        "subject cameras, poses, splits, meta": (
            lambda: write_subject(tmp / "s", subject.arrays, {"source": "stress"}),
            [tmp / "s" / name for name in ("cameras.npz", "poses.npz", "splits.json", "meta.json")],
        ),
        "subject image and mask PNGs": (
            lambda: write_image(tmp / "s", 0, image, image[..., 0]),
            [tmp / "s" / "images" / "000000.png", tmp / "s" / "masks" / "000000.png"],
        ),
        "dataset meta.json": (lambda: write_dataset_meta(tmp / "d", ["s"], {}), [tmp / "d" / "meta.json"]),
        "eval report and strip": (lambda: eval_report(tmp / "r.json", tmp / "r.png"), [tmp / "r.json", tmp / "r.png"]),
        "render: one PNG": (lambda: PngFileSink(tmp / "f.png").write(image), [tmp / "f.png"]),
        "render: PNG sequence": (
            lambda: [sink := PngSequenceSink(tmp / "seq"), sink.write(image), sink.close()],
            [tmp / "seq" / "frame_00000.png"],
        ),
        "viewer screenshot": (lambda: save_png(tmp / "shot.png", image), [tmp / "shot.png"]),
        "plots (motion preview, benchmarks)": (lambda: figure(tmp / "plot.png"), [tmp / "plot.png"]),
        "contact sheet": (lambda: contact_sheet(tiny_dataset, tmp / "sheet.png", tile=32), [tmp / "sheet.png"]),
        "benchmark JSON": (lambda: write_json(tmp / "bench.json", {"rows": []}), [tmp / "bench.json"]),
        "UV atlas cache": (lambda: atlas_cache(atlas_dir), []),  # its name ends with a format version: globbed
    }


def test_every_writer_goes_through_a_temporary_file(tiny_dataset, tmp_path, monkeypatch):
    writers = _writers(tmp_path, tiny_dataset)
    for name, (write, outputs) in writers.items():
        with monkeypatch.context() as patch:
            spy = WriteSpy(patch)
            write()
        if name == "UV atlas cache":  # the file name ends with the format version: find it
            outputs = sorted((tmp_path / "cache" / "atlas").glob("*.npz"))
        ok, observed = spy.verdict(outputs, tmp_path)
        check(
            "nothing lost",
            f"atomic save: {name}",
            "temporary file + fsync + rename, destination never opened",
            observed,
            ok and bool(outputs),
        )
    leftovers = sorted(p.name for p in tmp_path.rglob(".*.tmp*"))
    check(
        "nothing lost",
        "no temporary files left after successful saves",
        "none",
        f"{len(leftovers)} left",
        not leftovers,
    )


def test_an_mp4_is_finished_before_it_replaces_the_old_one(tmp_path, monkeypatch):
    """The encoder writes a temporary file itself (PendingFile), so the spy sees the commit only."""
    import imageio_ffmpeg

    from pghm.render import Mp4Sink

    path = tmp_path / "video.mp4"
    path.write_bytes(b"the old video")
    frame = np.zeros((16, 16, 3), np.uint8)
    aborted = Mp4Sink(path, 30.0)
    aborted.write(frame)
    during = path.read_bytes()
    aborted.abort()
    kept = path.read_bytes() == b"the old video" == during
    finished = Mp4Sink(path, 30.0)
    for _ in range(3):
        finished.write(frame)
    before_close = path.read_bytes()
    with monkeypatch.context() as patch:
        spy = WriteSpy(patch)
        finished.close()
    committed, commit = spy.verdict([path], tmp_path)
    reader = imageio_ffmpeg.read_frames(str(path))
    next(reader)
    frames = sum(1 for _ in reader)
    leftovers = list(tmp_path.glob(".*"))
    check(
        "nothing lost",
        "render MP4 over an existing file",
        "old file untouched while encoding and on abort; a complete video after close, fsynced before its rename",
        f"old kept: {kept and before_close == b'the old video'}, "
        f"new video frames: {frames}, temporaries left: {len(leftovers)}; commit: {commit}",
        kept and before_close == b"the old video" and frames == 3 and not leftovers and committed,
    )


WRITE_CALLS = {
    "write_bytes",
    "write_text",
    "savefig",
    "save",
    "savez",
    "savez_compressed",
    "tofile",
    "imwrite",
    "write_frames",
    "to_csv",
    "dump",
}
"""Calls that write a file when given a path (attribute names)."""
IN_MEMORY = {"buffer", "member", "file"}
"""First arguments that are in-memory buffers or already-open temporary files."""
ATOMIC_BY_CONSTRUCTION = {
    ("pghm/cli/motion.py", "motion.save"),  # Motion.save: atomic_write_bytes (checked above)
    ("pghm/render/sinks.py", "imageio_ffmpeg.write_frames"),  # into a PendingFile's temporary path
    ("pghm/synth/video.py", "imageio_ffmpeg.write_frames"),  # into atomic_path's temporary path
    # pghm.io.atomic.Outputs (all_or_none): fsynced temporaries, renamed together.
    ("pghm/cli/train.py", "outputs.write_bytes"),
    ("pghm/train/evaluate.py", "outputs.write_bytes"),
}


def _write_calls(path: Path) -> list[str]:
    """'file:line call' for each call in ``path`` that could write a file other than atomically."""
    relative = path.relative_to(ROOT).as_posix()
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.Call):
            continue
        function = node.func
        target_position = 1 if ast.unparse(function) in ("torch.save", "json.dump", "pickle.dump") else 0
        first = node.args[target_position] if len(node.args) > target_position else None
        first_text = ast.unparse(first) if first is not None else ""
        if isinstance(function, ast.Name) and function.id == "open":
            mode = (
                node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
            )
            if isinstance(mode, ast.Constant) and isinstance(mode.value, str) and set(mode.value) & set("wax+"):
                found.append(f"{relative}:{node.lineno} open({first_text}, {mode.value!r})")
        elif isinstance(function, ast.Attribute) and function.attr in WRITE_CALLS:
            name = ast.unparse(function)
            if (
                first_text in IN_MEMORY
                or first_text.startswith("io.BytesIO")
                or (relative, name) in ATOMIC_BY_CONSTRUCTION
            ):
                continue
            if function.attr == "save" and first is None:
                continue
            found.append(f"{relative}:{node.lineno} {name}({first_text})")
    return found


def test_no_other_write_calls_in_pghm_and_the_viewer():
    files = [p for folder in ("pghm", "viewer") for p in sorted((ROOT / folder).rglob("*.py"))]
    found = [call for path in files if path.name != "atomic.py" for call in _write_calls(path)]
    check(
        "nothing lost",
        f"static audit of every write call in pghm/ and viewer/ ({len(files)} files)",
        "all through pghm.io.atomic",
        "none other" if not found else "; ".join(found),
        not found,
    )


# ------------------------------------------------------------- 2. kill -9 during a save

SAVE_POINTS = ("created", "written", "renamed")
"""The states of a save a kill can interrupt (:func:`pghm._fault_injection.save_point`)."""
VERSION_AFTER_KILL = {"created": 0, "written": 0, "renamed": 1}
"""The version a file holds when its save of version 1 over version 0 is killed at each point."""
STALE_AFTER_KILL = {"created": 1, "written": 1, "renamed": 0}
"""Temporary files a kill at each point leaves beside the destination."""
SAFETY_TIMEOUT = 600
"""Seconds after which a child that neither paused nor ended is a hung test; never part of a verdict."""


@dataclass
class Kill:
    landed: bool
    """The child paused at the chosen point and SIGKILL ended it there (exit status -SIGKILL)."""
    description: str


def _kill_at(command: list[str], point: str, count: int, name: str, marker: Path, **popen) -> Kill:
    """Run ``command`` with the save hook set to pause at the ``count``-th ``point`` of a save to a
    file named ``name``, and SIGKILL it once it has paused there."""
    from pghm._fault_injection import PAUSE_MARKER_VARIABLE, PAUSE_VARIABLE

    marker.unlink(missing_ok=True)
    env = dict(os.environ, **{PAUSE_VARIABLE: f"{point}:{count}:{name}", PAUSE_MARKER_VARIABLE: str(marker)})
    process = subprocess.Popen(command, env=env, **popen)
    try:
        for _ in range(int(SAFETY_TIMEOUT / 0.01)):
            if marker.exists() or process.poll() is not None:
                break
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(timeout=0.01)
        paused = marker.exists()
        if paused:
            process.send_signal(signal.SIGKILL)
    finally:
        process.kill()
        process.wait()
    landed = paused and process.returncode == -signal.SIGKILL
    where = f"save #{count} of {name}, {point}"
    if landed:
        return Kill(True, f"killed (exit {process.returncode}) at {where}")
    return Kill(False, f"NO KILL at {where}: the child never paused there (exit {process.returncode})")


@pytest.mark.parametrize("point", SAVE_POINTS)
@pytest.mark.parametrize("target", ["avatar.pt", "gaussians.ply"])
def test_kill_during_a_save_over_an_existing_file(target, point, tmp_path):
    versions = [output_versions(0), output_versions(1)]
    out = tmp_path / "out"
    out.mkdir()
    # Save 1 of each file creates version 0 (save_loop's first round); save 2 overwrites it with version 1.
    kill = _kill_at(
        [sys.executable, str(HERE / "save_loop.py"), str(out)],
        point,
        2,
        target,
        tmp_path / "paused",
        stdout=subprocess.DEVNULL,
    )
    temporaries = [p.name for p in out.iterdir() if p.name.startswith(f".{target}.")]
    outcomes = []
    intact = True
    for name in versions[0]:
        path = out / name
        try:
            which = [index for index, version in enumerate(versions) if version[name][1](path)]
        except Exception as error:  # noqa: BLE001 - a damaged file: report what reading it raised
            which, intact = [], False
            outcomes.append(f"{name}: UNREADABLE ({type(error).__name__})")
            continue
        expected = [VERSION_AFTER_KILL[point]] if name == target else [0, 1]
        intact &= len(which) == 1 and which[0] in expected
        outcomes.append(f"{name}: version {which[0] if which else '?'}")
    check(
        "nothing lost",
        f"kill -9 while {target} is being saved over the old one: temporary file {point}",
        f"every file loads and equals the old or the new version; {target} is version "
        f"{VERSION_AFTER_KILL[point]}, {STALE_AFTER_KILL[point]} stale temporary file",
        f"{kill.description}; {len(temporaries)} stale temporary file; " + ", ".join(outcomes),
        kill.landed and intact and len(temporaries) == STALE_AFTER_KILL[point],
    )


# --------------------------------------------------------- 3. kill -9 during training


PRIOR_ARGS = [
    "--uv-resolution",
    "64",
    "--latent-channels",
    "8",
    "--images",
    "2",
    "--no-lpips",
    "--checkpoint-every",
    "1",
]
PRIOR_STEPS = 4
FIT_STAGES = (1, 2)


def _command(*args) -> list[str]:
    return [sys.executable, "-m", "pghm.cli.main", *map(str, args)]


def _same_parameters(a: dict, b: dict) -> float:
    """Largest absolute difference between two state dicts (inf if their keys differ)."""
    if a.keys() != b.keys():
        return float("inf")
    return max(float((a[k].float() - b[k].float()).abs().max()) if a[k].numel() else 0.0 for k in a)


RESUME_TOLERANCE = 1e-5
"""Resumed against uninterrupted parameters: the same batches, optimizer state and learning-rate
scale, so equal up to float reassociation in threaded kernels (test_train's resume test holds
1e-6 on 6 steps of a smaller model; this one is larger, 1e-5 leaves room)."""


def _stale(checkpoint: Path) -> int:
    """How many temporary files of ``checkpoint`` lie beside it (left by a kill mid-save)."""
    return sum(1 for p in checkpoint.parent.iterdir() if p.name.startswith(f".{checkpoint.name}."))


def _kill_training(command, checkpoint: Path, point: str, count: int, marker: Path) -> tuple[Kill, dict]:
    """Kill a training run at the ``count``-th checkpoint save's ``point``; (the kill, the checkpoint then on disk)."""
    from pghm.train.loop import load_checkpoint

    kill = _kill_at(
        command, point, count, checkpoint.name, marker, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    return kill, load_checkpoint(checkpoint)  # must load: the last complete checkpoint


@pytest.fixture(scope="module")
def prior_run(tiny_dataset, tmp_path_factory):
    """train-prior killed between saves (after its 2nd checkpoint), then resumed and killed mid-save
    (its first checkpoint written, not renamed), then resumed to the end."""
    from pghm.io.avatar import load_avatar

    folder = tmp_path_factory.mktemp("killed_prior")
    out = folder / "prior.pt"
    checkpoint = out.with_name(out.name + ".ckpt")
    base = _command("train-prior", tiny_dataset, "--out", out, "--steps", PRIOR_STEPS, *PRIOR_ARGS)
    between, after_between = _kill_training(base, checkpoint, "renamed", 2, folder / "paused")
    stale_between = _stale(checkpoint)
    mid_save, after_mid_save = _kill_training(base + ["--resume"], checkpoint, "written", 1, folder / "paused")
    stale_mid_save = _stale(checkpoint)
    steps = (after_between["state"]["step"], after_mid_save["state"]["step"])
    events = [
        f"between saves: {between.description}: checkpoint loads at step {steps[0]}, {stale_between} stale file",
        f"mid-save after --resume: {mid_save.description}: checkpoint loads at step {steps[1]}, "
        f"{stale_mid_save} stale file (the step-3 save never renamed)",
    ]
    # Step 2's checkpoint stays the last complete one through both kills; only the mid-save kill leaves a temporary.
    landed = between.landed and mid_save.landed and steps == (2, 2) and (stale_between, stale_mid_save) == (0, 1)
    resumed = subprocess.run(base + ["--resume"], capture_output=True, text=True, timeout=SAFETY_TIMEOUT)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    return out, landed, events, load_avatar(out)


def test_kill_9_during_train_prior_then_resume(prior_run, tiny_dataset, tmp_path):
    from pghm.model import ModelConfig
    from pghm.train.prior import PriorConfig, train_prior

    out, landed, events, resumed = prior_run
    config = PriorConfig(  # what the command line above asks for, on the command's defaults
        model=ModelConfig(uv_resolution=64, latent_channels=8),
        loop=replace(PriorConfig().loop, steps=PRIOR_STEPS, images_per_shard=2, checkpoint_every=0),
        lpips=False,
    )
    straight = train_prior(tiny_dataset, tmp_path / "straight.pt", config)
    difference = _same_parameters(straight.model.state_dict(), resumed.model.state_dict())
    check(
        "nothing lost",
        "kill -9 during pghm train-prior, between saves and mid-save, then --resume",
        f"each kill lands where chosen; the step-2 checkpoint loads after both; resumed run ends at step "
        f"{PRIOR_STEPS} with the uninterrupted run's parameters (max diff <= {RESUME_TOLERANCE:g})",
        "; ".join(events) + f"; resumed to step {resumed.metadata['steps']}, max parameter diff {difference:.1e}",
        landed and resumed.metadata["steps"] == PRIOR_STEPS and difference <= RESUME_TOLERANCE,
    )


def test_kill_9_during_fit_then_resume(prior_run, tiny_dataset, tmp_path):
    from pghm.io.avatar import load_avatar
    from pghm.train.fit import FitConfig, fit

    prior, _, _, _ = prior_run
    subject = tiny_dataset / "subject_000"
    out = tmp_path / "avatar.pt"
    checkpoint = out.with_name(out.name + ".ckpt")
    base = _command(
        "fit",
        subject,
        "--prior",
        prior,
        "--out",
        out,
        "--stage1-steps",
        FIT_STAGES[0],
        "--stage2-steps",
        FIT_STAGES[1],
        "--no-lpips",
        "--checkpoint-every",
        "1",
    )
    # The 2nd checkpoint save is stage 2's first step: the kill falls between the stages' saves.
    kill, payload = _kill_training(base, checkpoint, "renamed", 2, tmp_path / "paused")
    where = (payload["extra"]["stage"], payload["state"]["step"])
    event = f"{kill.description}: checkpoint loads (stage {where[0]}, step {where[1]})"
    resumed = subprocess.run(base + ["--resume"], capture_output=True, text=True, timeout=SAFETY_TIMEOUT)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    avatar = load_avatar(out)
    defaults = FitConfig()  # what the command line above asks for, on the command's defaults
    config = FitConfig(
        stage1=replace(defaults.stage1, steps=FIT_STAGES[0], images_per_shard=2, checkpoint_every=0),
        stage2=replace(defaults.stage2, steps=FIT_STAGES[1], images_per_shard=2, checkpoint_every=0),
        lpips=False,
    )
    straight = fit(subject, prior, tmp_path / "straight.pt", config)
    difference = max(
        _same_parameters(straight.model.state_dict(), avatar.model.state_dict()),
        float((straight.latent - avatar.latent).abs().max()),
    )
    check(
        "nothing lost",
        "kill -9 during pghm fit between stage 2's saves, then --resume",
        f"the kill lands where chosen; the checkpoint loads at stage 2, step 1; resumed avatar equals an "
        f"uninterrupted fit (max diff <= {RESUME_TOLERANCE:g})",
        f"{event}; max parameter diff {difference:.1e}",
        kill.landed and where == (2, 1) and difference <= RESUME_TOLERANCE,
    )
