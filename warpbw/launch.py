"""Kernel launches tiled over a small thread pool on the CPU, and their progress bar: what every stage that
launches over pixels shares (the G-buffer, the bandwidth pass, the shading, the reflectance filtering's ground truth).

Public:
    ``launch_tiled(kernel, n_items, make_inputs, device, threads, progress, tile, costs, item_cost)``  CPU launches
        over threads, each of at most ``LAUNCH_COST_MAX`` samples where the items allow it
    ``progress_bar(total, desc, enabled)``  a bar for launch_tiled's ``progress`` (context manager; None if off)
    ``tile_ranges(n_items, tile, costs) -> [(offset, count)]``  its tiles: equal counts, or equal summed costs
    ``default_threads(device)``  the threads a CPU launch is tiled over
    ``PIXELS_PER_TILE``, ``TILES_PER_THREAD``, ``MIN_PIXELS_PER_TILE``, ``LAUNCH_COST_MAX``  the tiles' sizes

(In warpbw.shading until session 82: the G-buffer imported it from there inside a function, shading importing the
G-buffer.)
"""
from __future__ import annotations

import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Callable

import numpy as np
import warp as wp

from warpbw.errors import WarpbwError, check_count, check_device

# Pixels per kernel launch when tiling the work over threads (small enough for a smooth progress
# bar, large enough that launch overhead stays under 1%).
PIXELS_PER_TILE = 4096
# Smaller launches (the hierarchy's coarse levels, a few thousand pixels each) are cut into at least this
# many tiles per thread, of no fewer than MIN_PIXELS_PER_TILE pixels, so that every thread gets work.
TILES_PER_THREAD = 4
MIN_PIXELS_PER_TILE = 256
# Samples (an item's cost: its samples, rays or directions) in one launch on the CPU, at most: Python acts on Ctrl-C
# and SIGTERM only between launches, and tiles cut by pixels alone made one launch of 256 pixels x 2e6 samples (SIGINT
# at 5 s acted on at 36 s) or of 4096 pixels x 1e5 (minutes; options audit, session 64).  2^21 samples take about 1 s
# on one thread (the demo shades 3.05e6 samples/s on two); shade_reference shades a pixel of more samples in passes
# of about this many, one launch each (carrying its random state and sum, bit for bit the single launch's).
LAUNCH_COST_MAX = 2**21


def default_threads(device: str) -> int:
    """Threads used to tile CPU launches (a CPU launch runs on one core but releases the GIL)."""
    if not str(device).startswith("cpu"):
        return 1
    return max(1, min(os.cpu_count() or 1, 8))


def tile_ranges(n_items: int, tile: int, costs: np.ndarray | None = None) -> list[tuple[int, int]]:
    """(offset, count) of the ceil(n_items / tile) contiguous tiles of a launch: ``tile`` items each, or, with
    ``costs``, cut where the running cost (each item's cost + 1, for its fixed overhead) crosses equal
    shares of the total.  An adaptive frame's N_p runs from 1 to hundreds in a compact highlight: tiles of
    equal counts left one thread shading the highlight alone (chrome sphere of examples/bench_scenes.py,
    budget 4: 2 threads shaded in 0.071 s against 0.109 s on one; with tiles of equal cost 0.061 s)."""
    n_items = check_count(n_items, "tile_ranges: n_items", 0)   # -1 gave no tile, 2.5 a tile of 2.5 items
    tile = check_count(tile, "tile_ranges: tile", 1)            # 0: range()'s ValueError
    if costs is None:
        return [(o, min(tile, n_items - o)) for o in range(0, n_items, tile)]
    c = np.asarray(costs, np.float64).reshape(-1)
    if c.shape[0] != n_items or not np.all(np.isfinite(c) & (c >= 0)):
        raise WarpbwError(f"tile costs: expected {n_items} finite values >= 0, got {c.shape[0]}")
    if n_items == 0:   # no running cost to cut: an IndexError
        return []
    n_tiles = -(-n_items // tile)
    run = np.cumsum(c + 1.0)
    cuts = np.searchsorted(run, run[-1] * np.arange(1, n_tiles) / n_tiles, side="left") + 1
    bounds = np.unique(np.concatenate([[0], np.minimum(cuts, n_items), [n_items]]))
    return [(int(a), int(b - a)) for a, b in zip(bounds[:-1], bounds[1:])]


@contextmanager
def progress_bar(total: int, desc: str, enabled: bool = True):
    """Yield the ``progress`` callable of :func:`launch_tiled` (it adds ``count`` pixels to a bar over ``total``,
    :func:`precompute.progress.progress_callback`'s), or None when not ``enabled``; the bar is closed before an
    error or an interrupt is said, not drawn again after it at exit."""
    if not enabled:
        yield None
        return
    from precompute.progress import progress_callback

    with progress_callback(total, desc, "px") as step:
        done = [0]

        def add(count):
            done[0] += count
            step(done[0])

        yield add


def launch_tiled(kernel, n_items: int, make_inputs: Callable[[int, int], list], device: str,
                 threads: int | None = None, progress: Callable[[int], None] | None = None,
                 tile: int = PIXELS_PER_TILE, costs: np.ndarray | None = None, item_cost: int | None = None) -> None:
    """Launch ``kernel`` over ``n_items`` in tiles, on a small thread pool on the CPU (on a GPU, in one
    launch unless ``progress`` asks for tiles).

    ``make_inputs(offset, count)`` returns the kernel inputs for one tile; ``progress(count)`` is
    called as tiles finish.  ``costs`` (one per item, e.g. its sample count) cuts the same number of
    tiles at equal summed cost instead of equal counts (:func:`tile_ranges`); ``item_cost`` is every item's cost
    where they are equal.  On the CPU a launch holds at most ``LAUNCH_COST_MAX`` of cost where the items allow it, so
    that Ctrl-C acts within about a second.
    """
    check_device(device)
    if n_items <= 0:
        return
    # a count >= 1: 0, -1 or 1.5 were once taken as 1 without a word
    threads = default_threads(device) if threads is None else check_count(threads, "threads", 1)
    on_cpu = str(device).startswith("cpu")
    if threads > 1:
        tile = max(MIN_PIXELS_PER_TILE, min(tile, -(-n_items // (TILES_PER_THREAD * threads))))
    elif progress is None and not on_cpu:
        tile = n_items   # a GPU launch is parallel by itself: tiles only serve a progress bar there
    total = float(np.sum(costs, dtype=np.float64)) if costs is not None else float(item_cost or 0) * n_items
    by_cost = on_cpu and total > LAUNCH_COST_MAX * -(-n_items // tile)
    if by_cost:   # more tiles than the counts make, each of about LAUNCH_COST_MAX
        tile = -(-n_items // min(n_items, math.ceil(total / LAUNCH_COST_MAX)))
    tiles = tile_ranges(n_items, tile, costs if threads > 1 or by_cost else None)
    lock = threading.Lock()

    def run(t):
        o, c = t
        wp.launch(kernel, dim=c, inputs=make_inputs(o, c), device=device)
        if progress is not None:
            with lock:
                progress(c)

    if threads == 1 or len(tiles) == 1:
        for t in tiles:
            run(t)
    else:
        wp.load_module(kernel.module, device=device)  # load (compile) once, before the threads race for it
        with ThreadPoolExecutor(max_workers=threads) as pool:
            for _ in pool.map(run, tiles):
                pass
    wp.synchronize_device(device)
