"""LPIPS: weights come only from local files; missing files switch the term off with a reason."""

from __future__ import annotations

import torch

from pghm.train import lpips as lpips_module
from pghm.train.lpips import ALEX_CHANNELS, BACKBONE_FILE, LINEAR_FILE, alexnet_features, load_lpips, lpips_status


def write_weights(directory) -> tuple[dict, dict]:
    """Random weights in torchvision's AlexNet layout and the lpips package's linear layout."""
    torch.manual_seed(0)
    backbone = {f"features.{k}": v for k, v in alexnet_features().state_dict().items()}
    backbone["classifier.1.weight"] = torch.zeros(2, 2)  # torchvision files also hold the classifier
    linear = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1) for k, c in enumerate(ALEX_CHANNELS)}
    directory.mkdir(parents=True)
    torch.save(backbone, directory / BACKBONE_FILE)
    torch.save(linear, directory / LINEAR_FILE)
    return backbone, linear


def test_missing_weights_switch_lpips_off(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setattr(lpips_module.importlib.util, "find_spec", lambda name: None)
    assert load_lpips() is None
    assert lpips_status().startswith("LPIPS off") and BACKBONE_FILE in lpips_status()


def test_local_weights_are_loaded_and_used(tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    backbone, linear = write_weights(tmp_path / "hub" / "checkpoints")
    network = load_lpips()
    assert network is not None and lpips_status().startswith("LPIPS on")
    torch.testing.assert_close(network.features[0].weight, backbone["features.0.weight"])
    for k, lin in enumerate(network.lins):
        torch.testing.assert_close(lin.weight, linear[f"lin{k}.model.1.weight"])
    x = torch.rand(2, 3, 64, 64)
    y = (x + 0.2 * torch.randn_like(x)).clamp(0, 1)
    assert torch.equal(network(x, x), torch.zeros(2))
    distance = network(x, y)
    assert (distance > 0).all() and not any(p.requires_grad for p in network.parameters())
