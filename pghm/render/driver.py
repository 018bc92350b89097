"""The model-evaluation side: an avatar driven frame by frame to plain Gaussian arrays.

:class:`AvatarDriver` turns an identity map, a pose and a camera centre into
:class:`GaussianArrays` (float32 numpy, what both frame renderers and the viewer consume)
through :class:`~pghm.model.evaluator.CachedEvaluator`, so only the branches whose inputs
changed re-run, and times the model and skinning stages (:class:`StageTimes`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from pghm.device import move
from pghm.errors import PghmError

GaussianSet = Literal["dynamic", "static"]


@dataclass(frozen=True)
class GaussianArrays:
    """One frame's Gaussians as plain float32 numpy arrays (what the renderers consume).

    Attributes:
        means: (N, 3) world positions.
        scales: (N,) isotropic standard deviations, metres.
        colors: (N, 3) RGB in [0, 1].
        opacities: (N,) in (0, 1].
        normals: (N, 3) posed unit surface normals at the Gaussians' texels.
    """

    means: np.ndarray
    scales: np.ndarray
    colors: np.ndarray
    opacities: np.ndarray
    normals: np.ndarray

    @property
    def count(self) -> int:
        return self.means.shape[0]


@dataclass
class StageTimes:
    """Milliseconds of the last :meth:`AvatarDriver.evaluate`.

    Attributes:
        model_ms: the network branches that re-ran and assembling the Gaussians (skinning excluded).
        skinning_ms: forward kinematics and LBS of the texel surface (0 when the pose was unchanged).
    """

    model_ms: float = 0.0
    skinning_ms: float = 0.0


class _TimedModel:
    """The model as :class:`CachedEvaluator` sees it, timing ``skin`` and keeping its output.

    Every other attribute is the wrapped :class:`~pghm.model.pghm.PGHM`'s. The evaluator
    calls ``skin`` exactly when the pose changed, so ``skinned`` is the current pose's.
    """

    def __init__(self, model) -> None:
        self._model = model
        self.skinning_ms = 0.0
        self.skinned = None

    def skin(self, geometry, pose):
        start = time.perf_counter()
        self.skinned = self._model.skin(geometry, pose)
        self.skinning_ms += (time.perf_counter() - start) * 1e3
        return self.skinned

    def __getattr__(self, name: str):
        return getattr(self._model, name)


class AvatarDriver:
    """An avatar or prior driven frame by frame: identity map, pose, camera -> :class:`GaussianArrays`.

    Set-up builds the body, the subject geometry of identity ``index`` (its body shape) and a
    :class:`~pghm.model.evaluator.CachedEvaluator`; :meth:`evaluate` re-runs only what
    changed and returns the same :class:`GaussianArrays` object when nothing did. The network
    runs on the avatar's device; poses and camera centres come from the CPU and the arrays go
    back there.

    Args:
        avatar: a loaded :class:`~pghm.io.avatar.Avatar`, on the device to evaluate it on.
        index: identity of a prior whose body shape to use (ignored for an avatar).
        body_model_path: the model file of bodies that are not embedded (SMPL-X).
    """

    def __init__(self, avatar, index: int = 0, body_model_path: str | None = None) -> None:
        from pghm.body import load_body
        from pghm.io.avatar import avatar_geometry
        from pghm.model.evaluator import CachedEvaluator

        self.avatar = avatar
        self.index = index
        self.body = load_body(avatar.body_name, body_model_path)
        self.geometry = avatar_geometry(avatar, index, body_model_path)
        self.rest = self.body.rest(self.geometry.shape.cpu())
        self._timed = _TimedModel(avatar.model)
        self.evaluator = CachedEvaluator(self._timed, self.geometry)
        self.times = StageTimes()
        self._key: tuple | None = None  # (evaluator output, which set) the arrays were made from
        self._arrays: GaussianArrays | None = None

    @property
    def model(self):
        """The avatar's network (:class:`~pghm.model.pghm.PGHM`), e.g. for ``run_counts``."""
        return self.avatar.model

    def rest_pose(self):
        """The canonical rest pose (1, J, 3), (1, 3) of the body."""
        from pghm.body import BodyPose

        return BodyPose.rest(self.body.num_bones)

    @torch.no_grad()
    def evaluate(
        self,
        identity_map: Tensor,
        pose,
        camera_centre: Tensor | np.ndarray,
        gaussians: GaussianSet = "dynamic",
        view_dependent: bool = True,
        interrupt: Callable[[], bool] | None = None,
    ) -> GaussianArrays:
        """The Gaussians of ``identity_map`` (1, C, L, L) in ``pose`` (1 pose) seen from ``camera_centre`` (3,).

        ``gaussians`` picks the paper's static set V_sta (image I_s) or dynamic set V_dyn
        (I_d); ``view_dependent=False`` drops the view-dependent colour V_c^o (D_view is
        then not run). ``interrupt``: see :meth:`CachedEvaluator.evaluate
        <pghm.model.evaluator.CachedEvaluator.evaluate>` (raises ``Interrupted``).
        """
        if gaussians not in ("dynamic", "static"):
            raise PghmError(f"gaussians must be 'dynamic' or 'static', got {gaussians!r}")
        start = time.perf_counter()
        self._timed.skinning_ms = 0.0
        device = self.avatar.device
        centre = torch.as_tensor(np.asarray(camera_centre, dtype=np.float32), device=device)
        dynamic = gaussians == "dynamic"
        output = self.evaluator.evaluate(
            identity_map,
            move(pose, device),
            centre,
            dynamic=dynamic,
            view_dependent=dynamic and view_dependent,
            interrupt=interrupt,
        )
        # The same output object means nothing re-ran; the single-head model returns it for
        # either set, so the set is part of the key.
        if self._key is None or self._key[0] is not output or self._key[1] != dynamic:
            chosen = move(output.dynamic if dynamic else output.static, torch.device("cpu"))
            self._arrays = GaussianArrays(
                means=chosen.means[0].numpy().astype(np.float32),
                scales=chosen.scales[0].numpy().astype(np.float32),
                colors=chosen.colors[0].numpy().astype(np.float32),
                opacities=chosen.opacities[0].numpy().astype(np.float32),
                normals=self._timed.skinned.gaussian_normals[0].cpu().numpy().astype(np.float32),
            )
            self._key = (output, dynamic)
        total = (time.perf_counter() - start) * 1e3
        self.times = StageTimes(model_ms=total - self._timed.skinning_ms, skinning_ms=self._timed.skinning_ms)
        return self._arrays

    def root_position(self, pose) -> np.ndarray:
        """(3,) the posed root joint of a 1-pose BodyPose (for cameras that follow the body)."""
        transforms = self.geometry.transforms(move(pose, self.avatar.device))[0, 0]
        root = transforms[:3, :3] @ self.geometry.joints[0] + transforms[:3, 3]
        return root.cpu().numpy().astype(np.float64)
