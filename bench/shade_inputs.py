"""Dump one frame's shading-kernel inputs as raw arrays, for bench/shade_driver.c (instruction
counts under callgrind without a Python interpreter in the count).

    .venv/bin/python bench/shade_inputs.py bench/oakChair.json /tmp/chair
    gcc -O2 bench/shade_driver.c -o /tmp/shade_driver worker/native/_glintk*.so -lm -fopenmp \\
        -Wl,-rpath,$PWD/worker/native
    OMP_NUM_THREADS=1 /tmp/shade_driver /tmp/chair ggx 5          # CPU ms per call
    OMP_NUM_THREADS=1 valgrind --tool=callgrind /tmp/shade_driver /tmp/chair ggx 1

Materials: ggx (α 0.25), lambert, srbf (147 SRBFs, random coefficients); the light at 30°.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main(scene_path: str, out: str) -> None:
    from worker.cli import open_renderer
    from worker.core.lighting import light_tables
    from worker.core.render import MaterialTable
    from worker.assets import ensure_repo_scene
    from worker.scene import load_scene

    from profile_frame import material

    ensure_repo_scene(scene_path)   # its assets: tests/.cache/assets, fetched on first use
    scene = load_scene(scene_path)
    r, _ = open_renderer(scene, None, True)
    v = r.view(scene.spec.camera)
    _, _, node8 = light_tables(r.lighting, 30.0, 1.0, r.tree, r.k)
    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)

    def w(name, a, dt):
        np.ascontiguousarray(a, dt).tofile(d / f"{name}.bin")

    w("n", scene.mesh.normals[v.visible], np.float32); w("wo", v.wo, np.float32); w("vi", v.visible, np.int32)
    w("off", r.cuts.offsets, np.int64); w("h", r.cuts.heights, np.uint8); w("q", r.cuts.quant, np.uint8)
    w("node8", node8, np.float32); w("ndir", r.tree.node_dir, np.float32); w("nrad", r.tree.node_radius, np.float32)
    w("lev", r.tree.level_offset, np.int64)
    for name in ("ggx", "lambert", "srbf"):
        t = MaterialTable([material(name).pack()])
        w(f"{name}_kind", t.kind, np.int32); w(f"{name}_params", t.params, np.float32)
        w(f"{name}_refine", t.refine, np.float32); w(f"{name}_extent", t.extent, np.float32)
        w(f"{name}_tables", t.tables, np.float32); w(f"{name}_toff", t.table_off, np.int64)
    print(f"{len(v.visible)} points, tree height {r.tree.height} -> {d}")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    main(sys.argv[1], sys.argv[2])
