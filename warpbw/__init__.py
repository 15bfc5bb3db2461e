"""warpbw: bandwidth-driven adaptive shading of measured materials, simulated as NVIDIA Warp kernels.

Stages (one module each): ``scene`` (TOML scenes), ``io`` (EXR, meshes, MERL, NPF), ``envmap``,
``gbuffer``, ``brdf``, ``sampling``, ``shading`` (002 Eq. 2 reference estimator), ``metrics``;
``pipeline`` wires them together and ``cli`` is the ``warpbw`` command.
"""
__version__ = "0.1.0"
