"""The PGHM network: identity bank, Feature Decoder, multi-head U-Net, posed Gaussians."""

from pghm.model.config import ModelConfig
from pghm.model.gaussians import Gaussians
from pghm.model.geometry import SubjectGeometry, subject_geometry
from pghm.model.pghm import PGHM, AvatarOutput

__all__ = ["PGHM", "AvatarOutput", "Gaussians", "ModelConfig", "SubjectGeometry", "subject_geometry"]
