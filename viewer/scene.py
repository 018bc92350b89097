"""The viewer's model side: avatar, pose sliders, motion timeline, identity edits -> Gaussian arrays.

No GL here. :class:`AvatarScene` owns an :class:`~pghm.render.driver.AvatarDriver` (the
avatar through a :class:`~pghm.model.evaluator.CachedEvaluator`), an
:class:`~viewer.identity.IdentityEditor` and a :class:`PoseState`; :meth:`AvatarScene.evaluate`
hands the renderer plain numpy arrays. What re-runs on each edit is the evaluator's rule:

    identity edit (pick, blend, PCA, region gain)  -> E_u / D_static, pose and view branches (skinning cached)
    pose slider, timeline frame                    -> skinning, E_p / D_pose, E_v / D_view
    camera move                                    -> E_v / D_view (nothing if view-dependent colour is off)
    display toggles (I_s / I_d, view-dependent)    -> only the branches the new display needs
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import roma
import torch

from pghm.body import CANONICAL_JOINTS, BodyPose
from pghm.errors import PghmError
from pghm.motion.motion import Motion
from pghm.motion.open_motion import REST, motion_names, open_motion
from pghm.render import DEFAULT_FOV_Y, AvatarDriver, Framing, GaussianArrays, GaussianSet, frame_points
from pghm.render.framing import floor_shift
from pghm.uv.regions import RegionMap, region_map
from viewer.camera import OrbitView
from viewer.identity import IdentityEditor, IdentityState
from viewer.settings import SHIPPED_MOTIONS

SLIDERLESS_JOINTS = ("left_collar", "right_collar", "left_foot", "right_foot")
"""Canonical joints left without sliders: small motions, and fewer rows in the panel."""
POSE_JOINTS = tuple(name for name in CANONICAL_JOINTS if name not in SLIDERLESS_JOINTS)
"""Joints with pose sliders (canonical names, :data:`pghm.body.CANONICAL_JOINTS`); the pelvis
is the root bone, so its slider is the body's global orientation."""
AXES = ("x", "y", "z")
ANGLE_LIMIT = 180.0
"""Pose sliders span +-this many degrees."""
SPEED_RANGE = (0.1, 4.0)
"""Playback speed multipliers."""
_SERIALS = itertools.count(1)
"""Numbers for drivers and opened motions: part of the keys of evaluated frames (never reused, unlike id())."""


def clip_choices() -> list[tuple[str, str]]:
    """(label, source) of the clips the panel lists: rest, the procedural clips, the shipped BVH clips."""
    shipped = sorted(SHIPPED_MOTIONS.glob("*.bvh")) if SHIPPED_MOTIONS.is_dir() else []
    return [(name, name) for name in motion_names()] + [(path.stem, str(path)) for path in shipped]


def clip_index(choices: list[tuple[str, str]], source: str) -> int:
    """Index in ``choices`` (:func:`clip_choices`) of the open motion ``source``, -1 if not listed.

    A file matches by its resolved path, so a relative path opens the listed clip.
    """
    for index, (_, listed) in enumerate(choices):
        if listed == source or (Path(listed).is_file() and Path(listed).resolve() == Path(source).resolve()):
            return index
    return -1


def compose_pose(motion: Motion, frame: int, sliders: np.ndarray, joint_map: dict[str, int]) -> BodyPose:
    """Motion frame ``frame`` with the sliders (len(POSE_JOINTS), 3) degrees applied: R = R_motion R_slider."""
    pose = motion.pose(frame)
    if not sliders.any():
        return pose
    rotations = pose.rotations.clone()
    moved = np.flatnonzero(sliders.any(axis=1))  # untouched bones keep the motion's values exactly
    bones = [joint_map[POSE_JOINTS[row]] for row in moved]
    offsets = torch.from_numpy(np.radians(sliders[moved])).to(rotations.dtype)
    rotations[0, bones] = roma.rotvec_composition([rotations[0, bones], offsets])
    return BodyPose(rotations, pose.translation)


@dataclass
class PoseState:
    """The pose shown: a motion frame with the sliders' rotations applied on top.

    Attributes:
        sliders: (len(POSE_JOINTS), 3) degrees, the rotation vector of each slider joint in
            rest-aligned axes (pghm.body.pose). Applied after the motion's own rotation of
            that bone: R = R_motion R_slider (with the rest motion, R = R_slider).
        motion: the open motion (``rest`` is a one-frame clip).
        time: seconds into the motion.
        playing: whether :meth:`advance` moves ``time``.
        loop: wrap at the end (else stop on the last frame).
        speed: playback speed multiplier.
    """

    motion: Motion
    sliders: np.ndarray = field(default_factory=lambda: np.zeros((len(POSE_JOINTS), 3)))
    time: float = 0.0
    playing: bool = False
    loop: bool = True
    speed: float = 1.0

    @property
    def frame(self) -> int:
        return self.motion.frame_at(self.time, loop=self.loop)

    def advance(self, seconds: float) -> None:
        """Move the clock by ``seconds`` of wall time when playing (times ``speed``)."""
        if not self.playing:
            return
        self.time += seconds * self.speed
        if not self.loop and self.time >= self.motion.duration:
            self.time, self.playing = self.motion.duration, False
        elif self.loop and self.motion.num_frames > 1:
            self.time %= self.motion.num_frames / self.motion.fps

    def pose(self, joint_map: dict[str, int]) -> BodyPose:
        """The 1-pose :class:`BodyPose` of the current frame and sliders."""
        return compose_pose(self.motion, self.frame, self.sliders, joint_map)


@dataclass(frozen=True, eq=False)
class SceneRequest:
    """One evaluation for the model worker: everything it reads, fixed when the UI posted it.

    Attributes:
        snapshot: the scene state (driver, identity, sliders, motion, display set).
        frame: the motion frame.
        view: the orbit view the view-dependent colour is evaluated for.
        centre: (3,) float32 camera centre (the view, target shifted when following the body).
    """

    snapshot: SceneSnapshot
    frame: int
    view: OrbitView
    centre: np.ndarray

    @property
    def key(self) -> tuple:
        """(scene state, frame, camera centre): equal keys give equal Gaussians."""
        return self.snapshot.key, self.frame, self.centre.tobytes()


@dataclass(frozen=True)
class Evaluated:
    """A worker's answer: the Gaussians and what the model and skinning took (ms)."""

    arrays: GaussianArrays
    model_ms: float
    skinning_ms: float


@dataclass(frozen=True, eq=False)
class SceneSnapshot:
    """The scene's state as a value: what a frame's Gaussians depend on, besides the frame and the camera.

    Made on the UI thread (:meth:`AvatarScene.snapshot`), read by the model worker; ``key``
    names the state (serial numbers of the driver and the motion, identity, sliders, set).
    """

    driver: AvatarDriver
    driver_serial: int
    identity: IdentityEditor
    identity_state: IdentityState
    motion: Motion
    motion_serial: int
    sliders: np.ndarray
    rest_root: np.ndarray
    gaussians: GaussianSet
    view_dependent: bool
    follow: bool

    @property
    def key(self) -> tuple:
        return (
            self.driver_serial,
            self.identity_state,
            self.sliders.tobytes(),
            self.motion_serial,
            self.gaussians,
            self.view_dependent,
            self.follow,
        )

    def pose(self, frame: int) -> BodyPose:
        return compose_pose(self.motion, frame, self.sliders, self.driver.body.joint_map)

    def root_shift(self, pose: BodyPose) -> np.ndarray:
        """(3,) horizontal motion of the root from rest (cameras that follow the body add it)."""
        return floor_shift(self.driver.root_position(pose), self.rest_root)

    def camera_offset(self, frame: int) -> np.ndarray:
        """(3,) what the camera's target moves by at ``frame``: the root shift when following, else 0."""
        return self.root_shift(self.pose(frame)) if self.follow else np.zeros(3)

    def request(self, frame: int, view: OrbitView, offset: np.ndarray | None = None) -> SceneRequest:
        """The evaluation of ``frame`` seen from ``view`` (``offset``: :meth:`camera_offset`, if known)."""
        offset = self.camera_offset(frame) if offset is None else offset
        return SceneRequest(self, frame, view, view.centre(offset))


def evaluate_request(request: SceneRequest, interrupt: Callable[[], bool] | None = None) -> Evaluated:
    """Run the model for ``request`` (the model worker's job; only the changed branches re-run).

    ``interrupt`` is checked between the model's stages; True raises
    :class:`~pghm.model.evaluator.Interrupted` (a newer request waits).
    """
    snapshot = request.snapshot
    driver = snapshot.driver
    identity_map = snapshot.identity.map_of(snapshot.identity_state)
    pose = snapshot.pose(request.frame)
    arrays = driver.evaluate(
        identity_map, pose, request.centre, snapshot.gaussians, snapshot.view_dependent, interrupt=interrupt
    )
    return Evaluated(arrays, driver.times.model_ms, driver.times.skinning_ms)


class AvatarScene:
    """Everything the viewer shows about one avatar file, and the edits made to it.

    Args:
        avatar: a loaded :class:`~pghm.io.avatar.Avatar`.
        body_model_path: the model file of bodies that are not embedded (SMPL-X).
    """

    def __init__(self, avatar, body_model_path: str | None = None) -> None:
        self.avatar = avatar
        self.body_model_path = body_model_path
        self.driver = AvatarDriver(avatar, 0, body_model_path)
        self.driver_serial = next(_SERIALS)
        self.body = self.driver.body
        self.regions: RegionMap = region_map(self.driver.geometry, self.body)
        self.identity = IdentityEditor(avatar, self.regions)
        self.pose_state = PoseState(motion=open_motion(REST, self.body))
        self.motion_name = REST
        self.motion_serial = next(_SERIALS)
        self._rest_root = self.driver.root_position(self.driver.rest_pose())

    # ------------------------------------------------------------------ identity

    def pick_identity(self, index: int) -> None:
        """Show bank identity ``index``; its body shape replaces the geometry if it differs."""
        self.identity.pick(index)
        shape = self.avatar.shape_of(index)
        if not torch.equal(shape, self.driver.geometry.shape):
            self.driver = AvatarDriver(self.avatar, index, self.body_model_path)
            self.driver_serial = next(_SERIALS)
            self.regions = region_map(self.driver.geometry, self.body)
            self.identity.regions = self.regions
            self._rest_root = self.driver.root_position(self.driver.rest_pose())

    def reset_identity(self) -> None:
        """Identity 0 (and its body shape), no blend, PCA sliders at 0, region gains at 1."""
        self.identity.reset()
        if self.identity.is_prior:
            self.pick_identity(0)

    # ---------------------------------------------------------------------- pose

    def set_pose_slider(self, joint: str, axis: int | str, degrees: float) -> None:
        """Set one slider: ``joint`` of :data:`POSE_JOINTS`, ``axis`` 0-2 or "x"/"y"/"z"."""
        if joint not in POSE_JOINTS:
            raise PghmError(f"no pose slider for {joint!r}; sliders: {', '.join(POSE_JOINTS)}")
        axis = AXES.index(axis) if isinstance(axis, str) else int(axis)
        if not -ANGLE_LIMIT <= degrees <= ANGLE_LIMIT:
            raise PghmError(f"pose angle must be within +-{ANGLE_LIMIT} degrees, got {degrees}")
        self.pose_state.sliders[POSE_JOINTS.index(joint), axis] = float(degrees)

    def reset_pose(self) -> None:
        self.pose_state.sliders[:] = 0.0

    def current_pose(self) -> BodyPose:
        return self.pose_state.pose(self.body.joint_map)

    # -------------------------------------------------------------------- motion

    def open_motion(self, source: str) -> None:
        """Open a motion file (.npz, .bvh), a procedural name or a subject folder; the timeline restarts at 0."""
        motion = open_motion(source.strip(), self.body, self.driver.geometry.shape, self.avatar.pose_track)
        self.pose_state.motion, self.pose_state.time = motion, 0.0
        self.motion_name = source.strip()
        self.motion_serial = next(_SERIALS)

    def scrub_to(self, frame: int) -> None:
        """Show motion frame ``frame`` (clamped to the clip)."""
        frame = min(max(int(frame), 0), self.pose_state.motion.num_frames - 1)
        self.pose_state.time = frame / self.pose_state.motion.fps

    def set_speed(self, speed: float) -> None:
        if not SPEED_RANGE[0] <= speed <= SPEED_RANGE[1]:
            raise PghmError(f"speed must be in [{SPEED_RANGE[0]}, {SPEED_RANGE[1]}], got {speed}")
        self.pose_state.speed = float(speed)

    # ------------------------------------------------------------------- outputs

    def framing(self, aspect: float) -> Framing:
        """The default camera framing of the rest body for images of ``aspect`` = W / H."""
        return frame_points(self.driver.geometry.surface.positions.numpy(), DEFAULT_FOV_Y, aspect)

    def snapshot(self, gaussians: GaussianSet, view_dependent: bool, follow: bool) -> SceneSnapshot:
        """The current state as a value, for the model worker (copies the sliders and identity edits)."""
        return SceneSnapshot(
            driver=self.driver,
            driver_serial=self.driver_serial,
            identity=self.identity,
            identity_state=self.identity.state(),
            motion=self.pose_state.motion,
            motion_serial=self.motion_serial,
            sliders=self.pose_state.sliders.copy(),
            rest_root=self._rest_root,
            gaussians=gaussians,
            view_dependent=view_dependent,
            follow=follow,
        )

    def posed_mesh(self) -> np.ndarray:
        """(V, 3) float32 body mesh vertices in the current pose (the mesh overlay)."""
        with torch.no_grad():
            return self.body.posed_vertices(self.current_pose(), self.driver.rest)[0].numpy().astype(np.float32)

    def mesh_edges(self) -> np.ndarray:
        """(E, 2) uint32 unique edges of the body mesh's triangles."""
        faces = self.body.faces.numpy()
        edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        return np.unique(np.sort(edges, axis=1), axis=0).astype(np.uint32)

    def joint_pixels(self, camera, names: tuple[str, ...]) -> dict[str, tuple[float, float]]:
        """(u, v) pixel of posed canonical joints ``names`` in ``camera`` (for tests and labels)."""
        pose = self.current_pose()
        with torch.no_grad():
            transforms = self.driver.geometry.transforms(pose)[0]
        joints = self.driver.geometry.joints
        w2c = camera.world_to_camera.double()
        out = {}
        for name in names:
            bone = self.body.joint_map[name]
            world = transforms[bone, :3, :3] @ joints[bone] + transforms[bone, :3, 3]
            t = w2c[:3, :3] @ world.double() + w2c[:3, 3]
            out[name] = (float(camera.fx * t[0] / t[2] + camera.cx), float(camera.fy * t[1] / t[2] + camera.cy))
        return out
