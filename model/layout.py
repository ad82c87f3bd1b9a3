"""The scene's memory image: the only thing the golden model's traversal and the RTL read.

A flat array of little-endian 64-bit words (word address = byte address // 8), laid out as
documented bit by bit in ``docs/memory-format.md``::

    word 0..7       header (magic "SAARCOR1", section bases, counts, depth, format, scene box)
    node_base       kd-nodes, one word each (node i at node_base + i)
    list_base       triangle list, 32-bit entries, two per word (low half first)
    tri_base        triangles, 5 words each (9 x binary32 vertices + 32-bit scene-order id;
                    Config.int_test = "projection": the precomputed record's 9 x binary32,
                    its axis k in the two spare exponent bits of n_u and n_v, and the id)
    shade_base      shading data (own 8-word header, material ids, normals, UVs, materials,
                    texture directory, RGBA8 texels, and the RGS slave's per-triangle records:
                    face normal, vertex normals, flags)

Every section starts at a multiple of 8 words. Floating-point values are binary32 bit patterns
of values of the configured format (for M < 23 the low fraction bits are zero).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import Config
from .fp import FPFormat

MAGIC = int(np.frombuffer(b"SAARCOR1", "<u8")[0])
SHADE_MAGIC = int(np.frombuffer(b"SHADING1", "<u8")[0])
HEADER_WORDS = 8
ALIGN = 8                     # every section starts at a multiple of 8 words
TRI_WORDS = 5                 # 9 x binary32 (288 bits) + 32-bit id = 5 words
PROJ_K_BIT = 30               # projection records: k's bit 0 (1) is bit 30 of n_u (n_v),
                              # the exponent's top bit, always 0 as |n_u|, |n_v| <= 1
HDR_PROJECTION = 56           # header word 4 bit 56: the triangles are projection records
LEAF = 3                      # node axis code of a leaf (0, 1, 2: split axis x, y, z)
NODE_INDEX_BITS = 30          # left-child index / leaf triangle count
LIST_INDEX_BITS = 32          # leaf's first list entry
ADDR_BITS = 32                # word addresses in the header (32 GB of memory)
SHADE_HEADER_WORDS = 8
NORMAL_WORDS = 5              # 9 x binary32 per triangle + pad
UV_WORDS = 3                  # 6 x binary32 per triangle
MATERIAL_WORDS = 8            # 16 x 32 bits per material
# the slave's shading record: 28 slots of 32 bits (14 memory words), by slot
REC_NF = 0                    # 0..2: the unit face normal (format bits)
REC_NV = 3                    # 3..11: the vertex normals A, B, C (the face normal when none)
REC_FLAGS = 12                # 12: flags (below)
REC_KD = 13                   # 13..15: kd x (1 - reflectivity)
REC_KS = 16                   # 16..18: ks x (1 - reflectivity)
REC_KR = 19                   # 19: the reflectivity
REC_UV = 20                   # 20..25: the texture coordinates of A, B, C (textured only)
REC_KT = 20                   # 20..22: kt, eta_in, eta_out (transmitting, untextured only)
REC_TEX_ADDR = 26             # 26: the texture's first texel word (textured only)
REC_TEX_SIZE = 27             # 27: the texture's width | height << 16 (textured only)
REC_SLOTS = 28
REC_WORDS = REC_SLOTS // 2
REC_BITS = REC_SLOTS * 32
REC_REFLECTIVE = 1            # flags bit 0: the material reflects (reflect > 0)
REC_TEXTURED = 2              # flags bit 1: the material has a texture (and the scene UVs)
REC_TRANSMITS = 4             # flags bit 2: the material transmits (transmit > 0, untextured)
REC_SHIN_SHIFT = 16           # flags bits 16..25: the Phong exponent (0..1023)
SHIN_BITS = 10
NO_TEXTURE = 0xFFFFFFFF

MATERIAL_DTYPE = np.dtype([
    ("diffuse", "<f4", (3,)), ("specular", "<f4", (3,)), ("shininess", "<f4"),
    ("reflect", "<f4"), ("transmit", "<f4"), ("ior", "<f4"), ("emission", "<f4", (3,)),
    ("texture", "<i4"),       # index into the texture directory, -1 = none
])
"""One material, in the order of its 32-bit slots in memory (slots 14, 15 are zero)."""


class LayoutError(ValueError):
    """The scene does not fit a field of the memory format; the message names the field."""


def _align(x: int) -> int:
    return (x + ALIGN - 1) // ALIGN * ALIGN


def _f32_bits(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x, dtype="<f4").view("<u4")


def _pack_u32(vals: np.ndarray) -> np.ndarray:
    """32-bit values, two per 64-bit word, low half first."""
    v = np.ascontiguousarray(vals, dtype="<u4").ravel()
    if v.size % 2:
        v = np.concatenate([v, np.zeros(1, "<u4")])
    return v.view("<u8")


def _lohi(lo: int, hi: int) -> int:
    return (int(lo) & 0xFFFFFFFF) | (int(hi) & 0xFFFFFFFF) << 32


def face_normals(tris: np.ndarray, fmt: FPFormat) -> np.ndarray:
    """Unit normals (N, 3) of triangles ``tris`` (N, 3, 3), (B - A) x (C - A) normalized in
    float64 and rounded once to ``fmt`` (a zero-area triangle gives a zero vector): the face
    normals the slave records hold."""
    t = np.asarray(tris, np.float64)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return fmt.quantize(n)


def rec_material(mats: np.ndarray, fmt: FPFormat) -> dict:
    """The colour constants of materials ``mats`` (MATERIAL_DTYPE) as the slave records hold
    them: ``kd`` = (1 - reflect - transmit) * diffuse and ``ks`` = (1 - reflect - transmit) *
    specular ((n, 3), the light the surface itself sends back; the rest goes to the reflection
    and the refracted ray), ``kr`` = reflect, ``kt`` = transmit, ``eta_in`` = 1 / ior (a ray
    entering the mesh), ``eta_out`` = ior (leaving it) ((n,) each), each computed in float64
    and rounded once to ``fmt``; ``shin`` = the Phong exponent rounded to an integer and
    clipped to 0..1023 ((n,) int)."""
    mats = np.asarray(mats)
    keep = (1.0 - mats["reflect"].astype(np.float64) - mats["transmit"].astype(np.float64)
            )[:, None]
    ior = mats["ior"].astype(np.float64)
    ior = np.where(ior > 0, ior, 1.0)                # an unset record (ior 0) refracts nothing
    return {"kd": fmt.quantize(keep * mats["diffuse"].astype(np.float64)).astype(np.float32),
            "ks": fmt.quantize(keep * mats["specular"].astype(np.float64)).astype(np.float32),
            "kr": fmt.quantize(mats["reflect"].astype(np.float64)).astype(np.float32),
            "kt": fmt.quantize(mats["transmit"].astype(np.float64)).astype(np.float32),
            "eta_in": fmt.quantize(1.0 / ior).astype(np.float32),
            "eta_out": fmt.quantize(ior).astype(np.float32),
            "shin": np.clip(np.rint(mats["shininess"].astype(np.float64)), 0,
                            (1 << SHIN_BITS) - 1).astype(np.int64)}


def projection_records(tris: np.ndarray, fmt: FPFormat) -> tuple[np.ndarray, np.ndarray]:
    """The projection test's triangle records (Wald et al. 2001): (N, 9) float32 values of
    ``fmt`` (n_u, n_v, n_d, b_nu, b_nv, b_d, c_nu, c_nv, c_d) and (N,) uint8 k.

    Computed in float64 from the vertices A, B, C, then rounded once to ``fmt``. N = (B - A) x
    (C - A); k is the axis of N's largest magnitude (the lowest on a tie), u = (k+1) % 3,
    v = (k+2) % 3. With N scaled so that its k component is 1, the plane is
    ``p[k] + n_u p[u] + n_v p[v] = n_d``. In the projection onto (u, v),
    ``lambda = b_nu h_u + b_nv h_v + b_d`` is the hit point's weight of B and
    ``mu = c_nu h_u + c_nv h_v + c_d`` its weight of C (the watertight test's u and v).
    As N[k] is the largest magnitude, |n_u| <= 1 and |n_v| <= 1 (after rounding too): the top
    bit of their binary32 exponents is always 0, and the memory image keeps k there
    (``PROJ_K_BIT``). A degenerate triangle (N[k] = 0, or a coefficient that does not fit
    ``fmt``) gets the record that never hits: all zero but b_d = -1 (lambda is -1 or NaN,
    never >= 0), k = 0."""
    t = np.asarray(tris, np.float64).reshape(-1, 3, 3)
    n = t.shape[0]
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    e1, e2 = b - a, c - a
    nrm = np.cross(e1, e2)
    k = np.argmax(np.abs(nrm), axis=1)
    r = np.arange(n)
    ku, kv = (k + 1) % 3, (k + 2) % 3
    nk = nrm[r, k]
    good = nk != 0
    nk1 = np.where(good, nk, 1.0)
    n_u, n_v = nrm[r, ku] / nk1, nrm[r, kv] / nk1
    n_d = a[r, k] + n_u * a[r, ku] + n_v * a[r, kv]
    # 2-D: H - A = lambda e1 + mu e2 in (u, v); the 2x2 determinant is N[k]
    au, av = a[r, ku], a[r, kv]
    e1u, e1v, e2u, e2v = e1[r, ku], e1[r, kv], e2[r, ku], e2[r, kv]
    rec = np.stack([n_u, n_v, n_d,
                    e2v / nk1, -e2u / nk1, (av * e2u - au * e2v) / nk1,
                    -e1v / nk1, e1u / nk1, (au * e1v - av * e1u) / nk1], axis=1)
    with np.errstate(over="ignore", invalid="ignore"):
        q = fmt.quantize(rec).astype(np.float32)
    good &= np.isfinite(q).all(axis=1)
    q[~good] = 0
    q[~good, 5] = -1
    return q, np.where(good, k, 0).astype(np.uint8)


def image_size_words(n_nodes: int, n_list: int, n_tris: int) -> int:
    """Words of an image without shading data beyond the (empty) shading header."""
    return (HEADER_WORDS + _align(n_nodes) + _align((n_list + 1) // 2) + _align(TRI_WORDS * n_tris)
            + SHADE_HEADER_WORDS)


@dataclass
class ShadingData:
    """Per-triangle shading inputs, indexed like the ``tris`` given to :func:`build_image`."""

    mat_id: np.ndarray                        # (N,) material index per triangle
    materials: np.ndarray                     # (n_materials,) MATERIAL_DTYPE
    normals: np.ndarray | None = None         # (N, 3, 3) per-vertex normals A, B, C
    uvs: np.ndarray | None = None             # (N, 3, 2) per-vertex texture coordinates
    textures: list = field(default_factory=list)  # each (h, w, 4) uint8 RGBA


@dataclass
class MemoryImage:
    data: np.ndarray       # uint64 little-endian memory words
    node_base: int
    list_base: int
    tri_base: int
    shade_base: int
    n_nodes: int
    n_list: int
    n_tris: int
    root: int
    bounds: np.ndarray     # (2, 3) float32
    depth: int
    fmt: FPFormat
    projection: bool = False   # the triangles are projection records (Config.int_test)

    def words(self) -> np.ndarray:
        return self.data

    def tobytes(self) -> bytes:
        return self.data.astype("<u8").tobytes()

    def save(self, path) -> None:
        """Write the raw little-endian image (the header describes everything else)."""
        Path(path).write_bytes(self.tobytes())

    @classmethod
    def load(cls, path) -> "MemoryImage":
        raw = Path(path).read_bytes()
        if len(raw) % 8:
            raise LayoutError(f"{path}: {len(raw)} bytes is not a whole number of 64-bit words")
        return cls.from_words(np.frombuffer(raw, "<u8").astype(np.uint64))

    @classmethod
    def from_words(cls, data: np.ndarray) -> "MemoryImage":
        """Parse the header of a raw image."""
        data = np.asarray(data, dtype=np.uint64)
        if data.size < HEADER_WORDS or int(data[0]) != MAGIC:
            raise LayoutError("not a SaarCOR memory image: word 0 is not the magic 'SAARCOR1' "
                              "(was the file written by MemoryImage.save?)")
        h = [int(w) for w in data[:HEADER_WORDS]]
        lo = lambda w: w & 0xFFFFFFFF  # noqa: E731
        hi = lambda w: w >> 32  # noqa: E731
        E, M = (h[4] >> 40) & 0xFF, (h[4] >> 48) & 0xFF
        bounds = data[5:8].astype("<u8").view("<f4").reshape(2, 3).copy()
        img = cls(data=data, node_base=lo(h[1]), list_base=hi(h[1]), tri_base=lo(h[2]),
                  shade_base=hi(h[2]), n_nodes=lo(h[3]), n_tris=hi(h[3]), n_list=lo(h[4]),
                  root=0, bounds=bounds, depth=(h[4] >> 32) & 0xFF, fmt=FPFormat(E, M),
                  projection=bool((h[4] >> HDR_PROJECTION) & 1))
        if img.shade_base + SHADE_HEADER_WORDS > data.size:
            raise LayoutError(f"memory image truncated: {data.size} words, header says the "
                              f"shading section starts at word {img.shade_base}")
        return img

    # -- debug accessors (the hardware reads the same fields) ------------------------------
    def node(self, i: int) -> tuple:
        return decode_node(int(self.data[self.node_base + i]))

    def list_entries(self) -> np.ndarray:
        """All triangle-list entries (uint32)."""
        w = self.data[self.list_base:self.list_base + (self.n_list + 1) // 2]
        return w.astype("<u8").view("<u4")[:self.n_list]

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """(n_tris, 3, 3) float32 vertices (a projection image: each record's 9 words, k's
        bits in place) and (n_tris,) uint32 scene-order ids."""
        w = self.data[self.tri_base:self.tri_base + TRI_WORDS * self.n_tris]
        u = w.astype("<u8").view("<u4").reshape(self.n_tris, 2 * TRI_WORDS)
        return u[:, :9].copy().view("<f4").reshape(-1, 3, 3), u[:, 9].copy()

    def scene_ids(self, index: np.ndarray) -> np.ndarray:
        """Scene-order ids (int32) of triangles given by their index in the image (-1 stays -1:
        a miss)."""
        ids = self._ids()[2]
        return ids[np.asarray(index)]       # index -1 reads the last entry: -1

    def scene_id_table(self) -> np.ndarray:
        """:meth:`scene_ids` as a table (int32): entry i is triangle i's scene-order id, the
        last entry -1 (a miss)."""
        return self._ids()[2]

    def tri_index(self, scene_id: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`scene_ids`: image indices (int64) of scene-order ids (-1 stays
        -1; an id of no triangle in the image raises ``KeyError``)."""
        ids, inv, _ = self._ids()
        scene_id = np.asarray(scene_id, np.int64)
        hit = scene_id >= 0
        if hit.any() and (scene_id.max() >= len(inv) or (inv[scene_id[hit]] < 0).any()):
            raise KeyError("a triangle id that no triangle of the memory image has")
        return np.where(hit, inv[np.where(hit, scene_id, 0)], -1)

    def _ids(self):
        if getattr(self, "_id_cache", None) is None:
            w = self.data[self.tri_base + 4:self.tri_base + TRI_WORDS * self.n_tris:TRI_WORDS]
            ids = (w >> np.uint64(32)).astype(np.int64)
            inv = np.full(int(ids.max()) + 1 if len(ids) else 0, -1, np.int64)
            inv[ids] = np.arange(len(ids))
            self._id_cache = (ids, inv, np.append(ids, -1).astype(np.int32))
        return self._id_cache

    def shading_header(self) -> dict:
        h = [int(w) for w in self.data[self.shade_base:self.shade_base + SHADE_HEADER_WORDS]]
        lo, hi = (lambda w: w & 0xFFFFFFFF), (lambda w: w >> 32)
        return dict(magic_ok=h[0] == SHADE_MAGIC, n_materials=lo(h[1]), n_textures=hi(h[1]),
                    matid_base=lo(h[2]), normal_base=hi(h[2]), uv_base=lo(h[3]),
                    mat_base=hi(h[3]), texdir_base=lo(h[4]), texel_base=hi(h[4]),
                    has_normals=bool(h[5] & 1), has_uvs=bool(h[5] & 2), n_texel_words=hi(h[5]),
                    rec_base=lo(h[6]), rec_words=hi(h[6]))


def decode_node(word: int) -> tuple:
    """Decode a kd-node word: inner ``(axis, left_child, split)``, leaf ``(3, count, first)``."""
    word = int(word)
    axis = word & 3
    idx = (word >> 2) & ((1 << NODE_INDEX_BITS) - 1)
    top = (word >> 32) & 0xFFFFFFFF
    if axis == LEAF:
        return (LEAF, idx, top)
    split = float(np.array([top], "<u4").view("<f4")[0])
    return (axis, idx, split)


# ``KdTree`` below is model.kdtree.KdTree, named but not imported (model/kdtree.py imports this module)
def encode_nodes(tree: "KdTree") -> np.ndarray:
    """The node section: one uint64 word per node."""
    axis = tree.axis.astype(np.uint64)
    leaf = tree.axis == LEAF
    idx = np.where(leaf, tree.count, tree.child).astype(np.uint64)
    top = np.where(leaf, tree.first.astype(np.uint64), _f32_bits(tree.split).astype(np.uint64))
    return axis | (idx << np.uint64(2)) | (top << np.uint64(32))


def _check(name: str, value: int, bits: int, fix: str) -> None:
    if value >= 1 << bits:
        raise LayoutError(f"{name} = {value} does not fit the memory format's {bits}-bit field "
                          f"(max {(1 << bits) - 1}); {fix}")


def _shading_section(shading: ShadingData | None, n_tris: int, base: int, fmt: FPFormat,
                     tris: np.ndarray | None = None):
    """Words of the shading section starting at word address ``base`` (``tris``: the quantized
    triangles, for the records' face normals)."""
    hdr = np.zeros(SHADE_HEADER_WORDS, np.uint64)
    hdr[0] = SHADE_MAGIC
    if shading is None:
        return hdr
    q = lambda x: _f32_bits(fmt.quantize(np.asarray(x, np.float64)))  # noqa: E731
    mat_id = np.asarray(shading.mat_id)
    mats = np.asarray(shading.materials)
    if mats.dtype != MATERIAL_DTYPE:
        raise LayoutError(f"shading.materials has dtype {mats.dtype}; build it with "
                          "np.zeros(n, dtype=model.layout.MATERIAL_DTYPE)")
    n_mat, n_tex = mats.shape[0], len(shading.textures)
    if mat_id.shape != (n_tris,):
        raise LayoutError(f"shading.mat_id has shape {mat_id.shape}; expected ({n_tris},), "
                          "one material per triangle")
    if n_tris and (mat_id.min() < 0 or mat_id.max() >= n_mat):
        raise LayoutError(f"shading.mat_id holds values outside 0..{n_mat - 1} "
                          f"(there are {n_mat} materials)")
    if n_mat and (mats["texture"].min() < -1 or mats["texture"].max() >= n_tex):
        raise LayoutError(f"a material's texture index is outside -1..{n_tex - 1} "
                          f"(there are {n_tex} textures; -1 = none)")
    parts, addr = [hdr], base + SHADE_HEADER_WORDS

    def put(words):
        nonlocal addr
        start = addr
        w = np.zeros(_align(words.size), np.uint64)
        w[:words.size] = words
        parts.append(w)
        addr += w.size
        return start

    matid_base = put(_pack_u32(mat_id.astype(np.uint32)))
    normal_base = uv_base = 0
    if shading.normals is not None:
        nrm = np.asarray(shading.normals)
        if nrm.shape != (n_tris, 3, 3):
            raise LayoutError(f"shading.normals has shape {nrm.shape}; expected ({n_tris}, 3, 3)")
        u = np.zeros((n_tris, 2 * NORMAL_WORDS), "<u4")
        u[:, :9] = q(nrm).reshape(n_tris, 9)
        normal_base = put(u.view("<u8").ravel())
    if shading.uvs is not None:
        uv = np.asarray(shading.uvs)
        if uv.shape != (n_tris, 3, 2):
            raise LayoutError(f"shading.uvs has shape {uv.shape}; expected ({n_tris}, 3, 2)")
        uv_base = put(q(uv).reshape(n_tris, 6).view("<u8").ravel())
    m = np.zeros((n_mat, 2 * MATERIAL_WORDS), "<u4")
    m[:, 0:3] = q(mats["diffuse"])
    m[:, 3:6] = q(mats["specular"])
    m[:, 6] = q(mats["shininess"])
    m[:, 7] = q(mats["reflect"])
    m[:, 8] = q(mats["transmit"])
    m[:, 9] = q(mats["ior"])
    m[:, 10:13] = q(mats["emission"])
    m[:, 13] = mats["texture"].astype("<i4").view("<u4")
    mat_base = put(m.view("<u8").ravel())
    # texture directory (its size is known, so the texel addresses are too), then texels
    texels = []
    tex_dir = np.zeros(n_tex, np.uint64)
    taddr = addr + _align(n_tex)
    for t, tex in enumerate(shading.textures):
        tex = np.asarray(tex)
        if tex.ndim != 3 or tex.shape[2] != 4 or tex.dtype != np.uint8:
            raise LayoutError(f"texture {t} has shape {tex.shape} dtype {tex.dtype}; expected "
                              "(h, w, 4) uint8 RGBA")
        h, w = tex.shape[:2]
        if not (1 <= h < 1 << 16 and 1 <= w < 1 << 16):
            raise LayoutError(f"texture {t} is {w}x{h}; width and height must be 1..65535")
        tex_dir[t] = np.uint64(_lohi(w | h << 16, taddr))
        texels.append(_pack_u32(np.ascontiguousarray(tex).view("<u4").ravel()))
        taddr += _align(texels[-1].size)
    texdir_base = put(tex_dir)
    texel_base = addr
    for tw in texels:
        put(tw)
    n_texel_words = addr - texel_base
    # the slave's records: face normal, vertex normals A, B, C (face normal when none), flags,
    # the material's colour constants, texture coordinates, the texture's first texel word
    # and size
    rec = np.zeros((n_tris, REC_SLOTS), "<u4")
    if n_tris:
        fn = face_normals(tris, fmt)
        rec[:, REC_NF:REC_NF + 3] = _f32_bits(fn)
        vn = np.repeat(fn[:, None, :], 3, axis=1) if shading.normals is None else shading.normals
        rec[:, REC_NV:REC_NV + 9] = q(vn).reshape(n_tris, 9)
        mc = rec_material(mats, fmt)
        rec[:, REC_FLAGS] = (np.where(mats["reflect"][mat_id] > 0, REC_REFLECTIVE, 0)
                             | (mc["shin"][mat_id] << REC_SHIN_SHIFT).astype(np.uint32))
        rec[:, REC_KD:REC_KD + 3] = _f32_bits(mc["kd"][mat_id])
        rec[:, REC_KS:REC_KS + 3] = _f32_bits(mc["ks"][mat_id])
        rec[:, REC_KR] = _f32_bits(mc["kr"][mat_id])
        tex = mats["texture"][mat_id]
        textured = (tex >= 0) & (shading.uvs is not None)
        if textured.any():
            rec[:, REC_FLAGS] |= np.where(textured, REC_TEXTURED, 0).astype(np.uint32)
            uv = q(np.asarray(shading.uvs)).reshape(n_tris, 6)
            rec[textured, REC_UV:REC_UV + 6] = uv[textured]
            entry = tex_dir[tex[textured]]                  # | texel addr | height | width |
            rec[textured, REC_TEX_ADDR] = (entry >> np.uint64(32)).astype(np.uint32)
            rec[textured, REC_TEX_SIZE] = (entry & np.uint64(0xFFFFFFFF)).astype(np.uint32)
        # a material that transmits: kt, eta_in, eta_out where a textured one has its texture
        # coordinates (a textured material that transmits has the texture; the chip's slaves
        # refuse it, tb.harness.chip.frame_registers)
        trans = (mats["transmit"][mat_id] > 0) & ~textured
        if trans.any():
            rec[trans, REC_FLAGS] |= np.uint32(REC_TRANSMITS)
            for k, name in enumerate(("kt", "eta_in", "eta_out")):
                rec[trans, REC_KT + k] = _f32_bits(mc[name][mat_id[trans]])
    rec_base = put(rec.view("<u8").ravel())
    hdr[1] = _lohi(n_mat, n_tex)
    hdr[2] = _lohi(matid_base, normal_base)
    hdr[3] = _lohi(uv_base, mat_base)
    hdr[4] = _lohi(texdir_base, texel_base)
    hdr[5] = _lohi((shading.normals is not None) | (shading.uvs is not None) << 1, n_texel_words)
    hdr[6] = _lohi(rec_base, REC_WORDS)
    return np.concatenate(parts)


def build_image(tris: np.ndarray, tree: "KdTree", cfg: Config, tri_id: np.ndarray | None = None,
                shading: ShadingData | None = None) -> MemoryImage:
    """Lay out header, kd-nodes, triangle list, triangles and shading data in memory words.

    ``tris`` (N, 3, 3) float32 are the values of ``cfg.fmt`` the tree was built over (memory
    order); ``tri_id[i]`` is triangle i's scene-order id (default i)."""
    fmt = cfg.fmt
    tris = np.ascontiguousarray(tris, dtype=np.float32)
    n_tris = tris.shape[0]
    if tris.shape != (n_tris, 3, 3):
        raise LayoutError(f"tris has shape {tris.shape}; expected (N, 3, 3)")
    if n_tris and (fmt.quantize(tris).view(np.uint32) != tris.view(np.uint32)).any():
        raise LayoutError(f"tris are not values of {fmt}: quantize with cfg.fmt.quantize(tris) "
                          "and build the tree over the quantized triangles")
    if tri_id is None:
        tri_id = np.arange(n_tris, dtype=np.uint32)
    tri_id = np.asarray(tri_id)
    if tri_id.shape != (n_tris,):
        raise LayoutError(f"tri_id has shape {tri_id.shape}; expected ({n_tris},)")
    if n_tris and (tri_id.min() < 0 or int(tri_id.max()) >= 1 << 32):
        raise LayoutError("tri_id values must be in 0..2^32-1")
    if tree.tri_list.size and int(tree.tri_list.max()) >= n_tris:
        raise LayoutError(f"the tree lists triangle {int(tree.tri_list.max())} but only "
                          f"{n_tris} triangles were given: build the image with the same tris "
                          "as the tree")
    n_nodes, n_list = tree.n_nodes, tree.n_entries
    fix = "use a smaller scene or a shallower tree (cfg.kd_max_depth)"
    _check("n_nodes", n_nodes, NODE_INDEX_BITS, fix)
    _check("largest leaf count", int(tree.count.max()), NODE_INDEX_BITS, fix)
    _check("n_list (triangle-list entries)", n_list, LIST_INDEX_BITS, fix)
    _check("n_tris", n_tris, 32, "split the scene")
    _check("depth", tree.depth, 8, "use cfg.kd_max_depth <= 255")

    node_base = HEADER_WORDS
    list_base = node_base + _align(n_nodes)
    tri_base = list_base + _align((n_list + 1) // 2)
    shade_base = tri_base + _align(TRI_WORDS * n_tris)
    shade = _shading_section(shading, n_tris, shade_base, fmt, tris)
    total = shade_base + shade.size
    _check("image size in words", total, ADDR_BITS, "the scene needs more than 32 GB")

    data = np.zeros(total, np.uint64)
    data[0] = MAGIC
    data[1] = _lohi(node_base, list_base)
    data[2] = _lohi(tri_base, shade_base)
    data[3] = _lohi(n_nodes, n_tris)
    E, M = fmt.em
    data[4] = np.uint64(n_list | tree.depth << 32 | E << 40 | M << 48)
    bounds = np.ascontiguousarray(tree.bounds, dtype=np.float32)
    data[5:8] = _f32_bits(bounds).reshape(6).view("<u8")
    data[node_base:node_base + n_nodes] = encode_nodes(tree)
    lw = _pack_u32(tree.tri_list.astype(np.uint32))
    data[list_base:list_base + lw.size] = lw
    t = np.zeros((n_tris, 2 * TRI_WORDS), "<u4")
    if cfg.int_test == "projection":
        rec, k = projection_records(tris, fmt)
        t[:, :9] = _f32_bits(rec)
        t[:, 0] |= (k.astype(np.uint32) & 1) << np.uint32(PROJ_K_BIT)
        t[:, 1] |= (k.astype(np.uint32) >> 1) << np.uint32(PROJ_K_BIT)
        t[:, 9] = tri_id.astype(np.uint32)
        data[4] |= np.uint64(1 << HDR_PROJECTION)
    else:
        t[:, :9] = _f32_bits(tris).reshape(n_tris, 9)
        t[:, 9] = tri_id.astype(np.uint32)
    data[tri_base:tri_base + TRI_WORDS * n_tris] = t.view("<u8").ravel()
    data[shade_base:] = shade
    return MemoryImage(data=data, node_base=node_base, list_base=list_base, tri_base=tri_base,
                       shade_base=shade_base, n_nodes=n_nodes, n_list=n_list, n_tris=n_tris,
                       root=0, bounds=bounds.copy(), depth=tree.depth, fmt=fmt,
                       projection=cfg.int_test == "projection")


# ---------------------------------------------------------------------------------------------
# Amaranth layouts of the same words (imported lazily: the model does not need Amaranth)
# ---------------------------------------------------------------------------------------------

def node_layout():
    """kd-node word: ``axis`` (3 = leaf), ``index`` (left child / count), ``value`` (split
    bits / first list entry)."""
    from amaranth.lib import data
    return data.StructLayout({"axis": 2, "index": NODE_INDEX_BITS, "value": 32})


def list_word_layout():
    from amaranth.lib import data
    return data.ArrayLayout(32, 2)


def triangle_layout():
    """The 5 words of a triangle: 9 binary32 (A.xyz, B.xyz, C.xyz) then the 32-bit id."""
    from amaranth.lib import data
    return data.StructLayout({"v": data.ArrayLayout(32, 9), "id": 32})
