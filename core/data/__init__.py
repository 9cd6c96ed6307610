"""Scene data: manifest, events (HDF5 + ms index), trajectory and clock, camera, object meshes, SE(3), files."""
