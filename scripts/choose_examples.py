"""The two scenes of the README's `btfrs.choose` section: prints what choose decided for each.

Run: .venv/bin/python scripts/choose_examples.py  (a few minutes on 2 cores with lavapipe)
"""

import time

import numpy as np

import btfrs

btf = btfrs.materials.make("weave", size=32, seed=2)
print(btfrs.gpu_info())
top = btfrs.Camera.look_at([0, 0, 6], [0, 0, 0], 15)
ring = [[btfrs.DirectionalLight(btfrs.directions.from_theta_phi(40, a, degrees=True), 1.0)] for a in range(0, 360, 45)]
path = [btfrs.Camera.look_at([3 * np.cos(a), 3 * np.sin(a), 2], [0, 0, 0], 40)
        for a in np.radians(np.arange(0, 360, 45))]
scenes = {
    "top view, 8 lights on a 40-degree ring":
        btfrs.SceneUse(camera=top, lights=ring, size=(512, 512), scene=btfrs.Scene.plane(2.0), uv_scale=2),
    "camera path around a sphere, one point light":
        btfrs.SceneUse(camera=path, lights=[btfrs.PointLight([2, -2, 3], 8.0)], size=(512, 512),
                       scene=btfrs.Scene.sphere(), uv_scale=4),
}
for name, use in scenes.items():
    t = time.time()
    pick = btfrs.choose(btf, scene=use, tolerance=0.05, budget_bytes=8 << 20, seed=0)
    print(f"== {name}: {time.time() - t:.1f} s")
    print(pick.explain(), flush=True)
