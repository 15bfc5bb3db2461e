"""User-facing errors.

Public: ``WarpbwError``; ``is_int(value)`` (an int or numpy integer, not a bool) and
``check_count(value, name, lo, hi=None) -> int`` (such an integer in lo..hi, else a ``WarpbwError`` naming
``name``); ``check_path(path, name) -> Path`` (a file name, not None); ``check_input_file(path, expected) -> Path`` (an
existing file, else a ``WarpbwError`` saying whether it is missing or a directory);
``check_camera_reach(reach, lo, hi, target, kind, why, source)`` (the camera's distance to an object within what float32
intersection handles); ``check_coordinate_spacing(coord, size, target, source)`` (float32 fine enough where the camera
and an object lie, ``COORD_SPACING_REL_MAX``);
``check_flag(value, name) -> bool`` (True or False, not a truthy string); ``check_instance(value, kind, name,
expected)`` (an object of the kind a stage function reads); ``check_warp_array(a, name, dtype, n,
device, what, at_least)`` (a 1-D Warp array a kernel may index n items of); ``check_real(value, name, lo,
lo_open) -> float`` (a finite real number in float32's range, not a bool or a string); ``check_seed(seed, name)``
(a uint32), ``offset_seed(seed, offset)`` (a seed derived from the user's, kept a uint32 by wrapping) and
``check_device(device, name)`` (a Warp device this machine has), the renderers' own checks;
``numeric_array(values, name, expected)`` (float64 numbers, not strings or ragged lists);
``check_direction_pairs(wi, wo) -> (wi, wo)`` (the BRDF evaluators' (N, 3) direction pairs, broadcast, unit length)
and ``unit_directions(d, name)`` (finite non-zero directions scaled to unit length); ``check_finite_image(image,
source)`` (a rendered image without inf or NaN pixels, which radiance near float32's top gives); the bounds
``INT32_MAX``, ``FLOAT32_MAX``, ``SEED_MAX`` and ``BRDF_VALUE_MAX`` that user values are checked against;
``available_memory() -> bytes | None`` (Linux's MemAvailable) and ``warn_if_short_of_memory(need, have, what, advice)``
(a warning before a step the system would stop without a word); ``one_line(exc) -> str`` (another library's exception
in one line, its class name where it says nothing).

Anything the user can cause (a bad file, a bad key in a scene, a bad CLI value) is raised as
``WarpbwError`` with a one-line message that names the file or key and says what was expected.
The CLIs print it as ``warpbw: error: <message>`` and exit with status 2, never a traceback.
"""
from __future__ import annotations

import math
import numbers
from pathlib import Path

# The kernels index pixels and count samples (spp, N_p) in Warp int32: a larger count wraps around.
INT32_MAX = 2**31 - 1
# Scene values (positions, radii, radiances, scales) become float32 in the kernels: beyond this they are inf.
FLOAT32_MAX = 3.4028234663852886e38
# Largest BRDF value a table may hold (MERL entries after their channel scales, NPF factors).  The 100 MERL
# materials' NPF fits reach 6.7e6 (rho_s of the mirror-like fits); the kernels multiply a value by up to
# 1 / (4 cos theta_i cos theta_o) and by the radiance in float32, so values near FLOAT32_MAX overflow to inf there
# and every sample is dropped: a black image.  1e20 leaves 13 orders of magnitude above the real fits.
BRDF_VALUE_MAX = 1e20
# Seeds are uint32 in Warp's RNG and numpy's / scikit-learn's seeding: larger or negative ones wrap or fail.
SEED_MAX = 2**32 - 1


class WarpbwError(Exception):
    """A problem with the user's input, reported in one line without a traceback.  Not a ``ValueError``: code that
    catches numpy's or Pillow's ValueError around a call into warpbw must not swallow a message meant for the user
    (a map too large to read was reported as "not an image file")."""


def is_int(value) -> bool:
    """An integer (Python or numpy), not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def check_count(value, name: str, lo: int, hi: int | None = None) -> int:
    """``value`` as an int when it is an integer >= lo (and <= hi); otherwise a one-line error naming ``name``."""
    if not is_int(value) or value < lo:
        raise WarpbwError(f"{name}: expected an integer >= {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise WarpbwError(f"{name}: expected an integer from {lo} to {hi}, got {value!r}")
    return int(value)


def check_real(value, name: str, lo: float = -FLOAT32_MAX, lo_open: bool = False) -> float:
    """``value`` as a float when it is a real number (not a bool or a string: a keyword given "1" reached
    math.isfinite and came out as a TypeError) that is finite in float32, as the kernels take it, and >= ``lo``
    (> ``lo`` with ``lo_open``); else a one-line ``WarpbwError`` naming ``name``."""
    import numpy as np

    x = math.nan
    if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
        try:
            x = float(value)
        except OverflowError:      # an int beyond float64
            x = math.inf
    if not (math.isfinite(x) and abs(x) <= FLOAT32_MAX and (x > lo if lo_open else x >= lo)):
        bound = "" if lo == -FLOAT32_MAX else f" {'>' if lo_open else '>='} {lo:g}"
        beyond = f" within float32's range (+-{FLOAT32_MAX:.4g}, as the kernels take it)" if math.isfinite(x) \
            and abs(x) > FLOAT32_MAX else ""   # 1e300 was told "expected a finite number", which it is
        raise WarpbwError(f"{name}: expected a finite number{bound}{beyond}, got {value!r}")
    return x


def check_warp_array(a, name: str, dtype, n: int, device, what: str, at_least: bool = False):
    """``a`` when it is a 1-D Warp array of ``n`` (``at_least``: n or more) ``dtype`` on ``device``, else a
    one-line ``WarpbwError`` naming ``name`` and ``what`` its items are: kernels index such arrays without
    bounds, so a shorter one was read, or written, past its end (heap corruption, a segfault later)."""
    import warp as wp

    ok = isinstance(a, wp.array) and a.ndim == 1 and (a.shape[0] >= n if at_least else a.shape[0] == n)
    if not (ok and a.dtype == dtype):
        got = (f"a Warp array of shape {a.shape} {wp.types.type_repr(a.dtype)}" if isinstance(a, wp.array)
               else type(a).__name__)
        raise WarpbwError(f"{name}: expected a Warp array of {'at least ' if at_least else ''}{n} "
                          f"{wp.types.type_repr(dtype)} ({what}), got {got}")
    if a.device != wp.get_device(device):
        raise WarpbwError(f"{name}: expected an array on device {device}, got one on {a.device}")
    return a


def check_instance(value, kind, name: str, expected: str):
    """``value`` when it is an instance of ``kind`` (a class, a tuple of them, or a Warp struct: its instances'
    type), else a one-line ``WarpbwError``: ``NAME: expected EXPECTED, got TYPE`` (the stage functions read its
    fields: a wrong object gave an AttributeError from deep inside, or, handed to a kernel, a segfault)."""
    kinds = kind if isinstance(kind, tuple) else (kind,)
    kinds = tuple(getattr(k, "instance_type", k) for k in kinds)   # a @wp.struct class: what its instances are
    if not isinstance(value, kinds):
        raise WarpbwError(f"{name}: expected {expected}, got {type(value).__name__}")
    return value


def check_flag(value, name: str) -> bool:
    """``value`` as a bool when it is True or False (a numpy bool too), else a one-line error naming ``name``: a
    string such as "no" is truthy, and once switched an option on."""
    import numpy as np

    if not isinstance(value, (bool, np.bool_)):
        raise WarpbwError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def check_seed(seed, name: str = "seed") -> int:
    """A seed the RNGs take as it is: an integer from 0 to ``SEED_MAX`` (else it would wrap, or fail inside numpy)."""
    return check_count(seed, name, 0, SEED_MAX)


def offset_seed(seed: int, offset: int) -> int:
    """``seed + offset`` modulo 2^32: the seed of one run or level derived from the user's, a uint32 for every seed
    ``check_seed`` takes (``bench --seed 4294967295`` was refused after its ground truth, naming a seed past it)."""
    return (int(seed) + int(offset)) % (SEED_MAX + 1)


def check_device(device, name: str = "device") -> str:
    """``device`` (a name: cpu, cuda, cuda:N; or a ``warp.Device``) when Warp has it on this machine, else a
    ``WarpbwError`` naming ``name``."""
    import warp as wp

    from warpbw.native_output import init_warp_quietly

    if isinstance(device, wp.Device):   # a Device object is fine too (and cheap: frame loops pass one)
        return device
    init_warp_quietly()
    names = ", ".join(d.alias for d in wp.get_devices())
    if not isinstance(device, str) or not device:
        raise WarpbwError(f"{name} {device!r}: expected a Warp device name (Warp found: {names})")
    if device.startswith("cuda") and not wp.is_cuda_available():
        # checked before wp.get_device("cuda"), which prints native CUDA errors when there is no driver
        raise WarpbwError(f"{name} {device}: no CUDA device on this machine (no NVIDIA GPU or driver found; "
                          f"Warp found: {names}); use {name + ' cpu' if name.startswith('-') else 'cpu'}")
    try:
        wp.get_device(device)
    except (RuntimeError, ValueError):
        raise WarpbwError(f"{name} {device}: not available on this machine (Warp found: {names})") from None
    return device


def numeric_array(values, name: str, expected: str = "numbers"):
    """``values`` as a float64 numpy array, else a one-line ``WarpbwError`` naming ``name`` and ``expected``: strings,
    None and ragged lists gave numpy's "could not convert string to float" or "inhomogeneous shape"."""
    import numpy as np

    try:
        complex_values = np.iscomplexobj(values)   # numpy's ComplexWarning, then the real part alone
        a = None if complex_values else np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise WarpbwError(f"{name}: expected {expected}, got {type(values).__name__} that numpy cannot read as "
                          "numbers") from None
    if complex_values:
        raise WarpbwError(f"{name}: expected {expected}, got complex numbers")
    return a


def unit_directions(d, name: str):
    """Directions (..., 3) scaled to unit length (the evaluators assume it: wi * 10 read 0.0116 for 0.62), else a
    ``WarpbwError`` naming ``name`` for a zero, NaN or infinite one (a NaN one read as 0, below the horizon)."""
    import numpy as np

    d = np.asarray(d, dtype=np.float64)
    # scaled by the largest component first: the norm of [0, 0, 1e200] overflowed, of [1e-200, 0, 0] underflowed
    big = np.max(np.abs(d), axis=-1, keepdims=True)
    bad = ~(np.isfinite(big) & (big > 0.0))
    if bad.any():
        k = int(np.flatnonzero(bad.reshape(-1))[0])
        raise WarpbwError(f"{name}: expected finite non-zero directions, {int(bad.sum())} of {bad.size} are not "
                          f"(the first, {k}: {d.reshape(-1, 3)[k].tolist()})")
    d = d / big
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def check_finite_image(image, source: str) -> None:
    """Refuse an image with inf or NaN pixels: radiance near the top of the float32 range (an environment map's or a
    light's) overflows where a kernel multiplies it by a sharp lobe or sums the samples of a pixel (a plane of
    roughness 1e-3 under a sky of 1e33 returned 447 of 512 pixels non-finite from Python, without a word)."""
    import numpy as np

    bad = int((~np.isfinite(image)).any(axis=-1).sum())
    if bad:
        raise WarpbwError(f"{source}: {bad} of {image.shape[0] * image.shape[1]} pixels came out infinite or NaN "
                          "(the radiance overflowed float32 in the shading; expected environment and light radiance "
                          f"well below {FLOAT32_MAX:.3g}: lower [environment] scale, the map's values or [[light]] "
                          "radiance); nothing written")


def check_direction_pairs(wi, wo):
    """``wi`` and ``wo`` as unit float64 arrays (N, 3) of one length (a single direction broadcasts), else a
    ``WarpbwError`` (numpy's broadcast error or an IndexError once came from deep inside the evaluators)."""
    import numpy as np

    a = np.atleast_2d(numeric_array(wi, "wi", "directions (N, 3)"))
    b = np.atleast_2d(numeric_array(wo, "wo", "directions (N, 3)"))
    if a.shape[-1:] != (3,) or b.shape[-1:] != (3,):
        raise WarpbwError(f"wi, wo: expected directions of 3 components, (N, 3), got shapes {a.shape} and {b.shape}")
    try:
        a, b = np.broadcast_arrays(a, b)
    except ValueError:
        raise WarpbwError(f"wi, wo: expected as many incident as outgoing directions, got shapes {a.shape} and "
                          f"{b.shape}") from None
    return unit_directions(a, "wi"), unit_directions(b, "wo")


def check_path(path, name: str = "path") -> Path:
    """``path`` (a str or os.PathLike, not empty) as a ``Path``, else a one-line error naming ``name``: None or a
    number was a TypeError from pathlib."""
    import os

    if isinstance(path, (str, os.PathLike)) and not str(path):   # '(str or Path)' told a CLI user nothing
        raise WarpbwError(f"{name}: expected a file name, got an empty one")
    if not isinstance(path, (str, os.PathLike)):
        raise WarpbwError(f"{name}: expected a file name (str or Path), got {path!r}")
    return Path(path)


def check_input_file(path, expected: str = "") -> Path:
    """``path`` as a ``Path`` when it is an existing file; otherwise a one-line error saying whether it is
    missing or a directory, and what was ``expected`` (``"an OpenEXR image"``)."""
    p = check_path(path, f"input file ({expected})" if expected else "input file")
    if not p.is_file():
        # a FIFO or a device (/dev/zero) exists: "file not found" sent the user looking for a typo
        what = ("a directory, not a file" if p.is_dir() else "not a regular file (a pipe, socket or device)"
                if p.exists() else "file not found")
        raise WarpbwError(f"{p}: {what}" + (f" (expected {expected})" if expected else ""))
    return p


# Far from the origin float32 spaces coordinates coarsely: at 1e6 they are 0.0625 apart, and a unit sphere there
# (camera beside it) came out with normals up to 179 degrees wrong, at 1e10 with no pixel at all (the camera
# rounded into it); a plane of side 2 seen from 0.35 away read 37 dB against its frame at the origin when both
# were moved 1e5 along x, 53 dB at 1e4, 77 dB at 1e3.  A scaled scene keeps its relative spacing; a translated one
# does not.  So the spacing at the largest coordinate a frame computes with (the camera's, or the object's) may be
# at most this share of the object's size (a sphere's radius, a mesh's diagonal, a plane's side): 2^-10, a normal
# error of about 1e-3 radians.  Measured on a unit sphere: 0.0039 radians at 1e5 (spacing 2^-7).
COORD_SPACING_REL_MAX = 2.0 ** -10


def check_coordinate_spacing(coord: float, size: float, target: str, source: str = "") -> None:
    """Refuse a frame whose camera or ``target`` (an object of ``size``: "a sphere of radius 1") lies ``coord``
    scene units from the origin, where float32 spaces coordinates by more than ``COORD_SPACING_REL_MAX`` of
    ``size``: its outline and shading would come out wrong without a word.  ``source`` starts the message."""
    import numpy as np

    if not size > 0.0:
        raise WarpbwError(f"{source + ': ' if source else ''}{target}: expected an object with extent, got size "
                          f"{size!r}")
    step = float(np.spacing(np.float32(min(abs(coord), FLOAT32_MAX))))
    if step <= COORD_SPACING_REL_MAX * size:
        return
    raise WarpbwError(
        f"{source + ': ' if source else ''}the camera and {target} lie up to {coord:.3g} scene units from the "
        f"origin, where float32 spaces coordinates {step:.3g} apart ({step / size:.2g} of its size; at most "
        f"{COORD_SPACING_REL_MAX:.2g}): its outline and shading would come out wrong; expected an object of at "
        f"least {step / COORD_SPACING_REL_MAX:.3g} there, or smaller coordinates (the camera nearer the object, or "
        "the camera and the objects translated together towards the origin)")


def check_camera_reach(reach: float, lo: float, hi: float, target: str, kind: str, why: str = "",
                       source: str = "") -> None:
    """Refuse a camera ``reach`` scene units from ``target`` (the far side or corner of an object) outside
    [lo, hi], what float32 ray-``kind`` intersection handles (``why``, if given, says why): its pixels would be
    left empty or wrong without a word.  ``source`` (a scene file) starts the message when given."""
    if lo <= reach <= hi:
        return
    raise WarpbwError(
        f"{source + ': ' if source else ''}the camera is {reach:.3g} scene units from {target}, outside the "
        f"{lo:.2g} to {hi:.2g} that float32 ray-{kind} intersection handles{f' ({why})' if why else ''}: its pixels "
        f"would be left empty or wrong; expected a {'smaller' if reach > hi else 'larger'} scene (scale the objects "
        "and the camera together)")


def available_memory() -> int | None:
    """Bytes of memory the system can give without swapping (Linux's MemAvailable), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def warn_if_short_of_memory(need: int, have: int | None, what: str, advice: str, stacklevel: int = 2) -> None:
    """Warn when ``what`` (a frame, a probe's bandwidth map) takes about ``need`` bytes and ``have`` (the memory
    available, None where unknown) is less: the system stops such a process without a word (no error, no image),
    and the warning names what to lower."""
    import warnings

    if have is not None and need > have:
        warnings.warn(f"{what} takes about {need / 1e9:.1f} GB, but {have / 1e9:.1f} GB of memory is available: the "
                      f"system may stop it ({advice})", RuntimeWarning, stacklevel=stacklevel + 1)


def one_line(exc: BaseException) -> str:
    """``exc``'s text with its whitespace and line breaks collapsed, or its class name where it has none (quoted inside
    a one-line error)."""
    return " ".join(str(exc).split()) or type(exc).__name__
