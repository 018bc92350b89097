"""Model timings at the default config (targets, 2 threads):

    full forward, identity map -> posed Gaussians     <= 60 ms
    pose-only update (cached evaluator)               <= 35 ms
    view-only update (cached evaluator)               <= 20 ms

plus forward+backward of a training step's model part, the parameter count and the peak
memory (resident set of this process, measured around the model work). Inference runs its
convolutions channels-last (``PGHM.train(False)``); the "nchw (before)" row is the same model
with the NCHW layout it replaced, measured in the same run.

    python benchmarks/bench_model.py
"""

from __future__ import annotations

import resource

import torch
from common import load_average, median_ms, print_table, setup_threads, write_json

from pghm.body import BodyPose, load_body
from pghm.model import PGHM, ModelConfig, subject_geometry
from pghm.model.evaluator import CachedEvaluator
from pghm.model.pghm import set_conv_layout
from pghm.uv.atlas import build_atlas


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


LAYOUTS = {"channels_last": torch.channels_last, "nchw (before)": torch.contiguous_format}
"""Inference conv layouts: the model's eval default, and the NCHW baseline it replaced."""


def measure(model: PGHM, geometry, body, layout: str) -> dict:
    """Full, pose-only and view-only times of ``model`` in eval mode with convs in ``layout``."""
    model.eval()
    set_conv_layout(model, LAYOUTS[layout])
    gen = torch.Generator().manual_seed(0)
    poses = [BodyPose(torch.randn(1, body.num_bones, 3, generator=gen) * 0.3, torch.zeros(1, 3)) for _ in range(2)]
    cameras = [torch.tensor([0.0, 0.2, 3.0]), torch.tensor([1.5, 0.2, 2.6])]
    with torch.no_grad():
        identity = model.decode_identity(0)
        full = median_ms(lambda: model(model.decode_identity(0), geometry, poses[0], cameras[0][None]))
    evaluator = CachedEvaluator(model, geometry)
    evaluator.evaluate(identity, poses[0], cameras[0])
    flip = iter(range(10**9))

    def pose_update():
        evaluator.evaluate(identity, poses[next(flip) % 2], cameras[0])

    def view_update():
        evaluator.evaluate(identity, poses[0], cameras[next(flip) % 2])

    pose_ms = median_ms(pose_update)
    evaluator.evaluate(identity, poses[0], cameras[0])
    view_ms = median_ms(view_update)
    return {"full_ms": full, "pose_update_ms": pose_ms, "view_update_ms": view_ms}


def main() -> None:
    setup_threads()
    body = load_body()
    rows = []
    for head in ("multi", "single"):
        config = ModelConfig(head=head)
        geometry = subject_geometry(body, build_atlas(body, config.uv_resolution))
        model = PGHM(config, num_identities=8)
        for module in model.modules():  # non-zero heads, so no branch is trivially cheap
            if isinstance(module, torch.nn.Conv2d) and module.kernel_size == (1, 1):
                torch.nn.init.normal_(module.weight, std=0.01)
        rss_before = peak_rss_mb()
        layouts = list(LAYOUTS) if head == "multi" else ["channels_last"]
        times = {layout: measure(model, geometry, body, layout) for layout in layouts}
        model.train()
        gen = torch.Generator().manual_seed(1)
        batch_pose = BodyPose(torch.randn(4, body.num_bones, 3, generator=gen) * 0.3, torch.zeros(4, 3))
        batch_cams = torch.tensor([[0.0, 0.2, 3.0]] * 4)

        def train_step():
            out = model(model.decode_identity(0), geometry, batch_pose, batch_cams)
            (out.static.colors.mean() + out.dynamic.means.mean() + out.regularizer).backward()

        train_ms = median_ms(train_step, repeat=5, warmup=1)
        for layout, measured in times.items():
            rows.append(
                {
                    "head": head,
                    "inference_layout": layout,
                    "L": config.uv_resolution,
                    "gaussians": geometry.num_gaussians,
                    "params_M": sum(model.parameter_count().values()) / 1e6,
                    **measured,
                    "fwd_bwd_4views_ms": train_ms,
                    "peak_rss_MB": peak_rss_mb(),
                    "rss_before_MB": rss_before,
                }
            )
    print_table(rows)
    fast, before = (next(r for r in rows if r["head"] == "multi" and r["inference_layout"] == k) for k in LAYOUTS)
    print(
        "channels-last / nchw:",
        ", ".join(f"{k} {fast[k] / before[k]:.2f}" for k in ("full_ms", "pose_update_ms", "view_update_ms")),
    )
    load = load_average()
    print("targets: full <= 60 ms, pose update <= 35 ms, view update <= 20 ms; load average", load)
    counts = PGHM(ModelConfig(), num_identities=0).parameter_count()
    print("parameters per component (default config, no bank):", counts)
    write_json(
        "model",
        {
            "rows": rows,
            "parameter_count": counts,
            "targets_ms": {"full": 60, "pose": 35, "view": 20},
            "load_average": load,
        },
    )


if __name__ == "__main__":
    main()
