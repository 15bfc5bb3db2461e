"""What a damaged mesh file has wrong, in its format's terms: the checks ``warpbw.io.mesh`` runs before and after
trimesh reads a file, and the words for where trimesh stops.

Public functions (``data`` is the bytes of ``path``; each refusal is a one-line ``WarpbwError`` naming the file and
its line or index where the format has one, not trimesh's words):

- ``check_before_reading(path, data)``: a PLY's header (``_check_ply``), a GLB's or glTF's accessors and bufferViews
  (``_check_gltf``), an OBJ's vertex and face lines, and its face indices where a relative one comes before a later
  vertex line (which trimesh reads as another vertex).
- ``check_after_reading(path, data, triangles, lost_uv)``: an ASCII STL read short of its facets
  (``_check_ascii_stl_read``), an OBJ whose texture coordinates trimesh dropped for an index out of range.
- ``format_damage(path, data) -> str | None``: what an STL's lengths or an OBJ's face indices say is wrong, where
  trimesh read no triangles or indices outside its vertices.
- ``read_failure(path, data, exc) -> str``: the message for a file trimesh stopped on with ``exc``.
- ``triangle_count(path, data) -> int | None``: how many triangles the file holds, from its header or its face lines,
  without reading its geometry (``warpbw info``'s memory estimate).
- ``suffix_problem(path) -> str | None``: what is wrong with the file's name, where trimesh has no reader for its
  suffix (it picks one by the name alone).

Constants: ``SUPPORTED`` (the formats messages name), ``MESH_SUFFIXES`` (their names' suffixes), ``PLY_TYPE_BYTES``,
``PLY_FACE_INDEX_NAMES``, ``GLB_HEADER_BYTES``, ``GLB_CHUNK_HEAD_BYTES``, ``GLTF_COMPONENT_BYTES``,
``GLTF_TYPE_COMPONENTS``, ``STL_HEADER_BYTES``, ``STL_TRIANGLE_BYTES``.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

from warpbw.errors import WarpbwError, one_line

# The formats named in messages (trimesh reads them, and others: a file of another suffix is tried as it is).
SUPPORTED = "OBJ, PLY, STL or GLB"
# Their names' suffixes (and glTF's), which ``suffix_problem`` accepts without importing trimesh (2 s).
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")
# An OBJ face whose vertex index is 0 (OBJ counts from 1, and from -1 backwards): trimesh reads it as vertex 0,
# a different triangle from the one the file's author meant, so it is refused.
_OBJ_ZERO_INDEX = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?<=[ \t])0(?:/\S*)?(?=\s|$)", re.M)
# An OBJ vertex line that is not 3 to 7 numbers (x y z [w], or x y z r g b [a]: colours as trimesh reads them),
# and nothing after them (trimesh reads no trailing comment): trimesh stopped in numpy's "could not be read to its
# end due to unmatched data".
_OBJ_NUMBER = rb"(?i:[-+]?(?:(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?|nan|inf(?:inity)?))"
_OBJ_BAD_VERTEX = re.compile(rb"^[ \t]*v[ \t](?![ \t]*(?:" + _OBJ_NUMBER + rb"[ \t]+){2,6}" + _OBJ_NUMBER
                             + rb"[ \t]*\r?$)[^\n]*", re.M)
# The indices of an OBJ face corner (v, v/vt, v//vn, v/vt/vn) that trimesh reads: the vertex's and the texture
# coordinate's (a normal's it drops when out of range, and warpbw derives its own), with the words and the lines
# defining what they index.  Each counts from 1, or back from -1: the last one defined so far (the OBJ format).
_OBJ_INDEXED = {b"v": ("face index", "vertices"), b"vt": ("face texture index", "texture coordinates")}
# An OBJ face line as trimesh reads it: "f" at the start of a line, then a space.
_OBJ_FACE_LINE = re.compile(rb"^f [^\n]*", re.M)
# An ASCII STL facet, as trimesh's reader counts them.
_STL_FACET = re.compile(rb"facet[ \t]+normal", re.I)
# glTF primitive modes (glTF 2.0 Sec. 3.7.2.1): TRIANGLES (the default) holds count / 3 triangles, TRIANGLE_STRIP
# and TRIANGLE_FAN count - 2; POINTS and the LINES modes none.
_GLTF_TRIANGLES, _GLTF_STRIP_OR_FAN = 4, (5, 6)
# A face line holding a minus sign, a negative index: found from the first face line on.
_OBJ_NEGATIVE_FACE = re.compile(rb"^f[ \t][^\n]*-", re.M)
# An OBJ face line of fewer than three vertices ("f 1 3", a line cut short): trimesh dropped it without a word.
_OBJ_SHORT_FACE = re.compile(rb"^[ \t]*f(?:[ \t]+\S+){0,2}[ \t]*\r?$", re.M)
# An OBJ vertex, texture-coordinate or face line that is indented, or whose keyword a tab follows: legal OBJ, but
# trimesh reads only the lines that start "v ", "vt " or "f " (it splits the text at "\nv " ...) and skips these
# without a word, so the faces after a skipped vertex took the wrong vertices.  (The file's first line is read
# indented: trimesh strips the text first.)
_OBJ_SKIPPED_LINE = re.compile(rb"^(?:[ \t]+(?:v|vt|f)[ \t]|(?:v|vt|f)\t)[^\n]*", re.M)
# PLY property types and their sizes in bytes: the PLY format's char ... double (Turk 1994) and the sized names int8
# ... float64 that trimesh's reader also takes (trimesh/exchange/ply.py, _dtypes).
PLY_TYPE_BYTES = {"char": 1, "uchar": 1, "short": 2, "ushort": 2, "int": 4, "uint": 4, "float": 4, "double": 8,
                  "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4, "uint32": 4, "int64": 8, "uint64": 8,
                  "float16": 2, "float32": 4, "float64": 8}
# The names trimesh's PLY reader looks for on the face element's list of vertex indices (_elements_to_kwargs).
PLY_FACE_INDEX_NAMES = ("vertex_indices", "vertex_index")
# A GLB (glTF 2.0's binary container, Khronos glTF 2.0 specification Sec. 4.4): a 12-byte header (magic, version,
# length), then chunks of an 8-byte head (the data's length, its type) and the data: JSON first, then BIN.
GLB_HEADER_BYTES, GLB_CHUNK_HEAD_BYTES = 12, 8
_GLB_MAGIC, _GLB_JSON, _GLB_BIN = b"glTF", b"JSON", b"BIN\0"
# glTF accessor component types and their sizes in bytes (glTF 2.0 Sec. 3.6.2.2: BYTE ... FLOAT; 5124 is none).
GLTF_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
# glTF accessor types and their components per element (the same section; trimesh reads matrices unpadded).
GLTF_TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
# A binary STL: an 80-byte comment, a uint32 triangle count, then 50 bytes per triangle (an ASCII one starts "solid").
STL_HEADER_BYTES, STL_TRIANGLE_BYTES = 84, 50
# A line that is none of an ASCII STL's (solid and endsolid with a name, facet normal with anything after it: trimesh
# recomputes a normal it cannot read; outer loop, vertex and three numbers, endloop, endfacet, a blank line), or that
# holds a NUL byte: the first damaged line, named when trimesh stops or reads fewer triangles than the file holds.
_STL_DAMAGED_LINE = re.compile(
    rb"^(?!(?:\xef\xbb\xbf)?[ \t]*(?:(?:solid|endsolid|facet[ \t]+normal)(?:[ \t][^\n\0]*)?|outer[ \t]+loop|endloop"
    rb"|endfacet|vertex(?:[ \t]+" + _OBJ_NUMBER + rb"){3})?[ \t]*\r?$)[^\n]*", re.M | re.I)


def _line_number(data: bytes, at: int) -> int:
    """The 1-based number of the line of ``data`` that byte ``at`` lies on."""
    return data.count(b"\n", 0, at) + 1


@dataclass(frozen=True)
class _PlyElement:
    """An element of a PLY header: its name, row count, the header line declaring it, and its properties (name ->
    (type, the list's count type or None))."""

    name: str
    count: int
    line: int
    props: dict


def _ply_header(path: Path, data: bytes) -> tuple[bool, list, int]:
    """The header of a PLY file (``data``, the bytes of ``path``) as trimesh's reader takes it: whether the body is
    ASCII, its elements (``_PlyElement``) and where the body starts.  What trimesh would stop on in its own words (a
    header cut short: "list index out of range"; an unknown type: "('float128')") or skip without a word (a property
    line of another shape: its column read as the next property's) is a one-line WarpbwError naming the line."""
    end = re.search(rb"(?<!\S)end_header(?!\S)", data)
    if end is None:
        raise WarpbwError(f"{path}: PLY header cut short (no 'end_header' line): truncated or corrupt")
    newline = data.find(b"\n", end.end())
    body = len(data) if newline < 0 else newline + 1
    lines = data[:data.rfind(b"\n", 0, end.start()) + 1].split(b"\n")[:-1]   # the lines before end_header's
    if not lines or b"ply" not in lines[0].lower():
        raise WarpbwError(f"{path}: not a PLY file (expected 'ply' on its first line)")
    if len(lines) < 2:
        raise WarpbwError(f"{path}:2: PLY header has no 'format' line (expected 'format ascii 1.0' or a binary one)")
    elements: dict[str, _PlyElement] = {}
    for number, raw in enumerate(lines[2:], start=3):
        try:
            words = raw.decode("utf-8").split()
        except UnicodeDecodeError:
            raise WarpbwError(f"{path}:{number}: PLY header line is not UTF-8 text: corrupt") from None
        said = " ".join(words)
        if not words:   # trimesh indexed the line's first word
            raise WarpbwError(f"{path}:{number}: blank line in the PLY header (expected element, property, comment "
                              "... lines up to 'end_header')")
        if "element" in words[0]:   # trimesh's test: the word holds "element"
            count = words[2] if len(words) == 3 else ""
            if not re.fullmatch(r"\d+", count):
                raise WarpbwError(f"{path}:{number}: PLY element line {said!r} (expected 'element NAME COUNT', COUNT "
                                  "a whole number 0 or more)")
            elements[words[1]] = _PlyElement(words[1], int(count), number, {})
        elif "property" in words[0]:
            elements_so_far = list(elements.values())
            if not elements_so_far:
                raise WarpbwError(f"{path}:{number}: PLY property line {said!r} before any element line")
            if len(words) == 5 and "list" in words[1]:
                types, name = (words[3], words[2]), words[4]
            elif len(words) == 3 and words[1] != "list":
                types, name = (words[1], None), words[2]
            else:   # trimesh skipped the line, and read its column as the next property's
                raise WarpbwError(f"{path}:{number}: PLY property line {said!r} (expected 'property TYPE NAME' or "
                                  "'property list COUNT_TYPE TYPE NAME')")
            for kind in types:
                if kind is not None and kind not in PLY_TYPE_BYTES:
                    raise WarpbwError(f"{path}:{number}: PLY property type {kind!r} unknown (expected one of "
                                      f"{', '.join(PLY_TYPE_BYTES)})")
            elements_so_far[-1].props[name] = types
    return b"ascii" in lines[1].lower(), list(elements.values()), body


def _check_ply_geometry(path: Path, ascii_body: bool, elements: list) -> None:
    """Refuse a PLY whose vertices lack x, y or z (trimesh's bare KeyError "('y')") or whose faces lack a list of
    vertex indices under a name trimesh looks for ("cannot access local variable 'faces'"; a binary file's only
    list property it takes whatever its name)."""
    named = {e.name: e for e in elements}
    vertex, face = named.get("vertex"), named.get("face")
    for axis in "xyz" if vertex is not None and vertex.count else "":
        if axis not in vertex.props:
            raise WarpbwError(f"{path}:{vertex.line}: PLY vertex element has no {axis!r} property (expected x, y "
                              "and z)")
    if face is None or not face.count:
        return
    lists = [name for name, (_, count_type) in face.props.items() if count_type is not None]
    if not (set(lists) & set(PLY_FACE_INDEX_NAMES) or (not ascii_body and len(face.props) == 1 and lists)):
        raise WarpbwError(f"{path}:{face.line}: PLY face element has no list property of vertex indices "
                          f"({' or '.join(map(repr, PLY_FACE_INDEX_NAMES))})")


def _check_ply(path: Path, data: bytes) -> None:
    """Refuse a PLY (``data``, the bytes of ``path``) whose header is damaged (``_ply_header``,
    ``_check_ply_geometry``) or declares more rows than its body holds: an ASCII body of another number of rows (trimesh
    read a file cut short as the faces it kept, and took a face count of 2147483647 on 80 faces, without a word), a
    binary one shorter than its rows take at the least (each list empty)."""
    ascii_body, elements, start = _ply_header(path, data)
    _check_ply_geometry(path, ascii_body, elements)
    said = ", ".join(f"{e.count} {e.name}" for e in elements)
    if ascii_body:
        rows = sum(1 for line in data[start:].splitlines() if line.strip())
        want = sum(e.count for e in elements)
        if rows != want:
            raise WarpbwError(f"{path}: ASCII PLY header declares {want} rows ({said}) but its body holds {rows}: "
                              "truncated or corrupt")
        return
    least = sum(e.count * sum(PLY_TYPE_BYTES[count_type or kind] for kind, count_type in e.props.values())
                for e in elements)
    if least > len(data) - start:
        raise WarpbwError(f"{path}: binary PLY header declares {said} rows (at least {least} bytes) but its body "
                          f"holds {len(data) - start} bytes: truncated or corrupt")


def _check_obj_lines(path: Path, data: bytes) -> None:
    """Refuse an OBJ (``data``, the bytes of ``path``) vertex line that is not 3 to 7 numbers (``_OBJ_BAD_VERTEX``), a
    face with vertex index 0 (``_OBJ_ZERO_INDEX``), a face of fewer than three vertices (``_OBJ_SHORT_FACE``) and a
    line trimesh would skip (``_OBJ_SKIPPED_LINE``), naming the line."""
    first = len(data) - len(data.lstrip())   # trimesh strips the text: an indented first line is read
    for pattern, problem in (
            (_OBJ_BAD_VERTEX, lambda text: f"vertex line {text[:60]!r} (expected 'v x y z': three numbers, optionally "
                                           "a w or a colour, and nothing after them)"),
            (_OBJ_ZERO_INDEX, lambda text: "a face has vertex index 0 (OBJ indices count from 1, or back from -1)"),
            (_OBJ_SHORT_FACE, lambda text: f"face line {text[:60]!r} has {len(text.split()) - 1} vertices (expected "
                                           "3 or more; a line cut short?)"),
            (_OBJ_SKIPPED_LINE, lambda text: f"line {text[:60]!r} is indented or has a tab after its keyword, and the "
                                             "OBJ reader (trimesh) skips such lines without a word: the mesh would be "
                                             "read without it (expected the keyword at the start of the line, then "
                                             "a space)")):
        m = pattern.search(data, first if pattern is _OBJ_SKIPPED_LINE else 0)
        if m is not None:
            text = m.group(0).strip().decode("utf-8", "replace")
            raise WarpbwError(f"{path}:{_line_number(data, m.start())}: {problem(text)}; malformed mesh")


def _obj_corner_problem(text: bytes, kind: bytes, so_far: int, total: int) -> str | None:
    """What is wrong with one index of an OBJ face corner as written (``text``), into the items of ``kind`` (b"v",
    b"vt": ``_OBJ_INDEXED``), ``so_far`` of them defined before its face and ``total`` in the file; None when trimesh
    reads the item the file means."""
    (what, noun), keyword, shown = _OBJ_INDEXED[kind], f"'{kind.decode()}' line", text.decode("utf-8", "replace")
    expected = (f"expected 1 to {total}, or -1 to -{so_far} counting back" if total else
                f"expected an index of a {keyword}, and the file has none")
    try:
        i = int(text)
    except ValueError:
        return f"{what} {shown!r} is not a whole number ({expected})"
    if i == 0:
        return f"{what} 0 (OBJ indices count from 1, or back from -1)"
    if i > total:
        return f"{what} {shown} is past the file's {total} {noun} ({expected})"
    if -i > so_far:
        return f"{what} {shown} counts back past the {so_far} {noun} defined before it ({expected})"
    if i < 0 and so_far < total:
        return (f"{what} {shown} counts back from the {so_far} {noun} defined so far, but trimesh counts back from the "
                f"file's {total}: another one (expected positive indices, or negative ones after the last {keyword})")
    return None


def _obj_index_problem(path: Path, data: bytes) -> str | None:
    """The first face corner of an OBJ (``data``, the bytes of ``path``) whose vertex or texture index, as written,
    lies outside those defined (trimesh's int64 parse made 99999999999999999999 "index 9223372036854775806"), or
    counts back from those defined so far where more follow (trimesh counts back from the file's last one: another
    vertex, without a word), with its line; else None.  A loop over the lines, run where trimesh failed or found no
    texture coordinates, or a face counts back before a definition (``_obj_may_count_back_early``): not on every
    load."""
    lines = data.split(b"\n")
    firsts = [line.split(None, 1)[:1] for line in lines]
    total = {kind: firsts.count([kind]) for kind in _OBJ_INDEXED}
    so_far = dict.fromkeys(total, 0)
    for number, (line, first) in enumerate(zip(lines, firsts), start=1):
        if first and first[0] in so_far:
            so_far[first[0]] += 1
        if first != [b"f"]:
            continue
        for corner in line.split()[1:]:
            for text, kind in zip(corner.split(b"/"), _OBJ_INDEXED):
                problem = text and _obj_corner_problem(text, kind, so_far[kind], total[kind])
                if problem:
                    return f"{path}:{number}: {problem}; malformed mesh"
    return None


def _obj_may_count_back_early(data: bytes) -> bool:
    """Whether an OBJ (``data``) has a vertex or texture coordinate defined after its first face, and a face with a
    negative index: the case a relative index may mean another item than trimesh reads (``_obj_index_problem``
    decides).  Found with trimesh's own markers ("\\nv ", "\\nf "), without a pass over every line."""
    first_face = 0 if data.startswith(b"f ") else data.find(b"\nf ")
    if first_face < 0 or max(data.rfind(b"\nv "), data.rfind(b"\nvt ")) < first_face:
        return False
    return _OBJ_NEGATIVE_FACE.search(data, first_face) is not None


def _stl_starts_solid(data: bytes) -> bool:
    """Whether an STL (``data``) starts with "solid", as an ASCII one does (after blanks and a byte-order mark)."""
    return data[:STL_HEADER_BYTES].lstrip(b" \t\r\n\xef\xbb\xbf")[:5].lower() == b"solid"


def _binary_stl_bytes(data: bytes) -> int | None:
    """The length of a binary STL of the triangle count in bytes 80 to 84 of ``data``; None for a file shorter than
    the header."""
    if len(data) < STL_HEADER_BYTES:
        return None
    return STL_HEADER_BYTES + STL_TRIANGLE_BYTES * int.from_bytes(data[80:STL_HEADER_BYTES], "little")


def _stl_damage(path: Path, data: bytes) -> str | None:
    """What is wrong with an STL file (``data``, the bytes of ``path``) trimesh found no triangles in: an ASCII one
    that does not end in "endsolid" (cut short), or a binary one whose length is not what its triangle count says
    (cut short, bytes appended, the count damaged; trimesh then read it as ASCII); else None."""
    if _stl_starts_solid(data):   # ASCII
        if b"endsolid" not in data[-4096:].lower():
            return f"{path}: ASCII STL that does not end in 'endsolid': truncated or corrupt"
        return None
    start = data[:4096]
    if b"\0" not in start and re.search(rb"facet[ \t]+normal", start, re.I):   # text after all: its first line lost
        return f"{path}: ASCII STL that does not start with 'solid': cut at its start or corrupt"
    size, want = len(data), _binary_stl_bytes(data)
    if want is None or size == want:
        return None
    count = (want - STL_HEADER_BYTES) // STL_TRIANGLE_BYTES
    return (f"{path}: binary STL header says {count} triangles ({STL_HEADER_BYTES} + {STL_TRIANGLE_BYTES} x {count} "
            f"= {want} bytes) but the file is {size} bytes: truncated or corrupt")


def _stl_read_as_ascii(data: bytes) -> bool:
    """Whether trimesh reads an STL (``data``) as ASCII: it starts with "solid" and is not as long as a binary STL
    of the triangle count in its bytes 80 to 84 (trimesh tries binary first)."""
    return _binary_stl_bytes(data) != len(data) and _stl_starts_solid(data)


def _stl_damaged_line(data: bytes) -> tuple[int, str] | None:
    """The first damaged line of an ASCII STL (``data``; ``_STL_DAMAGED_LINE``): its number and what it holds, or
    None.  A pass over the file, run only where trimesh stopped or fell short."""
    m = _STL_DAMAGED_LINE.search(data) if _stl_read_as_ascii(data) else None
    if m is None:
        return None
    return _line_number(data, m.start()), m.group(0).strip(b" \t\r").decode("utf-8", "replace")[:50]


def _stl_line_problem(path: Path, data: bytes) -> str | None:
    """An ASCII STL's first damaged line (``_stl_damaged_line``) named with what was expected there, or None."""
    damaged = _stl_damaged_line(data)
    if damaged is None:
        return None
    number, text = damaged
    expected = ("'vertex x y z': three numbers" if text[:6].lower() == "vertex" else
                "solid, facet normal, outer loop, vertex, endloop, endfacet or endsolid")
    return f"{path}:{number}: ASCII STL line {text!r} (expected {expected}): corrupt"


def _check_ascii_stl_read(path: Path, data: bytes, triangles: int) -> None:
    """Refuse an ASCII STL (``data``, the bytes of ``path``) trimesh read ``triangles`` from where its 'vertex' lines
    make another number, or its 'endfacet' lines say another, or that holds NUL bytes: trimesh reads the numbers after
    every 'vertex' up to the first that does not parse, and dropped whole facets without a word (a zeroed run: 76 of
    80).  Counted in the bytes as they are first, lower-cased only where that falls short."""
    if b"\0" not in data and data.count(b"vertex") == 3 * triangles and data.count(b"endfacet") == triangles:
        return
    low = data.lower()
    vertices, ends, nul = low.count(b"vertex"), low.count(b"endfacet"), b"\0" in data
    if nul or vertices != 3 * triangles or ends != triangles:
        number, text = _stl_damaged_line(data) or ("", "")
        raise WarpbwError(_stl_damage(path, data) or (
            f"{path}{f':{number}' if number else ''}: ASCII STL read as {triangles} triangles, but it has {ends} "
            f"'endfacet' and {vertices} 'vertex' lines{' and NUL bytes' if nul else ''}"
            f"{f' (first damaged line: {text!r})' if number else ''}: truncated or corrupt"))


def _gltf_document(path: Path, data: bytes) -> tuple[dict, list] | None:
    """The JSON document of a glTF file (``data``, the bytes of ``path``: a GLB, or a .gltf's text) and the length of
    each buffer as trimesh's reader holds it: a GLB's BIN chunks in turn, None for one read from a URI (not checked
    here).  None where the JSON does not parse or the GLB's first chunk is not JSON: trimesh's message says that.  A
    GLB chunk longer than the bytes after its head is refused (trimesh: "chunk was not expected length!")."""
    if path.suffix.lower() == ".gltf":
        text, chunks = data, []
    elif data[:4] == _GLB_MAGIC and data[16:20] == _GLB_JSON:
        start = GLB_HEADER_BYTES + GLB_CHUNK_HEAD_BYTES
        text = data[start:start + int.from_bytes(data[12:16], "little")]
        chunks, pos = [], start + len(text)
        while pos + GLB_CHUNK_HEAD_BYTES <= len(data):
            size, kind = int.from_bytes(data[pos:pos + 4], "little"), data[pos + 4:pos + 8]
            pos += GLB_CHUNK_HEAD_BYTES
            if pos + size > len(data):
                raise WarpbwError(f"{path}: GLB chunk {len(chunks) + 1} declares {size} bytes but {len(data) - pos} "
                                  "follow its head: truncated or corrupt")
            chunks.append(size if kind == _GLB_BIN else None)
            pos += size
    else:
        return None
    try:
        doc = json.loads(text)
    except (ValueError, UnicodeDecodeError):
        return None
    if not isinstance(doc, dict) or not isinstance(doc.get("buffers", []), list):
        return None
    bins = iter([size for size in chunks if size is not None])
    lengths = []
    for buffer in doc.get("buffers", []):   # trimesh: a buffer with a URI reads it, one without the next BIN chunk
        if isinstance(buffer, dict) and "uri" in buffer:
            lengths.append(None)
        elif (size := next(bins, None)) is not None:
            lengths.append(size)
    return doc, lengths + list(bins)


def _gltf_whole(path: Path, item: dict, key: str, what: str, default=None, least: int = 0) -> int:
    """``item[key]`` (``default`` when absent) when a whole number >= ``least``, else a one-line WarpbwError naming
    ``what`` (trimesh indexed lists with it: a negative one read another item, a float failed in Python's words)."""
    value = item.get(key, default)
    if value is None:
        raise WarpbwError(f"{path}: glTF {what} has no {key!r}")
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise WarpbwError(f"{path}: glTF {what}'s {key} {value!r} is not a whole number {least} or more")
    return value


def _check_gltf_views(path: Path, views: list, buffer_bytes: list) -> list:
    """Refuse a glTF bufferView that names a buffer the file lacks or passes its end (trimesh: "list index out of
    range", a bare AssertionError); the views' lengths in bytes."""
    lengths = []
    for i, view in enumerate(views):
        what = f"bufferView {i}"
        buffer = _gltf_whole(path, view, "buffer", what)
        start, size = _gltf_whole(path, view, "byteOffset", what, 0), _gltf_whole(path, view, "byteLength", what)
        if buffer >= len(buffer_bytes):
            raise WarpbwError(f"{path}: glTF {what} names buffer {buffer}, which the file does not hold (it has "
                              f"{len(buffer_bytes)})")
        held = buffer_bytes[buffer]
        if held is not None and start + size > held:
            raise WarpbwError(f"{path}: glTF {what} (bytes {start} to {start + size}) passes the end of buffer "
                              f"{buffer} ({held} bytes): truncated or corrupt")
        lengths.append(size)
    return lengths


def _check_gltf_accessors(path: Path, accessors: list, views: list, view_bytes: list) -> None:
    """Refuse a glTF accessor that names a bufferView the file lacks, has an unknown type, or whose elements pass its
    bufferView's end (trimesh: "list index out of range", a bare KeyError ('VEC7'), numpy's "cannot reshape")."""
    for i, acc in enumerate(accessors):
        what = f"accessor {i}"
        if "bufferView" not in acc:   # zeros, or data an extension or a sparse block supplies
            continue
        v = _gltf_whole(path, acc, "bufferView", what)
        if v >= len(views):
            raise WarpbwError(f"{path}: glTF {what} names bufferView {v}, which the file does not hold (it has "
                              f"{len(views)})")
        component, kind = acc.get("componentType"), acc.get("type")
        for key, value, known in (("componentType", component, GLTF_COMPONENT_BYTES),
                                  ("type", kind, GLTF_TYPE_COMPONENTS)):
            if isinstance(value, bool) or value not in known:
                raise WarpbwError(f"{path}: glTF {what}'s {key} {value!r} unknown (expected one of "
                                  f"{', '.join(map(str, known))})")
        count, start = _gltf_whole(path, acc, "count", what), _gltf_whole(path, acc, "byteOffset", what, 0)
        element = GLTF_COMPONENT_BYTES[component] * GLTF_TYPE_COMPONENTS[kind]
        stride = _gltf_whole(path, views[v], "byteStride", f"bufferView {v}", element, 1)
        end = start + (count - 1) * stride + element if count else start
        if end > view_bytes[v]:
            every = f", one every {stride} bytes" if stride != element else ""
            raise WarpbwError(f"{path}: glTF {what} ({count} {kind} of {element} bytes from byte {start}{every}) "
                              f"passes the end of bufferView {v} ({view_bytes[v]} bytes): truncated or corrupt")


def _check_gltf(path: Path, data: bytes) -> None:
    """Refuse a GLB or glTF (``data``, the bytes of ``path``) whose accessors or bufferViews reach past what it holds
    (``_check_gltf_views``, ``_check_gltf_accessors``), naming the index, before trimesh reads it."""
    parsed = _gltf_document(path, data)
    if parsed is None:
        return
    doc, buffer_bytes = parsed
    views, accessors = doc.get("bufferViews", []), doc.get("accessors", [])
    if not (isinstance(views, list) and isinstance(accessors, list)
            and all(isinstance(item, dict) for item in views + accessors)):
        return   # not a layout trimesh reads either: its message names it
    _check_gltf_accessors(path, accessors, views, _check_gltf_views(path, views, buffer_bytes))


def suffix_problem(path: Path) -> str | None:
    """What is wrong with the name of the mesh file ``path``, or None: trimesh picks its reader by the name's suffix
    alone, so an OBJ saved as "bunny" or "bunny.obj.bak" did not read ("malformed or unsupported mesh file")."""
    name = path.name.lower()
    if name.endswith(MESH_SUFFIXES):
        return None
    import trimesh

    if any(name.endswith(f".{f}") for f in trimesh.available_formats()):
        return None
    return (f"{path}: trimesh reads a mesh by its name's suffix, and has no reader for "
            f"{repr(path.suffix) if path.suffix else 'a name without one'} (expected a name ending in .obj, .ply, .stl "
            "or .glb, or another format trimesh reads)")


def read_failure(path: Path, data: bytes, exc: Exception) -> str:
    """The message for a file (``data``, the bytes of ``path``) trimesh stopped on with ``exc`` after the checks
    before it passed: the damage where an STL's check names it, else trimesh's words without a cause they do not give
    (a GLB's "list index out of range" was "a reference to something it does not hold", an accessor's bufferView)."""
    problem = format_damage(path, data) or (_stl_line_problem(path, data) if path.suffix.lower() == ".stl" else None)
    if problem:
        return problem
    if isinstance(exc, IndexError) and "out of bounds for axis 0" in str(exc):   # numpy's, trimesh indexing an array
        return f"{path}: an index in the file lies outside the array it indexes ({one_line(exc)}); malformed mesh"
    return f"{path}: malformed or unsupported mesh file (trimesh: {one_line(exc)}); expected {SUPPORTED}"


def check_before_reading(path: Path, data: bytes) -> None:
    """Refuse what trimesh would misread or stop on in words that do not say what is wrong (module docstring)."""
    suffix = path.suffix.lower()
    if suffix == ".obj":
        _check_obj_lines(path, data)
        problem = _obj_index_problem(path, data) if _obj_may_count_back_early(data) else None
        if problem:
            raise WarpbwError(problem)
    elif suffix == ".ply":
        _check_ply(path, data)
    elif suffix in (".glb", ".gltf"):
        _check_gltf(path, data)


def check_after_reading(path: Path, data: bytes, triangles: int, lost_uv: bool) -> None:
    """Refuse a file trimesh read ``triangles`` triangles from (``lost_uv``: without texture coordinates) short of
    what it holds: an ASCII STL's facets, an OBJ's texture coordinates dropped for an index out of range."""
    suffix = path.suffix.lower()
    if suffix == ".stl" and _stl_read_as_ascii(data):
        _check_ascii_stl_read(path, data, triangles)
    if suffix == ".obj" and lost_uv and b"vt " in data:
        problem = _obj_index_problem(path, data)
        if problem:
            raise WarpbwError(problem)


def format_damage(path: Path, data: bytes) -> str | None:
    """What an STL's lengths (``_stl_damage``) or an OBJ's face indices (``_obj_index_problem``) say is wrong with a
    file trimesh read no triangles, or faces outside its vertices, from; None where they say nothing."""
    named = {".stl": _stl_damage, ".obj": _obj_index_problem}.get(path.suffix.lower())
    return None if named is None else named(path, data)


def _gltf_triangles(doc: dict) -> int:
    """The triangles a glTF document (``doc``) places: each mesh's triangle primitives (``_GLTF_TRIANGLES``,
    ``_GLTF_STRIP_OR_FAN``) counted from their index or position accessor, once for each node that names the mesh
    (each mesh once where no node does), as trimesh concatenates them.  A KeyError, TypeError or IndexError where
    the document is not laid out so."""
    accessors = doc.get("accessors", [])

    def mesh_triangles(mesh: dict) -> int:
        total = 0
        for prim in mesh.get("primitives", []):
            mode = prim.get("mode", _GLTF_TRIANGLES)
            count = int(accessors[prim["indices"] if "indices" in prim else prim["attributes"]["POSITION"]]["count"])
            total += count // 3 if mode == _GLTF_TRIANGLES else max(count - 2, 0) if mode in _GLTF_STRIP_OR_FAN else 0
        return total

    per_mesh = [mesh_triangles(m) for m in doc.get("meshes", [])]
    placed = [node["mesh"] for node in doc.get("nodes", []) if "mesh" in node]
    return sum(per_mesh[m] for m in placed) if placed else sum(per_mesh)


def triangle_count(path: Path, data) -> int | None:
    """How many triangles a mesh file (``data``: the bytes of ``path``, or a memory map of them) holds, without
    reading its geometry: an OBJ's face lines (a face of n corners is n - 2 triangles, as trimesh cuts it), a PLY's
    face count (a polygon counted as one), an STL's triangle count or facets, a GLB's or glTF's triangle primitives
    (``_gltf_triangles``).  None for another format, or where the header does not read (a render says what is
    wrong with it)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".obj":
            # corners - 2 a face (its "f" is one of its words): a line at a time, so a huge file takes no copy
            return sum(len(m.group().split()) - 3 for m in _OBJ_FACE_LINE.finditer(data))
        if suffix == ".ply":
            face = {e.name: e for e in _ply_header(path, data)[1]}.get("face")
            return 0 if face is None else face.count
        if suffix == ".stl":
            if _binary_stl_bytes(data) == len(data):
                return (len(data) - STL_HEADER_BYTES) // STL_TRIANGLE_BYTES
            return sum(1 for _ in _STL_FACET.finditer(data)) if _stl_starts_solid(data) else None
        if suffix in (".glb", ".gltf"):
            parsed = _gltf_document(path, bytes(data) if suffix == ".gltf" else data)
            return None if parsed is None else _gltf_triangles(parsed[0])
    except (WarpbwError, KeyError, TypeError, IndexError, ValueError, AttributeError):
        return None
    return None
