"""Identity edits: what the identity map F (1, C, L, L) fed to the model is built from.

For a prior (a bank of n compact latents z_i, (C, L', L') each, L' = L / 2):

    z = (1 - w) z_a + w z_b + sum_k a_k sigma_k v_k          (blend, then PCA sliders)
    F = FeatureDecoder(z) * G                                  (G: per-region gains)

with v_k the principal directions of the flattened bank latents and sigma_k their standard
deviations (computed once, :func:`bank_pca`), so a slider value a_k is in standard
deviations of the bank. For a personalised avatar F is its own latent (1, C, L, L) times G;
blend and PCA do not apply. G (1, 1, L, L) is one gain per body region of the UV atlas
(:mod:`pghm.uv.regions`), 1 on texels outside every island.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from pghm.errors import PghmError
from pghm.uv.regions import RegionMap

MAX_COMPONENTS = 6
"""PCA sliders shown (at most n - 1 exist for n bank latents)."""
COMPONENT_RANGE = 3.0
"""PCA sliders span +-this many standard deviations."""
GAIN_RANGE = (0.0, 3.0)
"""Per-region latent gain slider range."""


@dataclass(frozen=True)
class BankPCA:
    """Principal components of the bank latents, flattened to D = C L' L'.

    Attributes:
        mean: (D,) mean latent.
        components: (K, D) orthonormal principal directions v_k, largest variance first.
        stds: (K,) standard deviation sigma_k of the bank along each direction.
    """

    mean: np.ndarray
    components: np.ndarray
    stds: np.ndarray


def bank_pca(bank: Tensor, max_components: int = MAX_COMPONENTS) -> BankPCA:
    """PCA of bank latents (n, C, L', L'): SVD of the centred (n, D) matrix X - mean = U S V^T.

    sigma_k = S_k / sqrt(n - 1); directions with sigma_k ~ 0 (rank deficiency) are dropped.
    """
    flat = bank.detach().reshape(bank.shape[0], -1).double().numpy()
    mean = flat.mean(axis=0)
    if flat.shape[0] < 2:
        return BankPCA(mean, np.zeros((0, flat.shape[1])), np.zeros(0))
    _, singular, directions = np.linalg.svd(flat - mean, full_matrices=False)
    stds = singular / np.sqrt(flat.shape[0] - 1)
    keep = min(max_components, int((stds > stds[0] * 1e-6).sum()))
    return BankPCA(mean, directions[:keep], stds[:keep])


@dataclass(frozen=True)
class IdentityState:
    """The identity edits as a value: bank entries a and b, blend weight, PCA coefficients, region gains."""

    index_a: int
    index_b: int
    blend: float
    coefficients: tuple[float, ...]
    gains: tuple[float, ...]


class IdentityEditor:
    """The identity state of the viewer and the identity map it gives.

    Args:
        avatar: a loaded avatar or prior.
        regions: the body regions of its UV atlas.
    """

    def __init__(self, avatar, regions: RegionMap) -> None:
        self.avatar = avatar
        self.regions = regions
        self.is_prior = avatar.kind == "prior"
        self.pca = bank_pca(avatar.model.identity_bank) if self.is_prior else None
        self.reset()

    @property
    def num_identities(self) -> int:
        return self.avatar.model.num_identities if self.is_prior else 1

    @property
    def num_components(self) -> int:
        return 0 if self.pca is None else len(self.pca.stds)

    def reset(self) -> None:
        """Identity 0, no blend, every PCA slider at 0 and every region gain at 1."""
        self.index_a = 0
        self.index_b = 0
        self.blend = 0.0
        self.coefficients = np.zeros(self.num_components)
        self.gains = np.ones(len(self.regions.names))
        self._key: IdentityState | None = None
        self._map: Tensor | None = None

    def pick(self, index: int) -> None:
        """Show bank identity ``index`` (a prior only)."""
        self._require_prior("picking an identity")
        self._check_index(index)
        self.index_a = index

    def set_blend(self, index_b: int, weight: float) -> None:
        """Blend towards identity ``index_b`` with ``weight`` in [0, 1] (0: identity a alone)."""
        self._require_prior("blending identities")
        self._check_index(index_b)
        if not 0.0 <= weight <= 1.0:
            raise PghmError(f"blend weight must be in [0, 1], got {weight}")
        self.index_b, self.blend = index_b, float(weight)

    def set_component(self, k: int, value: float) -> None:
        """PCA slider ``k`` to ``value`` standard deviations."""
        self._require_prior("moving along the principal components")
        if not 0 <= k < self.num_components:
            raise PghmError(f"principal component must be in [0, {self.num_components}), got {k}")
        self.coefficients[k] = float(value)

    def set_region_gain(self, region: str | int, gain: float) -> None:
        """Multiply the identity map on ``region`` by ``gain``.

        ``region`` is a name of :data:`~pghm.uv.regions.REGION_NAMES` or its index.
        """
        index = self.regions.names.index(region) if isinstance(region, str) else int(region)
        if not 0 <= index < len(self.regions.names):
            raise PghmError(f"unknown region {region!r}")
        if not GAIN_RANGE[0] <= gain <= GAIN_RANGE[1]:
            raise PghmError(f"region gain must be in [{GAIN_RANGE[0]}, {GAIN_RANGE[1]}], got {gain}")
        self.gains[index] = float(gain)

    def state(self) -> IdentityState:
        """The current edits as an immutable value (what a model request carries)."""
        return IdentityState(
            self.index_a, self.index_b, self.blend, tuple(self.coefficients.tolist()), tuple(self.gains.tolist())
        )

    def identity_map(self) -> Tensor:
        """F (1, C, L, L) of the current state; recomputed only when the state changed."""
        return self.map_of(self.state())

    def map_of(self, state: IdentityState) -> Tensor:
        """F (1, C, L, L) of ``state``; the last one is kept (the viewer's model worker is the only caller)."""
        if state != self._key:
            with torch.no_grad():
                gains = torch.tensor(state.gains, dtype=torch.float64)
                self._map = self._base_map(state) * self.regions.gain_map(gains)
            self._key = state
        return self._map

    def _base_map(self, state: IdentityState) -> Tensor:
        if not self.is_prior:
            return self.avatar.latent
        bank = self.avatar.model.identity_bank.detach()
        latent = (1.0 - state.blend) * bank[state.index_a] + state.blend * bank[state.index_b]
        coefficients = np.array(state.coefficients)
        if self.num_components and coefficients.any():
            # sum_k a_k sigma_k v_k, reshaped to the latent's (C, L', L')
            edit = (coefficients * self.pca.stds) @ self.pca.components
            latent = latent + torch.from_numpy(edit).to(latent.dtype).view_as(latent)
        return self.avatar.model.decode_latent(latent[None])

    def _require_prior(self, what: str) -> None:
        if not self.is_prior:
            raise PghmError(f"{what} needs a prior (a bank of identities); this file is a personalised avatar")

    def _check_index(self, index: int) -> None:
        if not 0 <= index < self.num_identities:
            raise PghmError(f"identity must be in [0, {self.num_identities}), got {index}")
