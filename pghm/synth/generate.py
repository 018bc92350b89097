"""``pghm synth``: plan every subject, render the images on all cores, write the dataset.

Two stages, both inside each render task (one subject, or a chunk of its time steps):

1. Planning (~1 s): from the subject's own seed, an identity, a light, a motion, cameras,
   the estimator's pose noise and the splits. Subject i's random numbers come from
   ``SeedSequence(seed, spawn_key=(i,))``, so a subject does not change when others are
   added, and nothing depends on how the work is scheduled. Tasks of the same subject
   repeat the (deterministic) planning instead of waiting for each other.
2. Rendering (the cost): paint the identity and render the task's images with the exact
   poses, writing PNGs. An image's bytes depend only on its own inputs, so any number of
   workers gives the same files. The calling process writes the metadata at the end.

Worker processes are started with "spawn" (a fresh interpreter: no inherited GL or
thread state) and run torch and llvmpipe on one thread each, so two workers use the two
cores without oversubscribing them.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import signal
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from pghm._fault_injection import interrupt_point
from pghm.body import BodyModel, load_body
from pghm.errors import PghmError
from pghm.io.outputs import staged_folder
from pghm.subject import SubjectArrays, write_dataset_meta, write_image, write_subject
from pghm.synth import cameras as rigs
from pghm.synth.avatar import build_clothed_body, pose_clothed_body, shaped_body
from pghm.synth.cloth import wrinkle_amplitudes
from pghm.synth.config import SynthConfig
from pghm.synth.identity import Identity, sample_identity
from pghm.synth.poses import MOTION_KINDS, WALK_SPEED, add_pose_noise, motion_clip, place_on_path
from pghm.synth.regions import Landmarks
from pghm.synth.render import Lighting, MeshRenderer, RenderedView

GENERATOR_VERSION = "1.1"
"""Bumped whenever the same config and seed would give different bytes."""

POSE_BATCH = 32
"""Frames posed per LBS batch (bounds memory: 32 x V x 3 float64 ~ 10 MB)."""

NOVEL_POSE_KINDS = ("arm_raises", "squat", "dance")
"""Monocular: motions the held-out novel-pose frames are drawn from."""

ARM_REACH = 0.5
"""Metres the hands reach above the crown with the arms overhead (multi-view framing)."""

MONO_HEIGHT_MARGIN = 1.15
"""Monocular framing: image height over the body's height at the circle's near side."""

MONO_WIDTH_MARGIN = 1.2
"""Monocular framing: metres added to the circle's diameter (arms, body width)."""


@dataclass(frozen=True)
class SubjectPlan:
    """Everything needed to render and write one subject.

    Attributes:
        name: folder name.
        index: subject number (its seed's spawn key).
        identity: the person.
        lighting: the light.
        arrays: cameras, noisy and exact poses, splits (what goes to disk).
        motion_sources: provenance of each motion clip.
    """

    name: str
    index: int
    identity: Identity
    lighting: Lighting
    arrays: SubjectArrays
    motion_sources: list[str]


@dataclass(frozen=True)
class GenerationReport:
    """What :func:`generate` did.

    Attributes:
        out: the dataset folder.
        subjects: subject folder names.
        images: images written.
        seconds: wall time.
        workers: processes that rendered.
    """

    out: Path
    subjects: list[str]
    images: int
    seconds: float
    workers: int


def _rngs(seed: int, index: int, streams: int) -> list[np.random.Generator]:
    """Independent generators of subject ``index``: identity, motion, cameras, noise, light."""
    sequence = np.random.SeedSequence(seed, spawn_key=(index,))
    return [np.random.default_rng(child) for child in sequence.spawn(streams)]


def sample_lighting(rng: np.random.Generator) -> Lighting:
    """A key light from the upper hemisphere (30-70 degrees up, any azimuth) plus ambient."""
    azimuth = rng.uniform(0, 2 * np.pi)
    elevation = np.radians(rng.uniform(30, 70))
    direction = (np.sin(azimuth) * np.cos(elevation), np.sin(elevation), np.cos(azimuth) * np.cos(elevation))
    warmth = rng.uniform(-0.06, 0.06)
    intensity = rng.uniform(0.75, 0.95)
    return Lighting(
        direction=tuple(round(float(c), 6) for c in direction),
        colour=(round(intensity * (1 + warmth), 6), round(intensity, 6), round(intensity * (1 - warmth), 6)),
        ambient=round(float(rng.uniform(0.3, 0.5)), 6),
        shininess=round(float(rng.choice([16.0, 32.0, 64.0])), 6),
    )


def _shape(identity: Identity) -> torch.Tensor:
    return torch.tensor(identity.shape, dtype=torch.float32)


def _shape_landmarks(body: BodyModel, identity: Identity) -> tuple[torch.Tensor, Landmarks]:
    rest, marks = shaped_body(body, identity)
    return rest.joints, marks


def _noisy(
    config: SynthConfig, body: BodyModel, rotations: np.ndarray, translation: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    bones = sorted(set(body.joint_map.values()))
    return add_pose_noise(
        rotations, translation, bones, np.radians(config.pose_noise_deg), config.translation_noise_m, rng
    )


def _multiview_plan(config: SynthConfig, body: BodyModel, seed: int, index: int) -> SubjectPlan:
    """A subject moving in place inside a ring of cameras; the last frames are test poses."""
    identity_rng, motion_rng, camera_rng, noise_rng, light_rng = _rngs(seed, index, 5)
    identity = sample_identity(identity_rng, body.shape_names)
    joints, marks = _shape_landmarks(body, identity)
    # Motions rotate through the list, so every kind is in any dataset of enough subjects.
    kind = config.motions[index % len(config.motions)]
    clip_frames = config.frames * config.frame_stride
    rotations, translation, source = motion_clip(
        kind, body, _shape(identity), joints, clip_frames, config.fps, motion_rng, config.procedural_motions
    )
    rotations, translation = rotations[:: config.frame_stride], translation[:: config.frame_stride]
    # In place: a capture volume is small, so only the height of the root is kept.
    translation = translation * np.array([0.0, 1.0, 0.0])
    heading = np.full(config.frames, motion_rng.uniform(0, 2 * np.pi))
    rotations, translation = place_on_path(rotations, translation, heading, np.zeros((config.frames, 3)))
    noisy_rot, noisy_trans = _noisy(config, body, rotations, translation, noise_rng)

    # Frame from the soles to the hands raised overhead, ``fill`` of the image height.
    span = marks.height + ARM_REACH
    target = np.array([0.0, marks.feet + span / 2, 0.0])
    K, E = rigs.ring_cameras(
        camera_rng,
        config.views,
        target,
        span,
        config.width,
        config.height,
        config.camera_distance,
        config.camera_elevation_deg,
        config.fill,
    )
    frame_index = np.repeat(np.arange(config.frames), config.views)
    view_index = np.tile(np.arange(config.views), config.frames)
    train_frames = config.frames - config.test_frames
    arrays = SubjectArrays(
        K=K[view_index],
        world_to_camera=E[view_index],
        height=np.full(len(frame_index), config.height),
        width=np.full(len(frame_index), config.width),
        rotations=noisy_rot[frame_index],
        translation=noisy_trans[frame_index],
        shape=np.asarray(identity.shape),
        body=body.name,
        bone_names=list(body.bone_names),
        splits={
            "train": np.flatnonzero(frame_index < train_frames).tolist(),
            "test": np.flatnonzero(frame_index >= train_frames).tolist(),
        },
        frame_index=frame_index,
        view_index=view_index,
        rotations_true=rotations[frame_index],
        translation_true=translation[frame_index],
    )
    return SubjectPlan(f"subject_{index:03d}", index, identity, sample_lighting(light_rng), arrays, [source])


def _walk_in_circle(
    config: SynthConfig,
    body: BodyModel,
    identity: Identity,
    joints: torch.Tensor,
    frames: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, str]:
    """A walk turning ``walk_laps`` full turns over the training frames (continuing after).

    Procedural walks turn and travel with planted feet; the built-in walk is placed on the
    circle position(t) = r (sin phi, 0, cos phi), phi = phi_0 + (v / r) t, facing along it
    (heading phi + pi/2), with r chosen so the training frames cover ``walk_laps`` turns.
    """
    turn = 360.0 * config.walk_laps * frames / config.frames
    rotations, translation, source = motion_clip(
        "walk", body, _shape(identity), joints, frames, config.fps, rng, config.procedural_motions, turn_deg=turn
    )
    if source.startswith("synth:"):
        times = np.arange(frames) / config.fps
        radius = WALK_SPEED * (config.frames / config.fps) / (2 * np.pi * config.walk_laps)
        phi = rng.uniform(0, 2 * np.pi) + WALK_SPEED / radius * times
        path = radius * np.stack([np.sin(phi), np.zeros_like(phi), np.cos(phi)], axis=1)
        rotations, translation = place_on_path(rotations, translation, phi + np.pi / 2, path)
    return rotations, translation, source


def _on_the_spot(
    kind: str,
    config: SynthConfig,
    body: BodyModel,
    identity: Identity,
    joints: torch.Tensor,
    frames: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, str]:
    """A clip of ``kind`` performed in place: its root moves only vertically (then placed by the caller)."""
    rotations, translation, source = motion_clip(
        kind, body, _shape(identity), joints, frames, config.fps, rng, config.procedural_motions
    )
    return rotations, translation * np.array([0.0, 1.0, 0.0]), source


def _monocular_plan(config: SynthConfig, body: BodyModel, seed: int, index: int) -> SubjectPlan:
    """A subject walking a circle before one slowly panning camera, plus test images.

    Training: the first ``frames`` frames of the walk, seen by the main camera. Test: the
    walk continued (novel poses, later in time), then a different motion at the circle's
    centre facing the camera (novel poses), and every ``novel_view_stride``-th frame seen
    from ``novel_views`` static cameras spread around the rest of the circle (novel views).
    """
    identity_rng, motion_rng, camera_rng, noise_rng, light_rng = _rngs(seed, index, 5)
    identity = sample_identity(identity_rng, body.shape_names)
    joints, marks = _shape_landmarks(body, identity)
    train, walk_test = config.frames, config.test_frames // 2
    other_test = config.test_frames - walk_test
    if config.mono_motion == "walk":
        rotations, translation, source = _walk_in_circle(config, body, identity, joints, train + walk_test, motion_rng)
    else:
        rotations, translation, source = _on_the_spot(
            config.mono_motion, config, body, identity, joints, train + walk_test, motion_rng
        )
    sources = [source]
    path = translation[:train, [0, 2]]
    middle = 0.5 * (path.min(0) + path.max(0))
    radius = float(np.linalg.norm(path - middle, axis=1).max())
    centre = np.array([middle[0], marks.centre_height, middle[1]])
    if other_test:
        kind = NOVEL_POSE_KINDS[int(motion_rng.integers(len(NOVEL_POSE_KINDS)))]
        extra_rot, extra_trans, extra_source = _on_the_spot(
            kind, config, body, identity, joints, other_test, motion_rng
        )
        ground = np.array([middle[0], 0.0, middle[1]])
        facing = np.full(other_test, motion_rng.uniform(-0.5, 0.5))
        extra_rot, extra_trans = place_on_path(extra_rot, extra_trans, facing, np.repeat(ground[None], other_test, 0))
        rotations = np.concatenate([rotations, extra_rot])
        translation = np.concatenate([translation, extra_trans])
        sources.append(extra_source)
    frames = len(rotations)
    noisy_rot, noisy_trans = _noisy(config, body, rotations, translation, noise_rng)

    # Frame the whole circle across, and the body at the circle's near side (seen
    # larger) from top to bottom: the focal length that satisfies both.
    near = config.mono_distance - radius
    tall = MONO_HEIGHT_MARGIN * marks.height * config.mono_distance / near
    wide = 2 * radius + MONO_WIDTH_MARGIN
    focal = min(
        rigs.framing_focal(config.mono_distance, tall, config.height, 1.0),
        rigs.framing_focal(config.mono_distance, wide, config.width, 1.0),
    )
    K_main, E_main = rigs.monocular_cameras(
        camera_rng,
        frames,
        centre,
        focal,
        config.width,
        config.height,
        config.mono_distance,
        config.mono_elevation_deg,
        config.mono_drift_deg,
    )
    novel_frames = np.arange(0, frames, config.novel_view_stride)
    Ks, Es, frame_index, view_index = [K_main], [E_main], [np.arange(frames)], [np.zeros(frames, dtype=np.int64)]
    eye_main = -E_main[0, :3, :3].T @ E_main[0, :3, 3]
    main_azimuth = np.arctan2(eye_main[0] - centre[0], eye_main[2] - centre[2])
    for view in range(1, config.novel_views + 1):
        # Spread the novel views evenly around the rest of the circle.
        azimuth = main_azimuth + 2 * np.pi * view / (config.novel_views + 1) + camera_rng.uniform(-0.2, 0.2)
        elevation = np.radians(camera_rng.uniform(0.0, 30.0))
        eye = centre + config.mono_distance * np.array(
            [np.sin(azimuth) * np.cos(elevation), np.sin(elevation), np.cos(azimuth) * np.cos(elevation)]
        )
        Ks.append(np.repeat(rigs.intrinsics(focal, config.width, config.height)[None], len(novel_frames), axis=0))
        Es.append(np.repeat(rigs.look_at(eye, centre)[None], len(novel_frames), axis=0))
        frame_index.append(novel_frames)
        view_index.append(np.full(len(novel_frames), view))
    frame_index_all = np.concatenate(frame_index)
    view_index_all = np.concatenate(view_index)
    training = (view_index_all == 0) & (frame_index_all < train)
    arrays = SubjectArrays(
        K=np.concatenate(Ks),
        world_to_camera=np.concatenate(Es),
        height=np.full(len(frame_index_all), config.height),
        width=np.full(len(frame_index_all), config.width),
        rotations=noisy_rot[frame_index_all],
        translation=noisy_trans[frame_index_all],
        shape=np.asarray(identity.shape),
        body=body.name,
        bone_names=list(body.bone_names),
        splits={
            "train": np.flatnonzero(training).tolist(),
            "test": np.flatnonzero(~training).tolist(),
            "test_novel_pose": np.flatnonzero((view_index_all == 0) & (frame_index_all >= train)).tolist(),
            "test_novel_view": np.flatnonzero(view_index_all > 0).tolist(),
        },
        frame_index=frame_index_all,
        view_index=view_index_all,
        rotations_true=rotations[frame_index_all],
        translation_true=translation[frame_index_all],
    )
    return SubjectPlan(f"subject_{index:03d}", index, identity, sample_lighting(light_rng), arrays, sources)


def plan_subject(config: SynthConfig, body: BodyModel, seed: int, index: int) -> SubjectPlan:
    """The plan of subject ``index`` (stage 1 of the module docstring)."""
    make = _multiview_plan if config.capture == "multiview" else _monocular_plan
    plan = make(config, body, seed, index)
    if len(plan.arrays) != images_per_subject(config):
        raise AssertionError("bug: the plan's image count disagrees with images_per_subject")
    return plan


def frames_per_subject(config: SynthConfig) -> int:
    """Time steps of every subject: training and test frames."""
    return config.frames if config.capture == "multiview" else config.frames + config.test_frames


def images_per_subject(config: SynthConfig) -> int:
    """Images of every subject, known before planning (for the progress bar)."""
    frames = frames_per_subject(config)
    if config.capture == "multiview":
        return frames * config.views
    return frames + config.novel_views * len(range(0, frames, config.novel_view_stride))


# ---------------------------------------------------------------- rendering (workers)

_WORKER: dict[str, object] = {}
"""Per-process render state: the GL context, a renderer per image size, the progress
queue of a pool worker. Filled lazily; freed by :func:`release_worker_gl` (in-process
runs) or with the worker process (pools live for one :func:`generate`)."""


def _worker_init(progress: multiprocessing.Queue | None) -> None:
    """Initialise a spawned worker: one thread for torch and for llvmpipe (before any GL)."""
    os.environ["LP_NUM_THREADS"] = "1"
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle (it ends the pool)
    torch.set_num_threads(1)
    _WORKER["progress"] = progress


def _renderer(body: BodyModel, config: SynthConfig) -> MeshRenderer:
    from pghm.gl.context import headless_context

    if "ctx" not in _WORKER:
        _WORKER["ctx"] = headless_context()
    key = ("renderer", config.width, config.height, config.msaa_samples)
    if key not in _WORKER:
        _WORKER[key] = MeshRenderer(
            _WORKER["ctx"],
            body.faces.numpy(),
            body.uv_faces.numpy(),
            body.uv_coords.numpy(),
            config.width,
            config.height,
            config.msaa_samples,
        )
    return _WORKER[key]  # type: ignore[return-value]


def release_worker_gl() -> None:
    """Release the GL objects :func:`render_images` created in this process."""
    for key in [k for k in _WORKER if isinstance(k, tuple)]:
        _WORKER.pop(key).release()  # type: ignore[union-attr]
    if "ctx" in _WORKER:
        _WORKER.pop("ctx").release()  # type: ignore[union-attr]


def render_views(config: SynthConfig, plan: SubjectPlan, frames: list[int]) -> Iterator[tuple[int, RenderedView]]:
    """Paint ``plan``'s identity and render its images of time steps ``frames``, in order.

    Images sharing a time step share one posing. Yields (image index, view) pairs; the
    view's arrays are fresh per image.
    """
    body = load_body(plan.arrays.body)
    clothed = build_clothed_body(body, plan.identity, config.texture_size, config.cloth_geometry, config.wrinkles)
    renderer = _renderer(body, config)
    renderer.set_textures(clothed.albedo, clothed.wrinkles)
    a = plan.arrays
    by_frame = {f: np.flatnonzero(a.frame_index == f).tolist() for f in frames}
    for start in range(0, len(frames), POSE_BATCH):
        batch = frames[start : start + POSE_BATCH]
        rows = [by_frame[f][0] for f in batch]
        rotations = a.rotations_true[rows].astype(np.float64)
        amplitudes = wrinkle_amplitudes(rotations, body.joint_map) if config.wrinkles else np.zeros((len(rows), 8))
        positions, normals = pose_clothed_body(
            body, clothed, rotations, a.translation_true[rows].astype(np.float64), amplitudes
        )
        for k, frame in enumerate(batch):
            renderer.set_geometry(positions[k], normals[k])
            for i in by_frame[frame]:
                yield i, renderer.render(a.K[i], a.world_to_camera[i], plan.lighting, amplitudes[k])


def render_images(config: SynthConfig, plan: SubjectPlan, directory: Path, frames: list[int], progress=None) -> int:
    """Render ``plan``'s images of time steps ``frames`` (:func:`render_views`) into ``directory``.

    Returns the number of images written; ``progress`` (a callable taking a count) is told
    after each image.
    """
    written = 0
    for i, view in render_views(config, plan, frames):
        write_image(directory, i, view.rgb, view.coverage, config.png_compression)
        written += 1
        if progress is not None:
            progress(1)
    return written


@dataclass(frozen=True)
class RenderTask:
    """One unit of work: plan subject ``index`` and render its time steps ``frames``.

    Planning is repeated by every task of a subject (it is deterministic and cheap next
    to rendering), so workers need nothing but these numbers.
    """

    config: SynthConfig
    seed: int
    index: int
    frames: list[int]
    out: str


def run_task(task: RenderTask, progress=None) -> SubjectPlan:
    """Plan the task's subject, render its frames; returns the plan (for the metadata)."""
    body = load_body("anny")
    plan = plan_subject(task.config, body, task.seed, task.index)
    render_images(task.config, plan, Path(task.out) / plan.name, task.frames, progress)
    return plan


def _pool_task(task: RenderTask) -> SubjectPlan:
    sink = _WORKER.get("progress")
    return run_task(task, progress=(lambda n: sink.put(n)) if sink is not None else None)  # type: ignore[union-attr]


def make_tasks(config: SynthConfig, seed: int, out: Path, workers: int) -> list[RenderTask]:
    """Whole subjects, or frame chunks when there are fewer subjects than workers."""
    chunks = max(1, -(-workers // config.identities))
    frames = np.arange(frames_per_subject(config))
    return [
        RenderTask(config, seed, index, part.tolist(), str(out))
        for index in range(config.identities)
        for part in np.array_split(frames, min(chunks, len(frames)))
    ]


def _versions() -> dict[str, str]:
    import moderngl
    import PIL

    return {
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "torch": torch.__version__,
        "moderngl": moderngl.__version__,
        "pillow": PIL.__version__,
    }


def generate(
    config: SynthConfig, seed: int, out: str | Path, workers: int = 2, progress: bool = True
) -> GenerationReport:
    """Generate a dataset of ``config.identities`` subjects into the new folder ``out``.

    Args:
        config: what to generate (validated here).
        seed: the dataset's seed; with ``config`` it fixes every output byte.
        out: a folder that does not exist yet or is empty.
        workers: render processes (1: render in this process).
        progress: show a tqdm bar on stderr.
    """
    config.validate()
    if seed < 0:
        raise PghmError(f"seed must be >= 0, got {seed}")
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise PghmError(f"{out} already exists and is not empty; choose a new output folder")
    started = time.perf_counter()
    total = config.identities * images_per_subject(config)
    workers = max(1, min(int(workers), config.identities * frames_per_subject(config)))
    with staged_folder(out) as building:  # an interrupted run leaves no half-made dataset
        tasks = make_tasks(config, seed, building, workers)
        with tqdm(total=total, desc="pghm synth", unit="img", disable=not progress, file=sys.stderr) as bar:
            plans = _run_serially(tasks, bar) if workers == 1 else _run_in_pool(tasks, workers, bar)
        interrupt_point("synth-subjects")
        by_index = {plan.index: plan for plan in plans}
        versions = _versions()
        for index in range(config.identities):
            plan = by_index[index]
            write_subject(building / plan.name, plan.arrays, _subject_meta(config, seed, plan, versions))
        names = [by_index[i].name for i in range(config.identities)]
        write_dataset_meta(
            building,
            names,
            {
                "source": "pghm synth",
                "generator_version": GENERATOR_VERSION,
                "seed": seed,
                "config": config.to_json(),
                "versions": versions,
            },
        )
    return GenerationReport(out, names, total, time.perf_counter() - started, workers)


def _run_serially(tasks: list[RenderTask], bar: tqdm) -> list[SubjectPlan]:
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as in the workers, so float results cannot depend on the path taken
    try:
        return [run_task(task, progress=bar.update) for task in tasks]
    finally:
        torch.set_num_threads(threads)
        release_worker_gl()


def _run_in_pool(tasks: list[RenderTask], workers: int, bar: tqdm) -> list[SubjectPlan]:
    context = multiprocessing.get_context("spawn")
    sink = context.Queue()
    with context.Pool(workers, initializer=_worker_init, initargs=(sink,)) as pool:
        result = pool.map_async(_pool_task, tasks, chunksize=1)
        while not result.ready():
            try:
                bar.update(sink.get(timeout=0.2))
            except queue.Empty:
                pass
        plans = result.get()  # re-raises a worker's exception here
        while True:
            try:
                bar.update(sink.get_nowait())
            except queue.Empty:
                break
    return plans


def _subject_meta(config: SynthConfig, seed: int, plan: SubjectPlan, versions: dict[str, str]) -> dict:
    a = plan.arrays
    return {
        "source": "pghm synth",
        "generator_version": GENERATOR_VERSION,
        "seed": seed,
        "subject_index": plan.index,
        "seed_derivation": (
            "numpy SeedSequence(seed, spawn_key=(subject_index,)).spawn(5): identity, motion, cameras, noise, light"
        ),
        "capture": config.capture,
        "config": config.to_json(),
        "identity": plan.identity.to_json(),
        "lighting": asdict(plan.lighting),
        "motions": plan.motion_sources,
        "motion_kinds_available": list(MOTION_KINDS),
        "pose_noise": {
            "rotation_std_deg": config.pose_noise_deg,
            "translation_std_m": config.translation_noise_m,
            "bones": noisy_bone_names(a),
            "note": (
                "rotations/translation are noisy (as an estimator's); "
                "rotations_true/translation_true rendered the images"
            ),
        },
        "images": len(a),
        "frames": int(a.frame_index.max()) + 1,
        "views": int(a.view_index.max()) + 1,
        "versions": versions,
    }


def noisy_bone_names(arrays: SubjectArrays) -> list[str]:
    """Names of the bones that received estimator noise (the canonical joints' bones)."""
    body = load_body(arrays.body)
    return [arrays.bone_names[b] for b in sorted(set(body.joint_map.values()))]
