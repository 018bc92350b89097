"""The avatar file (``avatar.pt``, and ``prior.pt`` in the same format).

One versioned file holding everything needed to rebuild and drive an avatar:

    format      "pghm-avatar"
    version     FORMAT_VERSION
    kind        "avatar" (one personalised subject) or "prior" (a bank of identities)
    config      the ModelConfig fields
    body        {"name": backend, "shape": (S,) for an avatar, "shapes": (n, S) for a prior}
    latent      (1, C, L, L) full-resolution identity latent of an avatar (None for a prior)
    weights     the network's state dict (the bank is ``identity_bank``, (n, C, L', L'); with the
                config's ``detail``, the detail layer's residuals ``detail.maps``, (1, 5, 2L, 2L))
    metadata    training record: data, steps, seconds, metrics (plain JSON-like values)
    pose_track  optional: the pose corrections a fit learned for its video (:class:`PoseTrack`)

Files are read with ``torch.load(weights_only=True)``: only tensors and plain containers
can come back, so opening an untrusted avatar never runs code. Every problem — a
truncated file, random bytes, a foreign pickle, a wrong version, a missing key, a tensor
of the wrong shape or dtype or with NaN — is one :class:`AvatarFileError` line naming it.
Saves are atomic (temporary file, fsync, rename).
"""

from __future__ import annotations

import io
import json
import operator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pghm.body.model import shape_problem
from pghm.device import move
from pghm.errors import AvatarFileError, PghmError
from pghm.io.atomic import Outputs, atomic_write_bytes
from pghm.io.torch_file import TorchFileError, load_torch_file
from pghm.model.config import ModelConfig
from pghm.model.pghm import PGHM
from pghm.motion.motion import MAX_ROTATION, MAX_TRANSLATION

FORMAT_NAME = "pghm-avatar"
FORMAT_VERSION = 2
"""Written by this pghm. Version 2 added the model config's detail-layer fields
(``detail``, ``max_detail_offset``; the layer's map is the weight ``detail.maps``)."""
READABLE_VERSIONS = (1, FORMAT_VERSION)
"""Versions this pghm reads: a version 1 file is an avatar without a detail layer."""
REQUIRED_KEYS = ("format", "version", "kind", "config", "body", "latent", "weights", "metadata")
KINDS = ("avatar", "prior")
MAX_BRACKET_STEPS = 3
"""A frame a pose track does not hold is interpolated only between trained frames at most this many
frame steps apart (the subject's smallest step between frame numbers): a test frame with a dropped
frame beside it still is; anything farther keeps its stored pose."""


def bracket(known: np.ndarray, query: np.ndarray, max_gap: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interpolation of values known at frames ``known`` (K,) ascending onto frames ``query`` (Q,).

    Returns (lower, upper, weight), each (Q,): value(q) = (1 - w) value[lower] + w value[upper]
    with rows into ``known``; lower = upper and w = 0 where q is known; lower = upper = -1 where q
    is neither known nor bracketed by known frames at most ``max_gap`` apart.
    """
    if len(known) == 0:
        none = np.full(len(query), -1)
        return none, none.copy(), np.zeros(len(query))
    upper = np.searchsorted(known, query)
    exact = (upper < len(known)) & (known[np.minimum(upper, len(known) - 1)] == query)
    lower = upper - 1
    inside = (lower >= 0) & (upper < len(known))
    a = known[np.clip(lower, 0, len(known) - 1)]
    b = known[np.clip(upper, 0, len(known) - 1)]
    between = inside & ~exact & (b - a <= max_gap)
    weight = np.where(between, (query - a) / np.maximum(b - a, 1), 0.0)
    lower = np.where(exact, upper, np.where(between, lower, -1))
    upper = np.where(exact | between, upper, -1)
    return lower, upper, weight


@dataclass
class PoseTrack:
    """The pose corrections ``pghm fit`` learned for the frames of its subject (:mod:`pghm.train.pose_track`).

    Attributes:
        frames: (F,) int64 frame numbers (the subject's ``frame_index``) of the trained frames, ascending.
        bones: (K,) int64 the corrected bones.
        rotations: (F, K, 3) axis-angle deltas added to the stored rotations of those bones.
        translation: (F, 3) deltas added to the stored root translation.
        poses: digest of the stored poses they correct (:meth:`pghm.subject.SubjectArrays.poses_digest`).
        aligned: (A,) int64 those of ``frames`` the fit held out of training and aligned to their own
            images once the avatar was finished (:func:`pghm.train.fit.align_held_out`), ascending.
    """

    frames: Tensor
    bones: Tensor
    rotations: Tensor
    translation: Tensor
    poses: str
    aligned: Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.int64))

    def at(
        self, frames: np.ndarray, max_gap: int, aligned: frozenset[int] = frozenset()
    ) -> tuple[Tensor, Tensor, np.ndarray, np.ndarray]:
        """The corrections at frame numbers ``frames`` (Q,): a trained frame's own, or those of the
        trained frames on either side (at most ``max_gap`` apart) interpolated in time,

            delta_f = (1 - w) delta_a + w delta_b,    w = (f - a) / (b - a);

        the deltas are small axis-angle vectors, so this interpolates their rotations to first order.
        A held-out frame in ``aligned`` (its stored pose already fitted to its own image, meta.json's
        ``aligned_frames``) takes none: its neighbours' corrections would move it off its image.

        Returns rotations (Q, K, 3), translation (Q, 3) (zero where ``found`` is False), found (Q,)
        and exact (Q,) (a trained frame's own) boolean masks.
        """
        lower, upper, weight = bracket(self.frames.numpy(), np.asarray(frames), max_gap)
        exact = lower == upper
        found = (lower >= 0) & (exact | ~np.isin(frames, list(aligned)))
        w = torch.as_tensor(weight, dtype=torch.float32)
        lo, hi = torch.as_tensor(np.maximum(lower, 0)), torch.as_tensor(np.maximum(upper, 0))
        out = []
        for known in (self.rotations, self.translation):
            weights = w.view(-1, *[1] * (known.dim() - 1))
            value = (1 - weights) * known[lo] + weights * known[hi]
            out.append(torch.where(torch.as_tensor(found).view_as(weights), value, torch.zeros_like(value)))
        return out[0], out[1], found, found & exact


@dataclass
class Avatar:
    """A loaded avatar or prior.

    Attributes:
        model: the network, in eval mode.
        kind: "avatar" or "prior".
        body_name: body backend the avatar was built on.
        shape: (S,) body shape of an avatar; for a prior, the first identity's.
        shapes: (n, S) per-identity shapes of a prior, or None.
        latent: (1, C, L, L) personal latent of an avatar, or None for a prior.
        metadata: the training record.
        pose_track: the corrections of its training video's poses, or None.
    """

    model: PGHM
    kind: str
    body_name: str
    shape: Tensor
    shapes: Tensor | None = None
    latent: Tensor | None = None
    metadata: dict = field(default_factory=dict)
    pose_track: PoseTrack | None = None

    @property
    def device(self) -> torch.device:
        """Where the network (and an avatar's latent) live; files are written from the CPU."""
        return self.model.identity_bank.device

    def to(self, device: torch.device | str) -> Avatar:
        """This avatar with its network (moved in place) and latent on ``device``."""
        latent = None if self.latent is None else self.latent.to(device)
        return replace(self, model=self.model.to(device), latent=latent)

    def identity_map(self, index: int = 0) -> Tensor:
        """F (1, C, L, L): the personal latent of an avatar, or identity ``index`` of a prior."""
        if self.latent is not None:
            return self.latent
        self.check_identity(index)
        with torch.no_grad():
            return self.model.decode_identity(index)

    def shape_of(self, index: int = 0) -> Tensor:
        """(S,) the body shape of identity ``index`` (the avatar's own for an avatar)."""
        if self.shapes is None:
            return self.shape
        self.check_identity(index)
        return self.shapes[index]

    def member(self, index: int) -> Avatar:
        """Identity ``index`` of a prior as an avatar: its decoded identity map as the personal
        latent and its own shape (to evaluate how well the prior fits the people it learned)."""
        if self.kind != "prior":
            raise PghmError("member() picks an identity of a prior; this is an avatar")
        return Avatar(
            model=self.model,
            kind="avatar",
            body_name=self.body_name,
            shape=self.shape_of(index),
            latent=self.identity_map(index),
            metadata={**self.metadata, "prior_identity": index},
        )

    def check_identity(self, index: int) -> None:
        """PghmError unless ``index`` picks a member of a prior's bank (an avatar is one person: 0 only)."""
        if self.kind != "prior":
            if index != 0:
                raise PghmError(
                    f"identity {index!r}: this is a personalised avatar (one person); --identity picks a prior's member"
                )
            return
        count = self.model.num_identities
        try:
            position = operator.index(index)
        except TypeError:
            position = -1
        if isinstance(index, bool) or not 0 <= position < count:
            raise PghmError(f"identity {index!r} is outside the prior's {count} identities (0 to {count - 1})")


def _plain(value: object, where: str) -> object:
    """``value`` as plain JSON-like data (what weights_only loading accepts)."""
    try:
        return json.loads(json.dumps(value))
    except (TypeError, ValueError) as error:
        raise PghmError(f"avatar {where} must be plain JSON-like data: {error}") from None


def recorded_path(path: str | Path) -> str:
    """How a file an avatar was made from is named in its metadata: relative to the working
    directory when inside it, else its name alone (a file records no directory of the machine
    that made it)."""
    resolved = Path(path).resolve()
    try:
        return resolved.relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return resolved.name


def avatar_payload(avatar: Avatar) -> dict:
    """The dictionary written to disk."""
    body = {"name": avatar.body_name, "shape": avatar.shape.detach().float().cpu()}
    if avatar.shapes is not None:
        body["shapes"] = avatar.shapes.detach().float().cpu()
    return {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "kind": avatar.kind,
        "config": _plain(avatar.model.config.to_dict(), "config"),
        "body": body,
        "latent": None if avatar.latent is None else avatar.latent.detach().float().cpu(),
        "weights": {k: v.detach().cpu() for k, v in avatar.model.state_dict().items()},
        "metadata": _plain(avatar.metadata, "metadata"),
        "pose_track": None if avatar.pose_track is None else _track_payload(avatar.pose_track),
    }


def _track_payload(track: PoseTrack) -> dict:
    return {
        "frames": track.frames.detach().long().cpu(),
        "bones": track.bones.detach().long().cpu(),
        "rotations": track.rotations.detach().float().cpu(),
        "translation": track.translation.detach().float().cpu(),
        "poses": track.poses,
        "aligned": track.aligned.detach().long().cpu(),
    }


def save_avatar(path: str | Path, avatar: Avatar, outputs: Outputs | None = None) -> None:
    """Write ``avatar`` to ``path`` atomically (with ``outputs``: as one of a command's outputs,
    which appear together, :func:`pghm.io.atomic.all_or_none`)."""
    if avatar.kind not in KINDS:
        raise PghmError(f"avatar kind must be one of {KINDS}, got {avatar.kind!r}")
    buffer = io.BytesIO()
    torch.save(avatar_payload(avatar), buffer)
    (outputs.write_bytes if outputs is not None else atomic_write_bytes)(path, buffer.getvalue())


def _fail(path: Path, problem: str) -> AvatarFileError:
    return AvatarFileError(f"{path}: {problem}")


def _read(path: Path) -> dict:
    try:
        payload = load_torch_file(path)
    except TorchFileError as error:
        raise _fail(path, f"not a readable avatar file: {error}") from None
    if not isinstance(payload, dict):
        raise _fail(path, f"not a pghm avatar file (holds a {type(payload).__name__})")
    return payload


def _is_exactly(value: object, kind: type, expected: object) -> bool:
    """``value == expected`` for a plain ``kind`` value (a tensor or list never equals a marker)."""
    return type(value) is kind and value == expected


def _short(value: object) -> str:
    """A value for a message: its repr, cut to one short line."""
    text = repr(value).replace("\n", " ")
    return text if len(text) <= 60 else text[:57] + "..."


def _check_tensor(
    path: Path, name: str, value: object, shape: tuple[int, ...] | None, limit: tuple[float, str] | None = None
) -> Tensor:
    """``value`` as a float tensor of ``shape``, finite and (``limit``: (bound, unit)) within +-bound."""
    if not isinstance(value, Tensor):
        raise _fail(path, f"'{name}' is not a tensor")
    if not value.is_floating_point():
        raise _fail(path, f"'{name}' has dtype {value.dtype}, expected a float tensor")
    if shape is not None and tuple(value.shape) != shape:
        raise _fail(path, f"'{name}' has shape {tuple(value.shape)}, expected {shape}")
    if not torch.isfinite(value).all():
        raise _fail(path, f"'{name}' has non-finite values")
    largest = float(value.abs().max()) if value.numel() else 0.0
    if limit is not None and largest > limit[0]:
        raise _fail(path, f"'{name}' has values beyond +-{limit[0]:g} {limit[1]} (largest {largest:.3g})")
    return value.float()


def _check_indices(path: Path, name: str, value: object) -> Tensor:
    """A (n,) int64 tensor of distinct, ascending, non-negative indices."""
    if not isinstance(value, Tensor) or value.dtype != torch.int64 or value.dim() != 1:
        raise _fail(path, f"'{name}' is not a (n,) int64 tensor")
    if len(value) and (value.min() < 0 or (value.diff() <= 0).any()):
        raise _fail(path, f"'{name}' must be distinct non-negative indices in ascending order")
    return value


def _load_track(path: Path, value: object) -> PoseTrack | None:
    if value is None:
        return None
    keys = ("frames", "bones", "rotations", "translation", "poses")
    if not isinstance(value, dict) or any(key not in value for key in keys):
        raise _fail(path, f"'pose_track' must hold {', '.join(keys)}")
    frames = _check_indices(path, "pose_track.frames", value["frames"])
    bones = _check_indices(path, "pose_track.bones", value["bones"])
    if not isinstance(value["poses"], str):
        raise _fail(path, "'pose_track.poses' is not a digest string")
    # Files written before the fit aligned its held-out frames have no "aligned": none are.
    aligned = _check_indices(path, "pose_track.aligned", value.get("aligned", torch.zeros(0, dtype=torch.int64)))
    if not bool(torch.isin(aligned, frames).all()):
        raise _fail(path, "'pose_track.aligned' lists frames the track has no correction for")
    return PoseTrack(
        frames=frames,
        bones=bones,
        rotations=_check_tensor(
            path, "pose_track.rotations", value["rotations"], (len(frames), len(bones), 3), (MAX_ROTATION, "rad")
        ),
        translation=_check_tensor(
            path, "pose_track.translation", value["translation"], (len(frames), 3), (MAX_TRANSLATION, "m")
        ),
        poses=value["poses"],
        aligned=aligned,
    )


def load_avatar(path: str | Path) -> Avatar:
    """Read an avatar or prior file; one :class:`AvatarFileError` line on any problem."""
    path = Path(path)
    payload = _read(path)
    missing = [key for key in REQUIRED_KEYS if key not in payload]
    if not _is_exactly(payload.get("format"), str, FORMAT_NAME):
        raise _fail(path, "not a pghm avatar file (no 'format: pghm-avatar' marker)")
    if missing:
        raise _fail(path, f"missing keys: {', '.join(missing)}")
    if not any(_is_exactly(payload["version"], int, version) for version in READABLE_VERSIONS):
        readable = " and ".join(map(str, READABLE_VERSIONS))
        raise _fail(path, f"format version {_short(payload['version'])}, this pghm reads versions {readable}")
    if not isinstance(payload["kind"], str) or payload["kind"] not in KINDS:
        raise _fail(path, f"unknown kind {_short(payload['kind'])}")
    try:
        config = ModelConfig.from_dict(payload["config"])
    except PghmError as error:
        raise _fail(path, str(error)) from None
    except (TypeError, AttributeError) as error:
        raise _fail(path, f"bad model config: {error}") from None

    weights = payload["weights"]
    if not isinstance(weights, dict) or "identity_bank" not in weights:
        raise _fail(path, "'weights' is not a network state dict")
    bank = weights["identity_bank"]
    if not isinstance(bank, Tensor) or bank.dim() != 4:
        raise _fail(path, "'weights.identity_bank' is not a (n, C, L', L') tensor")
    if payload["kind"] == "prior" and bank.shape[0] == 0:
        raise _fail(path, "a prior file must hold at least one identity")
    if payload["version"] == 1 and config.detail:
        raise _fail(path, "a format version 1 file cannot hold a detail layer")
    if payload["kind"] == "prior" and config.detail:
        raise _fail(path, "a prior file must not hold a detail layer (a fit adds one: pghm fit --detail-steps)")
    # The shapes the config implies, from a model on the meta device (no memory): a config
    # that asks for more than the file holds is rejected before anything is allocated.
    with torch.device("meta"):
        expected = PGHM(config, num_identities=bank.shape[0]).state_dict()
    missing_weights = sorted(set(expected) - set(weights))
    unexpected = sorted(set(weights) - set(expected), key=str)
    if missing_weights or unexpected:
        listed = ", ".join(map(str, (missing_weights or unexpected)[:3]))
        raise _fail(
            path, f"weights do not match the model config ({'missing' if missing_weights else 'unexpected'}: {listed})"
        )
    for name, tensor in expected.items():
        _check_tensor(path, f"weights.{name}", weights[name], tuple(tensor.shape))
    model = PGHM(config, num_identities=bank.shape[0])
    model.load_state_dict({k: v.float() for k, v in weights.items()})
    model.eval()

    body = payload["body"]
    if not isinstance(body, dict) or not isinstance(body.get("name"), str) or "shape" not in body:
        raise _fail(path, "'body' must hold a backend 'name' and a 'shape'")
    shape = _check_tensor(path, "body.shape", body["shape"], None)
    if shape.dim() != 1:
        raise _fail(path, f"'body.shape' has shape {tuple(shape.shape)}, expected (S,)")
    shapes = None
    if "shapes" in body:
        shapes = _check_tensor(path, "body.shapes", body["shapes"], (bank.shape[0], shape.shape[0]))
    for name, values in (("body.shape", shape), ("body.shapes", shapes)):
        problem = None if values is None else shape_problem(body["name"], values)
        if problem is not None:
            raise _fail(path, f"'{name}' {problem}")
    latent = payload["latent"]
    if payload["kind"] == "avatar":
        size = config.uv_resolution
        latent = _check_tensor(path, "latent", latent, (1, config.latent_channels, size, size))
    elif latent is not None:
        raise _fail(path, "a prior file must not hold a personal latent")
    metadata = payload["metadata"] if isinstance(payload["metadata"], dict) else {}
    return Avatar(
        model=model,
        kind=payload["kind"],
        body_name=body["name"],
        shape=shape,
        shapes=shapes,
        latent=latent,
        metadata=metadata,
        pose_track=_load_track(path, payload.get("pose_track")),
    )


def avatar_geometry(avatar: Avatar, index: int = 0, body_model_path: str | None = None):
    """The :class:`~pghm.model.geometry.SubjectGeometry` of identity ``index`` of ``avatar``, on its device.

    Args:
        avatar: a loaded avatar or prior.
        index: which identity of a prior (ignored for an avatar).
        body_model_path: the user's model file for bodies that are not embedded (SMPL-X).
    """
    from pghm.body import load_body
    from pghm.model.geometry import detail_atlas, subject_geometry
    from pghm.uv.atlas import build_atlas

    body = load_body(avatar.body_name, body_model_path)
    config = avatar.model.config
    atlas = build_atlas(body, config.uv_resolution)
    return move(subject_geometry(body, atlas, avatar.shape_of(index), detail_atlas(body, config)), avatar.device)
