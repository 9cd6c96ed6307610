"""The *validation family* generator: a second scene simulator, written independently of :mod:`evpose.core.sim`.

It shares no rendering, event-simulation or motion code with ``evpose synth`` (only the scene-folder I/O of
:mod:`evpose.core.data`), so estimators tuned on ``synth`` scenes can be checked on scenes whose quirks differ:
ray casting through the distorted lens (open3d), smooth shading, solid procedural textures, clutter, a
level-crossing sensor with leak and shot noise, robot poses at 100/250 Hz with their own motion profiles.

Modules by role: :mod:`~evpose.core.sim_validation.config` (parameters), :mod:`~evpose.core.sim_validation.rays`
(distortion and pixel rays), :mod:`~evpose.core.sim_validation.textures` (solid noise),
:mod:`~evpose.core.sim_validation.shading` (lights and materials), :mod:`~evpose.core.sim_validation.world`
(objects, table, clutter), :mod:`~evpose.core.sim_validation.raycaster` (frames),
:mod:`~evpose.core.sim_validation.profiles` (robot motion), :mod:`~evpose.core.sim_validation.sensor`
(level-crossing events), :mod:`~evpose.core.sim_validation.stepping` (adaptive frame times),
:mod:`~evpose.core.sim_validation.assemble` (the scene folder and ``ground_truth.json``).
"""
