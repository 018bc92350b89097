"""The Parametric Gaussian Human Model (paper section "Parametric Prior Model Training").

Data flow for one identity map F (C x L x L), a pose theta and a camera:

    F_u      = E_u(F)                                  identity pyramid (cached per F)
    U_p, U_s, U_c = D_static(F_u)                      static maps (cached per F)
    U_theta  = posed texel points scattered to L x L   (pghm.uv.maps)
    F_p      = E_p(pose map)                           pose map: U_theta in the root frame minus V_bar
    U_p^o, U_s^o = D_pose(F_u, F_p)
    F_v      = E_v([U_theta - root, V, N_theta])       V: view directions, N_theta: posed normals
    U_c^o    = D_view(F_u, F_v)

Gathering the maps at the valid texels gives per-Gaussian attributes (paper notation ->
code): V_p -> ``static_offset``, V_p^o -> ``pose_offset``, V_c -> ``static_color``,
V_c^o -> ``view_color``. With the texel points posed on the skinned mesh (pghm.uv.maps):

    V_sta = LBS(V_bar + V_p),            V_dyn = LBS(V_bar + V_p + V_p^o)
    V_p   = a_s tanh(U_p),               V_p^o = a_p tanh(U_p^o)            (bounded offsets)
    s_sta = base exp(ln r tanh(U_s)),    s_dyn = base exp(ln r tanh(U_s + U_s^o))
    c_sta = sigmoid(U_c),                c_dyn = sigmoid(U_c + U_c^o)
    opacity = 1, rotation = identity (isotropic Gaussians)

so scales stay within [base / r, base r] (never zero, negative or absurd) and colours in
(0, 1). ``base`` is ``base_scale_factor`` times the surface length a texel spans. With a
detail layer (``ModelConfig.detail``) the same formulas run on the 2L texels, on the network's
outputs upsampled and a trained per-texel colour residual and lift (:mod:`pghm.model.detail`).

The regulariser (the paper's L_reg, an L2 penalty keeping offsets near their initial
values) is, with u = ``REG_POSITION_UNIT``:

    L_reg = mean |V_p|^2 / u^2 + mean |V_p^o|^2 / u^2 + mean (ln s_sta/base)^2 + mean (ln s_dyn/base)^2
"""

from __future__ import annotations

import contextlib
import math
from collections import Counter
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from pghm.body.pose import BodyPose
from pghm.body.skinning import blend_transform_deltas, rotate_directions
from pghm.errors import PghmError
from pghm.model.config import ModelConfig
from pghm.model.detail import LIFT_CHANNEL, DetailLayer, DetailSkinned, pose_detail, upsample
from pghm.model.gaussians import Gaussians
from pghm.model.geometry import SubjectGeometry
from pghm.model.networks import FeatureDecoder, Pyramid, PyramidDecoder, PyramidEncoder
from pghm.uv.atlas import UVAtlas
from pghm.uv.maps import gather_from_map, posed_points, scatter_to_map, view_directions

STATIC_CHANNELS = 7
"""D_static outputs: position offset (3), log-scale (1), colour logits (3)."""
POSE_CHANNELS = 4
"""D_pose outputs: position offset (3), log-scale offset (1)."""
VIEW_CHANNELS = 3
"""D_view outputs: colour logit offset (3)."""
POSE_INPUT_CHANNELS = 3
"""E_p input: posed texel points in the root frame, minus the canonical points."""
VIEW_INPUT_CHANNELS = 9
"""E_v input: posed points relative to the root joint (3), view directions (3), posed normals (3)."""
REG_POSITION_UNIT = 0.05
"""Length (metres) at which a position offset costs as much as an e-fold scale change: loose
clothes sit a few centimetres off the body, which this should not fight."""
LATENT_INIT_STD = 0.01
"""Standard deviation of a new identity latent."""

COMPONENTS = (
    "feature_decoder",
    "unet_encoder",
    "static_decoder",
    "pose_encoder",
    "pose_decoder",
    "view_encoder",
    "view_decoder",
    "single_decoder",
)
"""Submodules whose runs :attr:`PGHM.run_counts` counts (to prove what a cached update skips)."""


def set_conv_layout(module: nn.Module, layout: torch.memory_format) -> None:
    """Store every Conv2d weight of ``module`` in ``layout`` (same values, other strides)."""
    for conv in module.modules():
        if isinstance(conv, nn.Conv2d):
            conv.weight.data = conv.weight.data.contiguous(memory_format=layout)


@dataclass
class IdentityFeatures:
    """What depends only on the identity map: the E_u pyramid and (multi-head) D_static's maps.

    Attributes:
        skips: E_u pyramid, batch 1 or B.
        static: (1 or B, 7, L, L) D_static output, or None for the single-head model.
    """

    skips: Pyramid
    static: Tensor | None


@dataclass
class Skinned:
    """The posed body at the texels: everything skinning gives, no network involved.

    Attributes:
        transforms: (B, J, 4, 4) skinning transforms.
        surface_points: (B, N, 3) posed texel points on the skinned mesh (U_theta's values).
        rotation_delta: (B, N, 3, 3) blended rotation minus identity, for offsets.
        normals: (B, N, 3) posed unit normals.
        root: (B, 3) posed root joint.
        pose_input: (B, 3, L, L) E_p's input: U_theta in the root frame minus V_bar.
        detail: the posed 2L texels of a model with a detail layer, else None.
    """

    transforms: Tensor
    surface_points: Tensor
    rotation_delta: Tensor
    normals: Tensor
    root: Tensor
    pose_input: Tensor
    detail: DetailSkinned | None = None

    def select(self, index: Tensor) -> Skinned:
        """The poses ``index`` (B,) of this batch, e.g. one per view of a shared pose."""
        return Skinned(
            *(
                field[index]
                for field in (
                    self.transforms,
                    self.surface_points,
                    self.rotation_delta,
                    self.normals,
                    self.root,
                    self.pose_input,
                )
            ),
            detail=None if self.detail is None else self.detail.select(index),
        )

    @property
    def gaussian_normals(self) -> Tensor:
        """(B, N, 3) posed unit normals at the Gaussians' texels (the 2L texels' with a detail layer)."""
        return self.normals if self.detail is None else self.detail.normals


@dataclass
class PoseBranch:
    """E_p's pyramid and (multi-head) D_pose's maps (B, 4, L, L), None for the single head."""

    features: Pyramid
    maps: Tensor | None

    def select(self, index: Tensor) -> PoseBranch:
        """The poses ``index`` (B,) of this batch."""
        return PoseBranch([f[index] for f in self.features], None if self.maps is None else self.maps[index])


@dataclass
class AvatarOutput:
    """Both Gaussian sets of the paper and the regulariser.

    Attributes:
        static: Gaussians of V_sta with colours V_c (rendered as I_s).
        dynamic: Gaussians of V_dyn with colours V_c + V_c^o (rendered as I_d).
        regularizer: () the L_reg value.
    """

    static: Gaussians
    dynamic: Gaussians
    regularizer: Tensor


class PGHM(nn.Module):
    """Identity bank, Feature Decoder and the (multi- or single-head) U-Net.

    Args:
        config: sizes and bounds.
        num_identities: n, latents in the bank (0 for a personalised avatar, which carries a
            full-resolution latent of its own instead).
    """

    def __init__(self, config: ModelConfig, num_identities: int) -> None:
        super().__init__()
        self.config = config
        channels = config.latent_channels
        size = config.latent_resolution
        self.identity_bank = nn.Parameter(torch.randn(num_identities, channels, size, size) * LATENT_INIT_STD)
        self.feature_decoder = FeatureDecoder(channels)
        self.unet_encoder = PyramidEncoder(channels, config.encoder_channels)
        self.pose_encoder = PyramidEncoder(POSE_INPUT_CHANNELS, config.condition_channels, light=True)
        self.view_encoder = PyramidEncoder(VIEW_INPUT_CHANNELS, config.condition_channels, light=True)
        skip, cond, up = config.encoder_channels, config.condition_channels, config.decoder_channels
        if config.head == "multi":
            no_condition = tuple(0 for _ in skip)
            self.static_decoder = PyramidDecoder(skip, no_condition, up, STATIC_CHANNELS)
            self.pose_decoder = PyramidDecoder(skip, cond, up, POSE_CHANNELS)
            self.view_decoder = PyramidDecoder(skip, cond, up, VIEW_CHANNELS)
        else:
            both = tuple(2 * c for c in cond)
            self.single_decoder = PyramidDecoder(skip, both, up, STATIC_CHANNELS + POSE_CHANNELS + VIEW_CHANNELS)
        self.detail = DetailLayer(config.uv_resolution) if config.detail else None
        self.compute_dtype = torch.float32
        self.run_counts: Counter[str] = Counter()
        for name in COMPONENTS:
            if hasattr(self, name):
                getattr(self, name).register_forward_hook(self._counter(name))

    def _counter(self, name: str):
        def hook(module, inputs, output):
            self.run_counts[name] += 1

        return hook

    def train(self, mode: bool = True) -> PGHM:
        """Set training or inference mode, and lay the convolution weights out for it.

        Inference runs every convolution channels-last (NHWC), which oneDNN executes about
        20 % faster on this CPU (benchmarks/bench_model.py, its "inference_layout" rows); the activations
        follow the weights' layout. Training in float32 keeps the default NCHW, whose backward pass is
        faster; in bfloat16 channels-last is faster both ways. The values are the same either way;
        only the strides differ.
        """
        super().train(mode)
        nchw = mode and self.compute_dtype == torch.float32
        set_conv_layout(self, torch.contiguous_format if nchw else torch.channels_last)
        return self

    def set_precision(self, dtype: torch.dtype) -> PGHM:
        """Run the convolutions in ``dtype``: float32, or bfloat16 under autocast (the weights, the
        heads and everything after them stay float32). On a CPU that multiplies bfloat16 natively a
        forward and backward pass runs 1.5-1.7 times as fast (docs/training.md, "bfloat16 where the CPU
        multiplies it natively"); the values differ by bfloat16's rounding (8 bits of mantissa) in the
        features, not in the stored weights."""
        if dtype not in (torch.float32, torch.bfloat16):
            raise PghmError(f"the model computes in float32 or bfloat16, not {dtype}")
        self.compute_dtype = dtype
        return self.train(self.training)

    def compute_context(self) -> contextlib.AbstractContextManager:
        """The context the convolutional networks run in: autocast to :attr:`compute_dtype`."""
        if self.compute_dtype == torch.float32:
            return contextlib.nullcontext()  # autocast refuses some devices even disabled (meta)
        return torch.autocast(self.identity_bank.device.type, dtype=self.compute_dtype)

    def at_resolution(self, uv_resolution: int) -> PGHM:
        """This model with UV maps of side ``uv_resolution`` (a new model; this one is unchanged).

        Every network is convolutional, so its weights carry over as they are; only the
        identity bank (N, C, L', L') is resized, bilinearly, to the new L' = L / 2. A bank
        latent therefore decodes to the same smooth identity map sampled more finely, and
        there are (L_new / L)^2 times as many Gaussians, each a texel's size smaller. The
        networks' receptive fields shrink by L / L_new measured on the body, which is why
        a fit at another L than its prior's trains the networks too (stage 2 of ``pghm fit``).
        """
        config = replace(self.config, uv_resolution=uv_resolution)
        model = PGHM(config, num_identities=self.num_identities)
        weights = self.state_dict()
        size = config.latent_resolution
        weights["identity_bank"] = F.interpolate(
            weights["identity_bank"], size=(size, size), mode="bilinear", align_corners=False
        )
        model.load_state_dict(weights)
        model.compute_dtype = self.compute_dtype  # checked when this model's was set
        return model.train(self.training)

    def with_detail(self) -> PGHM:
        """This model with a zero detail layer (:mod:`pghm.model.detail`; a new model, this one unchanged)."""
        model = PGHM(replace(self.config, detail=True), num_identities=self.num_identities)
        model.load_state_dict({**self.state_dict(), "detail.maps": model.detail.maps.detach()})
        model.compute_dtype = self.compute_dtype  # checked when this model's was set
        return model.train(self.training)

    @property
    def num_identities(self) -> int:
        return self.identity_bank.shape[0]

    @property
    def multi_head(self) -> bool:
        return self.config.head == "multi"

    # Stage 0: the identity map.
    def decode_identity(self, index: int | Tensor) -> Tensor:
        """F (B, C, L, L) of bank latents ``index`` (an int or a (B,) long tensor)."""
        latents = self.identity_bank[index] if isinstance(index, Tensor) else self.identity_bank[index : index + 1]
        return self.feature_decoder(latents)

    def decode_latent(self, latent: Tensor) -> Tensor:
        """F (B, C, L, L) of compact latents (B, C, L', L') (e.g. a blend of bank latents)."""
        return self.feature_decoder(latent)

    # Stage 1: everything that depends only on F.
    def identity_features(self, identity_map: Tensor) -> IdentityFeatures:
        """E_u and D_static on an identity map (1 or B, C, L, L)."""
        skips = self.unet_encoder(identity_map)
        static = self.static_decoder(skips) if self.multi_head else None
        return IdentityFeatures(skips, static)

    # Stage 2: everything that depends on the pose.
    def skin(self, geometry: SubjectGeometry, pose: BodyPose) -> Skinned:
        """Skinning and U_theta for a batch of B poses (no network)."""
        surface = geometry.surface
        transforms = geometry.transforms(pose)
        points = posed_points(surface, transforms)
        rotation_delta = blend_transform_deltas(surface.weights, transforms)[..., :3]
        normals = rotate_directions(surface.normals, rotation_delta)  # one blend of the weights for both
        root_rotation, root_translation = transforms[:, 0, :3, :3], transforms[:, 0, :3, 3]
        root = root_rotation @ geometry.joints[0].to(points.dtype) + root_translation
        # U_theta in the root frame: A_root^-1 x = R^T (x - t), minus V_bar (zero at rest).
        in_root = (points - root_translation[:, None]) @ root_rotation
        pose_input = scatter_to_map(in_root - surface.positions, geometry.atlas)
        detail = self._skin_detail(geometry, transforms) if self.detail is not None else None
        return Skinned(transforms, points, rotation_delta, normals, root, pose_input, detail)

    @staticmethod
    def _skin_detail(geometry: SubjectGeometry, transforms: Tensor) -> DetailSkinned:
        """The 2L texels posed by (B, J, 4, 4) ``transforms``, as :meth:`skin` poses the L texels."""
        if geometry.detail is None:
            raise PghmError("the model has a detail layer; its subject geometry was built without the 2L atlas")
        return pose_detail(geometry.detail.surface, transforms)

    def pose_branch(self, features: IdentityFeatures, skinned: Skinned) -> PoseBranch:
        """E_p, and D_pose for the multi-head model."""
        pose_features = self.pose_encoder(skinned.pose_input)
        maps = self.pose_decoder(features.skips, pose_features) if self.multi_head else None
        return PoseBranch(pose_features, maps)

    # Stage 3: everything that depends on the camera.
    def view_branch(
        self,
        features: IdentityFeatures,
        skinned: Skinned,
        pose: PoseBranch,
        geometry: SubjectGeometry,
        camera_centres: Tensor,
    ) -> Tensor:
        """E_v and D_view for (B, 3) camera centres: (B, 3, L, L), or all 14 single-head maps."""
        points = skinned.surface_points
        directions = view_directions(points, camera_centres.to(points.dtype))
        relative = points - skinned.root[:, None]
        view_input = scatter_to_map(torch.cat([relative, directions, skinned.normals], -1), geometry.atlas)
        view_features = self.view_encoder(view_input)
        if self.multi_head:
            return self.view_decoder(features.skips, view_features)
        condition = [torch.cat([p, v], 1) for p, v in zip(pose.features, view_features)]
        return self.single_decoder(features.skips, condition)

    # Stage 4: maps -> Gaussians.
    def assemble(
        self,
        features: IdentityFeatures,
        skinned: Skinned,
        pose: PoseBranch | None,
        view: Tensor | None,
        geometry: SubjectGeometry,
    ) -> AvatarOutput:
        """Gather the maps at the valid texels and build both Gaussian sets.

        For the multi-head model, ``pose=None`` leaves out the pose-dependent offsets and
        ``view=None`` the view-dependent colour (the dynamic set then equals the static one
        in what is left out). The single-head model needs ``view``, which holds every output.
        """
        batch = skinned.surface_points.shape[0]
        static, pose_out, view_offset = self._gather(features, pose, view, geometry.atlas, batch)
        if self.detail is not None:
            return self._detail_gaussians(static, pose_out, view_offset, skinned, geometry)
        return self._gaussians(
            static, pose_out, view_offset, skinned.surface_points, skinned.rotation_delta, geometry.texel_length
        )

    def _gather(
        self, features: IdentityFeatures, pose: PoseBranch | None, view: Tensor | None, atlas: UVAtlas, batch: int
    ) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """The network outputs at the valid texels: static (B, N, 7), pose (B, N, 4) and view (B, N, 3)
        (the multi-head model's pose or view None where its branch was left out)."""
        if self.multi_head:
            static = gather_from_map(features.static, atlas).expand(batch, -1, -1)
            pose_out = gather_from_map(pose.maps, atlas) if pose is not None else None
            view_offset = gather_from_map(view, atlas) if view is not None else None
            return static, pose_out, view_offset
        return gather_from_map(view, atlas).split([STATIC_CHANNELS, POSE_CHANNELS, VIEW_CHANNELS], -1)

    def _detail_gaussians(
        self,
        static: Tensor,
        pose_out: Tensor | None,
        view_offset: Tensor | None,
        skinned: Skinned,
        geometry: SubjectGeometry,
    ) -> AvatarOutput:
        """Both Gaussian sets on the 2L texels: the network outputs upsampled, the detail residuals
        added (:mod:`pghm.model.detail`)."""
        detail = geometry.detail
        static, pose_out, view_offset = (
            None if values is None else upsample(values, detail) for values in (static, pose_out, view_offset)
        )
        residual = gather_from_map(self.detail.maps, detail.atlas)  # (1, N2, 5)
        # The log-scale and colour residuals join D_static's channels 3..6; the offsets get none.
        static = static + F.pad(residual[..., :LIFT_CHANNEL], (STATIC_CHANNELS - LIFT_CHANNEL, 0))
        lift = self.config.max_detail_offset * torch.tanh(residual[..., LIFT_CHANNEL:]) * skinned.detail.normals
        return self._gaussians(
            static,
            pose_out,
            view_offset,
            skinned.detail.surface_points + lift,
            skinned.detail.rotation_delta,
            detail.texel_length,
        )

    def _gaussians(
        self,
        static: Tensor,
        pose_out: Tensor | None,
        view_offset: Tensor | None,
        surface_points: Tensor,
        rotation_delta: Tensor,
        texel_length: Tensor,
    ) -> AvatarOutput:
        """The paper's activations (module docstring) on per-texel network outputs (B, N, C) at
        texels posed at ``surface_points`` (B, N, 3) with ``rotation_delta`` (B, N, 3, 3), whose
        base scale follows ``texel_length`` (N,)."""
        config = self.config
        log_range = math.log(config.scale_factor_range)
        static_offset = config.max_static_offset * torch.tanh(static[..., 0:3])
        static_log_scale = log_range * torch.tanh(static[..., 3])
        if pose_out is not None:
            pose_offset = config.max_pose_offset * torch.tanh(pose_out[..., 0:3])
            dynamic_log_scale = log_range * torch.tanh(static[..., 3] + pose_out[..., 3])
        else:
            pose_offset = torch.zeros_like(static_offset)
            dynamic_log_scale = static_log_scale
        color_logit = static[..., 4:7]
        dynamic_logit = color_logit + view_offset if view_offset is not None else color_logit
        base = (config.base_scale_factor * texel_length).clamp(config.min_scale, config.max_scale)
        base = base.to(static.dtype)

        def place(offset: Tensor) -> Tensor:
            return surface_points + offset + (rotation_delta @ offset[..., None])[..., 0]

        def scales(log_scale: Tensor) -> Tensor:
            return (base * torch.exp(log_scale)).clamp(config.min_scale, config.max_scale)

        opacities = torch.ones(surface_points.shape[:2], dtype=static.dtype, device=static.device)
        regularizer = (
            static_offset.square().sum(-1).mean() / REG_POSITION_UNIT**2
            + pose_offset.square().sum(-1).mean() / REG_POSITION_UNIT**2
            + static_log_scale.square().mean()
            + dynamic_log_scale.square().mean()
        )
        return AvatarOutput(
            static=Gaussians(place(static_offset), scales(static_log_scale), torch.sigmoid(color_logit), opacities),
            dynamic=Gaussians(
                place(static_offset + pose_offset),
                scales(dynamic_log_scale),
                torch.sigmoid(dynamic_logit),
                opacities,
            ),
            regularizer=regularizer,
        )

    def forward(
        self,
        identity_map: Tensor,
        geometry: SubjectGeometry,
        pose: BodyPose,
        camera_centres: Tensor,
        pose_index: Tensor | None = None,
    ) -> AvatarOutput:
        """Full evaluation for B views.

        Args:
            identity_map: (1 or B, C, L, L).
            pose: P poses; P = B unless ``pose_index`` is given.
            camera_centres: (B, 3).
            pose_index: (B,) which of the P poses each view shows. Views of one instant
                (multi-view data) then share the skinning and the pose branch, which run
                once per pose instead of once per view.
        """
        with self.compute_context():
            features = self.identity_features(identity_map)
        return self.posed(features, geometry, pose, camera_centres, pose_index)

    def posed(
        self,
        features: IdentityFeatures,
        geometry: SubjectGeometry,
        pose: BodyPose,
        camera_centres: Tensor,
        pose_index: Tensor | None = None,
    ) -> AvatarOutput:
        """:meth:`forward` from an identity's features (:meth:`identity_features`, computed in
        :meth:`compute_context`): all of it that depends on the pose and the cameras. A frozen
        avatar's pose refinement runs E_u and D_static once and this at every step."""
        skinned = self.skin(geometry, pose)
        with self.compute_context():
            pose_branch = self.pose_branch(features, skinned)
            if pose_index is not None:
                skinned, pose_branch = skinned.select(pose_index), pose_branch.select(pose_index)
            view = self.view_branch(features, skinned, pose_branch, geometry, camera_centres)
        return self.assemble(features, skinned, pose_branch, view, geometry)

    def parameter_count(self) -> dict[str, int]:
        """Trainable parameters per component (the bank counted apart)."""
        counts = {"identity_bank": self.identity_bank.numel()}
        for name in COMPONENTS:
            if hasattr(self, name):
                counts[name] = sum(p.numel() for p in getattr(self, name).parameters())
        return counts
