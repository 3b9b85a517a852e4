"""``photonmap.core.rows``: records written as packet rows come back bit for bit — floats,
integers whose bits are a NaN or a denormal as a float, flags, a whole ``SurfaceInteraction3f``
with its shape pointers — from the slots that were written, where the mask allowed, in the order
asked; the rows' widths are powers of two that add up to the record's 32-bit words; and the loop
kernel writes them with packet stores (a NumPy reference of the same slots as the oracle)."""

import drjit as dr
import mitsuba as mi
import numpy as np

from photonmap.core.rows import Rows

FIELDS = {"p": mi.Point3f, "colour": mi.Color3f, "depth": mi.UInt32, "flag": mi.Bool,
          "signed": mi.Int32, "t": mi.Float}  # fmt: skip


def record(n: int):
    i = np.arange(n, dtype=np.uint64)
    # all ones (a NaN as a float), 1 (a denormal), hashes
    bits = np.where(i % 3 == 0, 0xFFFFFFFF, np.where(i % 3 == 1, 1, i * 2654435761 % 2**32))
    i = i.astype(np.uint32)
    p = np.stack([i * 0.5, -i * 0.25, i + 0.125]).astype(np.float32)
    colour = np.stack([i * 2.0, i * 3.0, np.full(n, np.inf)]).astype(np.float32)
    values = {"p": p, "colour": colour, "depth": bits.astype(np.uint32), "flag": i % 2 == 1,
              "signed": (-7 * i.astype(np.int32)), "t": (i * 1e-3).astype(np.float32)}  # fmt: skip
    jit = (mi.Point3f(*p), mi.Color3f(*colour), mi.UInt32(values["depth"]), mi.Bool(values["flag"]),
           mi.Int32(values["signed"]), mi.Float(values["t"]))  # fmt: skip
    return values, jit


def test_the_rows_add_up_to_the_words_in_powers_of_two():
    rows = Rows(FIELDS)  # 3 + 3 + 1 + 1 + 1 + 1 = 10 words
    assert rows.widths == [8, 2] and len(rows.others) == 0
    assert Rows({"a": mi.Point3f, "b": mi.Point3f, "c": mi.Point3f, "d": mi.Point3f,
                 "e": mi.UInt32, "f": mi.Bool, "g": mi.UInt32, "h": mi.UInt32, "i": mi.UInt32}
                ).widths == [16, 1]  # fmt: skip


def test_what_was_written_comes_back_bit_for_bit_where_the_mask_allowed():
    n, slots = 37, 50
    values, jit = record(n)
    rows = Rows(FIELDS)
    storage = rows.empty(slots)
    slot = (np.arange(n) * 7 + 3) % slots  # a permutation into the slots
    active = np.arange(n) % 4 != 2
    rows.write(storage, jit, mi.UInt32(slot.astype(np.uint32)), mi.Bool(active))
    want = np.flatnonzero(active)[::-1]  # read back in another order
    out = rows.read(storage, mi.UInt32(slot[want].astype(np.uint32)))
    for (name, expected), got in zip(values.items(), out, strict=True):
        got = np.ascontiguousarray(np.array(got))
        expected = np.ascontiguousarray(expected[..., want])
        assert got.dtype == expected.dtype, name
        assert np.array_equal(got.view(np.uint8), expected.view(np.uint8)), name


def test_a_struct_with_pointers_comes_back():
    behind = mi.ScalarTransform4f().translate([0, 0, -3])
    scene = mi.load_dict({"type": "scene", "a": {"type": "sphere"},
                          "b": {"type": "rectangle", "to_world": behind}})  # fmt: skip
    n = 16
    x = np.linspace(-0.3, 0.3, n).astype(np.float32)
    ray = mi.Ray3f(mi.Point3f(mi.Float(x), 0, 5), mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(ray)
    rows = Rows({"si": mi.SurfaceInteraction3f, "k": mi.UInt32})
    assert [kind for _, kind in rows.others] == [mi.ShapePtr] * 2
    storage = rows.empty(n)
    rows.write(storage, (si, dr.arange(mi.UInt32, n)), dr.arange(mi.UInt32, n), True)
    index = mi.UInt32(np.arange(n)[::-1].astype(np.uint32))
    back, k = rows.read(storage, index)
    assert np.array_equal(np.array(k), np.arange(n)[::-1])
    for name in ("t", "p", "n", "uv", "wi", "prim_index"):
        expected = np.array(dr.gather(type(getattr(si, name)), getattr(si, name), index))
        assert np.array_equal(np.array(getattr(back, name)), expected), name
    normal = si.sh_frame.n
    assert np.array_equal(np.array(back.sh_frame.n), np.array(dr.gather(type(normal), normal, index)))
    same = back.shape == dr.gather(mi.ShapePtr, si.shape, index)
    assert dr.all(same) and dr.all(back.is_valid())


def test_no_slot_read_gives_empty_fields():
    rows = Rows(FIELDS)
    out = rows.read(rows.empty(4), dr.zeros(mi.UInt32, 0))
    assert [dr.width(v) for v in out] == [0] * len(FIELDS)


@dr.syntax
def _loop_write(rows, storage, jit, n: int):
    i = mi.UInt32(0)
    lane = dr.arange(mi.UInt32, n)
    while i < 2:
        rows.write(storage, jit, i * n + lane, (lane + i) % 2 == 0)
        i += 1


def test_a_symbolic_loop_writes_packet_rows():
    n = 20
    values, jit = record(n)
    rows = Rows(FIELDS)
    storage = rows.empty(2 * n)
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        _loop_write(rows, storage, jit, n)
        dr.eval(storage)
        ir = "".join(k["ir"].getvalue() for k in dr.kernel_history() if "ir" in k)
    if dr.backend_v(mi.Float) == dr.JitBackend.LLVM:
        assert "scatter_8xf32" in ir  # one packet store of 8 words, not 8 scatters
    slot = np.array([i * n + j for i in range(2) for j in range(n) if (i + j) % 2 == 0])
    out = rows.read(storage, mi.UInt32(slot.astype(np.uint32)))
    lanes = slot % n
    assert np.array_equal(np.array(out[0]), values["p"][:, lanes])
    assert np.array_equal(np.array(out[2]), values["depth"][lanes])


def test_the_rows_of_a_dataclass_are_its_fields():
    from photonmap.core.media import Segments
    from photonmap.core.volume_map import VolumePhotons

    rows = Rows.of(VolumePhotons)  # 3 + 3 + 3 + 1 + 1 words
    assert list(rows.fields) == ["position", "direction", "power", "depth", "caustic"]
    assert rows.fields["depth"] is mi.UInt32 and rows.widths == [8, 2, 1]
    assert [kind for _, kind in Rows.of(Segments).others] == [mi.MediumPtr]
