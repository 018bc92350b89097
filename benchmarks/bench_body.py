"""Foundation timings: posed UV position map, atlas from cache, texel surface, body rest.

Targets: posed UV position map at L = 128 in at most 10 ms on 2 threads; atlas
build from cache in at most 50 ms.

    python benchmarks/bench_body.py
"""

from __future__ import annotations

import torch
from common import median_ms, print_table, setup_threads, write_json

from pghm.body import BodyPose, load_body
from pghm.uv import atlas as atlas_module
from pghm.uv.atlas import build_atlas
from pghm.uv.maps import texel_surface, uv_position_map, view_direction_map


def main() -> None:
    setup_threads()
    body = load_body()
    rest = body.rest()
    rows = []
    for resolution in (64, 128, 256):
        build_atlas(body, resolution)  # populate the disk cache

        def from_disk(resolution=resolution):
            atlas_module._MEMORY_CACHE.clear()
            return build_atlas(body, resolution)

        atlas = build_atlas(body, resolution)
        surface = texel_surface(body, atlas, rest)
        pose = BodyPose(torch.randn(1, body.num_bones, 3) * 0.3, torch.zeros(1, 3))

        def position_map():
            transforms = body.bone_transforms(pose, rest.joints)
            return uv_position_map(surface, atlas, transforms)

        def view_map():
            transforms = body.bone_transforms(pose, rest.joints)
            return view_direction_map(surface, atlas, transforms, torch.tensor([[0.0, 0.0, 3.0]]))

        rows.append(
            {
                "L": resolution,
                "texels": atlas.num_texels,
                "atlas_from_cache_ms": median_ms(from_disk, repeat=10),
                "atlas_raster_ms": median_ms(
                    lambda: atlas_module.rasterize_uv(body.uv_coords.numpy(), body.uv_faces.numpy(), resolution),
                    repeat=3,
                    warmup=1,
                ),
                "texel_surface_ms": median_ms(lambda: texel_surface(body, atlas, rest)),
                "posed_position_map_ms": median_ms(position_map),
                "view_direction_map_ms": median_ms(view_map),
            }
        )
    rows.append({"L": "-", "texels": "body.rest()", "atlas_from_cache_ms": median_ms(lambda: body.rest())})
    print_table(rows)
    write_json("body", {"rows": rows, "targets": {"posed_position_map_ms@128": 10, "atlas_from_cache_ms": 50}})


if __name__ == "__main__":
    main()
