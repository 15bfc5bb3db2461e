"""warpbw: bandwidth-driven adaptive shading of measured materials, simulated as NVIDIA Warp kernels.

Stages (one module each): ``scene`` (TOML scenes), ``io`` (EXR, meshes, MERL, NPF), ``envmap``,
``lights`` (directional lights), ``gbuffer`` (with ``mesh_normals`` for deformed meshes), ``brdf``,
``sampling``, ``shading`` (002 Eq. 2 reference estimator); adaptive shading (002): ``bandwidth_ops``,
``bandwidth``, ``pyramid``, ``upsample``, ``adaptive``; reflectance filtering of planes (004): ``filtering``;
``metrics``, ``bench`` and ``bench_filtering`` measure them.  ``pipeline`` wires them together and ``cli`` is
the ``warpbw`` command.
"""
__version__ = "0.1.0"
