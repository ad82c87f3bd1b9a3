"""Memory image: header, node/list/triangle/shading sections decoded from the raw words (with
bit operations written here from docs/memory-format.md) and compared with the inputs."""
import numpy as np
import pytest

from model.config import Config
from model.fp import FPFormat
from model.kdtree import KdTree, build_kdtree
from model.layout import (LayoutError, MATERIAL_DTYPE, MemoryImage, ShadingData, build_image,
                          decode_node, node_layout, triangle_layout)


def soup(n, seed, fmt=FPFormat()):
    rng = np.random.default_rng(seed)
    return fmt.quantize(rng.random((n, 1, 3)) * 10 + rng.normal(size=(n, 3, 3)) * 0.3)


def u32(x):
    return int(np.float32(x).view(np.uint32))


def lo32(w):
    return int(w) & 0xFFFFFFFF


def hi32(w):
    return int(w) >> 32


def f32(bits):
    return np.uint32(bits).view(np.float32)


@pytest.mark.parametrize("fmt", [FPFormat(8, 23), FPFormat(8, 16)], ids=str)
def test_round_trip(fmt):
    tris = soup(700, 1, fmt)
    cfg = Config(fmt=fmt)
    tree = build_kdtree(tris, cfg, cache_dir=None)
    tri_id = np.random.default_rng(2).permutation(len(tris)).astype(np.uint32) + 1000
    img = build_image(tris, tree, cfg, tri_id=tri_id)
    w = img.data
    assert w.dtype == np.uint64
    # header
    assert img.tobytes()[:8] == b"SAARCOR1"
    assert (lo32(w[1]), hi32(w[1])) == (img.node_base, img.list_base)
    assert (lo32(w[2]), hi32(w[2])) == (img.tri_base, img.shade_base)
    assert (lo32(w[3]), hi32(w[3])) == (tree.n_nodes, len(tris))
    assert lo32(w[4]) == tree.n_entries
    assert ((int(w[4]) >> 32) & 0xFF, (int(w[4]) >> 40) & 0xFF, (int(w[4]) >> 48) & 0xFF) == \
        (tree.depth, fmt.exp_bits, fmt.frac_bits)
    b = [f32(lo32(w[5])), f32(hi32(w[5])), f32(lo32(w[6])), f32(hi32(w[6])), f32(lo32(w[7])),
         f32(hi32(w[7]))]
    assert np.array_equal(np.array(b, np.float32).reshape(2, 3), tree.bounds)
    # sections: aligned, ordered, not overlapping
    for base in (img.node_base, img.list_base, img.tri_base, img.shade_base):
        assert base % 8 == 0
    assert 8 <= img.node_base and img.node_base + tree.n_nodes <= img.list_base
    assert img.list_base + (tree.n_entries + 1) // 2 <= img.tri_base
    assert img.tri_base + 5 * len(tris) <= img.shade_base <= len(w)
    # nodes, decoded by hand and by decode_node
    for i in range(tree.n_nodes):
        word = int(w[img.node_base + i])
        kind = word & 3
        assert kind == tree.axis[i]
        if kind == 3:
            assert (word >> 2) & (2**30 - 1) == tree.count[i]
            assert word >> 32 == tree.first[i]
            assert decode_node(word) == (3, tree.count[i], tree.first[i])
        else:
            assert (word >> 2) & (2**30 - 1) == tree.child[i]
            assert word >> 32 == u32(tree.split[i])
            assert decode_node(word) == (kind, tree.child[i], float(tree.split[i]))
    # list entries at byte list_base*8 + 4*j
    raw = img.tobytes()
    ents = np.frombuffer(raw, "<u4", count=tree.n_entries, offset=img.list_base * 8)
    assert np.array_equal(ents, tree.tri_list)
    assert np.array_equal(img.list_entries(), tree.tri_list)
    # triangles: 5 words, 9 binary32 then the id
    for i in range(0, len(tris), 37):
        words = w[img.tri_base + 5 * i: img.tri_base + 5 * i + 5]
        halves = [h for x in words for h in (lo32(x), hi32(x))]
        assert halves[:9] == [u32(v) for v in tris[i].ravel()]
        assert halves[9] == tri_id[i]
    v, ids = img.triangles()
    assert np.array_equal(v.view(np.uint32), tris.view(np.uint32))
    assert np.array_equal(ids, tri_id)
    # formats with M < 23: the low fraction bits of every stored value are zero
    if fmt.frac_bits < 23:
        low = (1 << (23 - fmt.frac_bits)) - 1
        assert not (v.view(np.uint32) & low).any()
        assert not (tree.split.view(np.uint32) & low).any()


def test_save_load(tmp_path):
    tris = soup(200, 3, FPFormat(8, 16))
    cfg = Config(fmt=FPFormat(8, 16))
    img = build_image(tris, build_kdtree(tris, cfg, cache_dir=None), cfg)
    img.save(tmp_path / "scene.bin")
    assert (tmp_path / "scene.bin").stat().st_size == 8 * len(img.data)
    back = MemoryImage.load(tmp_path / "scene.bin")
    assert np.array_equal(back.data, img.data)
    for f in ("node_base", "list_base", "tri_base", "shade_base", "n_nodes", "n_list", "n_tris",
              "root", "depth", "fmt"):
        assert getattr(back, f) == getattr(img, f), f
    assert np.array_equal(back.bounds, img.bounds)
    (tmp_path / "bad.bin").write_bytes(b"NOTANIMG" * 8)
    with pytest.raises(LayoutError, match="magic"):
        MemoryImage.load(tmp_path / "bad.bin")


def test_hand_built_tree_words():
    """A 3-node tree: root splits y at 2.5; left leaf has triangles [1, 0]; right leaf empty."""
    tree = KdTree(axis=np.array([1, 3, 3], np.uint8), split=np.array([2.5, 0, 0], np.float32),
                  child=np.array([1, 0, 0], np.int32), first=np.array([0, 0, 2], np.int32),
                  count=np.array([0, 2, 0], np.int32), tri_list=np.array([1, 0], np.int32),
                  bounds=np.array([[0, 0, 0], [4, 4, 4]], np.float32), depth=1)
    tris = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 1], [1, 2, 1], [0, 2, 2]]],
                    np.float32)
    img = build_image(tris, tree, Config())
    assert img.node_base == 8 and img.list_base == 16 and img.tri_base == 24
    assert img.shade_base == 40
    assert int(img.data[8]) == 0x40200000_00000005     # 2.5 = 0x40200000, child 1, axis 1
    assert int(img.data[9]) == 0x00000000_0000000B     # first 0, count 2, leaf
    assert int(img.data[10]) == 0x00000002_00000003    # first 2, count 0, leaf
    assert int(img.data[16]) == 0x00000000_00000001    # entries 1, 0
    assert int(img.data[24 + 5 + 4]) >> 32 == 1         # id of triangle 1
    assert int(img.data[24 + 5]) == 0x3F800000_00000000  # triangle 1: A.x = 0, A.y = 1.0
    assert int(img.data[0]) == int.from_bytes(b"SAARCOR1", "little")
    assert int(img.data[4]) == 2 | 1 << 32 | 8 << 40 | 23 << 48


def test_field_overflow_and_bad_input():
    tree = KdTree(axis=np.array([3], np.uint8), split=np.zeros(1, np.float32),
                  child=np.zeros(1, np.int32), first=np.zeros(1, np.int32),
                  count=np.array([2**30], np.int32), tri_list=np.zeros(0, np.int32),
                  bounds=np.zeros((2, 3), np.float32), depth=0)
    with pytest.raises(LayoutError, match="30-bit"):
        build_image(np.zeros((1, 3, 3), np.float32), tree, Config())
    cfg = Config(fmt=FPFormat(8, 10))
    tris = soup(10, 4, FPFormat(8, 10))
    tree = build_kdtree(tris, cfg, cache_dir=None)
    with pytest.raises(LayoutError, match="quantize"):
        build_image(tris + np.float32(1e-3), tree, cfg)
    with pytest.raises(LayoutError, match="same tris"):
        build_image(tris[:3], tree, cfg)


def test_shading_section():
    fmt = FPFormat(8, 16)
    cfg = Config(fmt=fmt)
    tris = soup(5, 5, fmt)
    tree = build_kdtree(tris, cfg, cache_dir=None)
    mats = np.zeros(2, MATERIAL_DTYPE)
    mats[0]["diffuse"] = [0.8, 0.1, 0.1]
    mats[0]["texture"] = -1
    mats[1]["diffuse"] = [0.5, 0.5, 0.5]
    mats[1]["ior"] = 1.5
    mats[1]["emission"] = [0, 0, 2]
    mats[1]["texture"] = 1
    rng = np.random.default_rng(6)
    normals = rng.normal(size=(5, 3, 3)).astype(np.float32)
    uvs = rng.random((5, 3, 2)).astype(np.float32)
    tex0 = rng.integers(0, 256, size=(2, 3, 4), dtype=np.uint8)
    tex1 = rng.integers(0, 256, size=(1, 1, 4), dtype=np.uint8)
    sh = ShadingData(mat_id=np.array([0, 1, 1, 0, 1]), materials=mats, normals=normals, uvs=uvs,
                     textures=[tex0, tex1])
    img = build_image(tris, tree, cfg, shading=sh)
    w = img.data
    s = img.shade_base
    assert int(w[s]) == int.from_bytes(b"SHADING1", "little")
    assert (lo32(w[s + 1]), hi32(w[s + 1])) == (2, 2)
    matid_base, normal_base = lo32(w[s + 2]), hi32(w[s + 2])
    uv_base, mat_base = lo32(w[s + 3]), hi32(w[s + 3])
    texdir_base, texel_base = lo32(w[s + 4]), hi32(w[s + 4])
    assert lo32(w[s + 5]) == 3
    for base in (matid_base, normal_base, uv_base, mat_base, texdir_base, texel_base):
        assert base % 8 == 0 and s + 8 <= base < len(w)
    raw = img.tobytes()
    ids = np.frombuffer(raw, "<u4", count=5, offset=8 * matid_base)
    assert ids.tolist() == [0, 1, 1, 0, 1]
    q = lambda x: fmt.quantize(x).view(np.uint32)  # noqa: E731
    for i in range(5):
        n = np.frombuffer(raw, "<u4", count=10, offset=8 * (normal_base + 5 * i))
        assert np.array_equal(n[:9], q(normals[i].ravel())) and n[9] == 0
        uv = np.frombuffer(raw, "<u4", count=6, offset=8 * (uv_base + 3 * i))
        assert np.array_equal(uv, q(uvs[i].ravel()))
    m1 = np.frombuffer(raw, "<u4", count=16, offset=8 * (mat_base + 8))
    assert np.array_equal(m1[0:3], q(np.float32([0.5, 0.5, 0.5])))
    assert m1[9] == u32(1.5) and m1[12] == u32(2.0) and m1[13] == 1
    m0 = np.frombuffer(raw, "<u4", count=16, offset=8 * mat_base)
    assert m0[13] == 0xFFFFFFFF
    for t, tex in enumerate([tex0, tex1]):
        d = int(w[texdir_base + t])
        assert d & 0xFFFF == tex.shape[1] and (d >> 16) & 0xFFFF == tex.shape[0]
        addr = d >> 32
        assert addr >= texel_base
        texels = np.frombuffer(raw, np.uint8, count=tex.size, offset=8 * addr)
        assert np.array_equal(texels.reshape(tex.shape), tex)   # R, G, B, A bytes, row-major
    with pytest.raises(LayoutError, match="mat_id"):
        build_image(tris, tree, cfg, shading=ShadingData(mat_id=np.array([0, 1, 2, 0, 0]),
                                                         materials=mats))


def test_no_shading_header_only():
    tris = soup(20, 7)
    cfg = Config()
    img = build_image(tris, build_kdtree(tris, cfg, cache_dir=None), cfg)
    assert len(img.data) == img.shade_base + 8
    assert int(img.data[img.shade_base + 1]) == 0


def test_amaranth_layouts_match_word_sizes():
    assert node_layout().size == 64
    assert triangle_layout().size == 5 * 64


def test_scene_ids_and_tri_index_are_inverse(tmp_path):
    """The hardware names a hit triangle by its index in the image; the image's fifth triangle
    word maps it to the scene-order id (ids with gaps: dropped triangles) and back."""
    cfg = Config()
    tris = soup(40, 7)
    ids = np.sort(np.random.default_rng(2).choice(1000, 40, replace=False)).astype(np.uint32)
    image = build_image(tris, build_kdtree(tris, cfg, cache_dir=tmp_path), cfg, tri_id=ids)
    index = np.array([0, 5, -1, 39, 12])
    sid = image.scene_ids(index)
    assert sid.tolist() == [int(ids[0]), int(ids[5]), -1, int(ids[39]), int(ids[12])]
    assert image.tri_index(sid).tolist() == index.tolist()
    assert image.tri_index(ids).tolist() == list(range(40))
    missing = next(i for i in range(1000) if i not in set(ids.tolist()))
    with pytest.raises(KeyError):
        image.tri_index([missing])
