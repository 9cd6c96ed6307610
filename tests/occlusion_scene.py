"""A small synthetic scene in which objects really hide each other (the shared tiny scene has none).

Built with the project's own generator (:func:`evpose.core.sim.synth.generate`): five 10 cm cubes on
the table (cubes stand as tall as they are wide, so from the generator's 45-72 degree camera elevations a
near cube can hide a far one), 0.2 s of events in the half-resolution DAVIS346 camera, no injected
clock or pose error (the manifest poses are the true ones). Seed 28 was picked by a search for a layout
where one cube (``cube1``, near the top border of the image) is about half hidden by another during the
whole recording; tests check that property instead of trusting it.
"""
from __future__ import annotations

from pathlib import Path

from evpose_testing import half_davis_camera

#: Edge of every cube, metres.
CUBE_M = 0.1
#: Generator parameters of the occlusion scene (with ``mesh_dir`` and ``camera`` added by the builder).
OCCLUSION_SCENE = {"objects": tuple(f"cube{i}" for i in range(5)), "trajectory": "B", "speed_mps": 0.3,
                   "duration_s": 0.2, "seed": 28}
#: The cube that another cube hides (in every window of the recording).
OCCLUDED = "cube1"


def build_occlusion_scene(base: Path) -> Path:
    """Write the cube meshes to ``base/meshes`` and generate the scene into ``base/scene``; returns the scene
    folder (about 2 s)."""
    import trimesh

    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    mesh_dir = Path(base) / "meshes"
    mesh_dir.mkdir(parents=True)
    for name in OCCLUSION_SCENE["objects"]:
        trimesh.creation.box(extents=(CUBE_M, CUBE_M, CUBE_M)).export(mesh_dir / f"{name}.ply")
    out = Path(base) / "scene"
    generate(out, SynthConfig(**OCCLUSION_SCENE, mesh_dir=str(mesh_dir), camera=half_davis_camera()))
    return out
