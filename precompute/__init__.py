"""Offline precompute stage: turns raw assets (MERL BRDFs, NPF fits, analytic BRDFs, normal maps) into
the tables the renderer reads. Run it as ``warpbw-precompute`` (``precompute/__main__.py``)."""
