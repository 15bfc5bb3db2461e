"""Asset readers and writers: EXR/PNG images, meshes, MERL ``.binary`` BRDFs, NPF tables."""
