"""Section payloads: pack -> parse is exact, and each structural requirement is enforced."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from spcodec.attributes import PatchAttribute, SketchAttribute
from spcodec.container import CLUSTER_DTYPE, SH_REST_ABSENT, PositionMode
from spcodec.errors import FormatError
from spcodec.limits import Limits
from spcodec.sections import (
    Codebook,
    PatchPositions,
    pack_codebooks,
    pack_indices,
    pack_positions,
    pack_sketch,
    parse_codebooks,
    parse_indices,
    parse_positions,
    parse_sketch,
    read_coefficients,
)
from spcodec.synthetic import positions_in_mode, random_cluster, random_codebooks, random_sketch

LIMITS = Limits()


def _code(fn) -> str:
    with pytest.raises(FormatError) as err:
        fn()
    return err.value.code


# ----------------------------------------------------------------------------- sketch
@given(st.integers(0, 3), st.integers(0, 6), st.integers(0, 2**31 - 1))
def test_sketch_tables_round_trip(sh_degree, clusters, seed):
    rng = np.random.default_rng(seed)
    cls = random_sketch(rng, sh_degree, clusters)
    table, draco, coeffs = pack_sketch(cls, sh_degree)
    layout = parse_sketch(table, len(draco), len(coeffs), sum(c.point_count for c in cls),
                          sh_degree, LIMITS)
    assert len(layout.records) == clusters
    assert [draco[r.start:r.stop] for r in layout.runs] == [c.draco for c in cls if c.draco]
    for run in layout.runs:  # a run is its first cluster and those continuing it
        assert cls[run.first_cluster].draco and not any(
            c.draco for c in cls[run.first_cluster + 1:run.end_cluster])
        assert run.points == sum(c.point_count for c in cls[run.first_cluster:run.end_cluster])
    for i, cl in enumerate(cls):
        for attr in SketchAttribute:
            got = read_coefficients(coeffs, layout, i, attr, sh_degree)
            if attr in cl.models:
                np.testing.assert_array_equal(got, cl.models[attr])
            else:
                assert got is None and layout.records["degrees"][i][attr] == SH_REST_ABSENT


def _one_cluster_tables(**record_changes):
    rng = np.random.default_rng(1)
    cl = random_cluster(rng, 1, points=10, with_sh_rest=True)
    table, draco, coeffs = pack_sketch([cl], 1)
    rec = np.frombuffer(table[4:], dtype=CLUSTER_DTYPE).copy()
    for key, value in record_changes.items():
        rec[0][key] = value
    return table[:4] + rec.tobytes(), len(draco), len(coeffs), cl.point_count


@pytest.mark.parametrize("change, code", [
    (dict(point_count=0), "bad-value"),
    (dict(half_extent=[1.0, 0.0, 1.0]), "bad-value"),
    (dict(center=[np.nan, 0, 0]), "bad-value"),
    (dict(degrees=[11, 1, 1, 1, 1]), "bad-value"),
    (dict(degrees=[1, 1, 1, 1, 12]), "bad-value"),
    (dict(reserved=b"\x01\0\0"), "reserved-nonzero"),
    (dict(draco_length=1), "bad-section"),
    (dict(draco_length=0), "bad-value"),          # the first cluster must start a blob
])
def test_cluster_record_checks(change, code):
    table, nd, nc, count = _one_cluster_tables(**change)
    assert _code(lambda: parse_sketch(table, nd, nc, count, 1, LIMITS)) == code


def test_cluster_table_consistency_checks():
    table, nd, nc, count = _one_cluster_tables()
    assert _code(lambda: parse_sketch(table, nd, nc, count + 1, 1, LIMITS)) == "bad-section"
    assert _code(lambda: parse_sketch(table, nd, nc + 2, count, 1, LIMITS)) == "bad-section"
    assert _code(lambda: parse_sketch(table[:-1], nd, nc, count, 1, LIMITS)) == "bad-section"
    assert _code(lambda: parse_sketch(table, nd, nc, count, 0, LIMITS)) == "bad-value"
    assert _code(lambda: parse_sketch(table, nd, nc, count, 1, Limits(max_clusters=0))) == \
        "limit-exceeded"
    assert _code(lambda: parse_sketch(b"\0\0", 0, 0, 0, 1, LIMITS)) == "bad-section"


def test_non_finite_coefficients_are_refused():
    rng = np.random.default_rng(2)
    cl = random_cluster(rng, 0, points=5)
    cl.models[SketchAttribute.OPACITY] = np.full_like(cl.models[SketchAttribute.OPACITY], np.inf)
    table, draco, coeffs = pack_sketch([cl], 0)
    layout = parse_sketch(table, len(draco), len(coeffs), cl.point_count, 0, LIMITS)
    assert _code(lambda: read_coefficients(coeffs, layout, 0, SketchAttribute.OPACITY, 0)) == \
        "bad-value"


# ------------------------------------------------------------------------------ patch
@given(st.integers(0, 3), st.integers(0, 2**31 - 1))
def test_codebooks_round_trip(sh_degree, seed):
    books = random_codebooks(np.random.default_rng(seed), sh_degree)
    parsed = parse_codebooks(pack_codebooks(books), sh_degree)
    assert [b.attribute for b in parsed] == PatchAttribute.for_sh_degree(sh_degree)
    for a, b in zip(books, parsed):
        np.testing.assert_array_equal(a.entries, b.entries)


def test_codebook_checks():
    books = random_codebooks(np.random.default_rng(0), 1)
    raw = pack_codebooks(books)
    assert _code(lambda: parse_codebooks(raw, 2)) == "bad-section"          # missing SH band 2
    assert _code(lambda: parse_codebooks(raw + b"\0", 1)) == "bad-section"  # trailing byte
    assert _code(lambda: parse_codebooks(raw[:-1], 1)) == "bad-section"
    bad_dim = [Codebook(b.attribute, np.zeros((4, 2), np.float16))
               if b.attribute == PatchAttribute.SCALE else b for b in books]
    assert _code(lambda: parse_codebooks(pack_codebooks(bad_dim), 1)) == "bad-value"
    too_many = [Codebook(b.attribute, np.zeros((257, 1), np.float16))
                if b.attribute == PatchAttribute.OPACITY else b for b in books]
    assert _code(lambda: parse_codebooks(pack_codebooks(too_many), 1)) == "bad-value"
    nan = [Codebook(b.attribute, np.full((3, b.entry_dim), np.nan, np.float16))
           if b.attribute == PatchAttribute.COLOR_DC else b for b in books]
    assert _code(lambda: parse_codebooks(pack_codebooks(nan), 1)) == "bad-value"


@given(st.integers(0, 3), st.integers(0, 300), st.integers(0, 2**31 - 1))
def test_indices_round_trip(sh_degree, n, seed):
    rng = np.random.default_rng(seed)
    books = random_codebooks(rng, sh_degree)
    idx = {b.attribute: rng.integers(0, b.entries.shape[0], (n, b.groups)).astype(np.uint8)
           for b in books}
    parsed = parse_indices(pack_indices(idx, books), n, books)
    for b in books:
        np.testing.assert_array_equal(parsed[b.attribute].T, idx[b.attribute])


def test_index_checks():
    books = [Codebook(a, np.zeros((3, a.width), np.float16)) for a in PatchAttribute.for_sh_degree(0)]
    raw = bytes([0, 1, 2, 0]) * 2
    assert len(parse_indices(raw, 2, books)) == 4
    assert _code(lambda: parse_indices(raw[:-1], 2, books)) == "bad-section"
    assert _code(lambda: parse_indices(bytes([0, 3, 0, 0]) * 2, 2, books)) == "bad-value"


@pytest.mark.parametrize("mode", list(PositionMode))
@given(n=st.integers(0, 400), seed=st.integers(0, 2**31 - 1))
def test_positions_round_trip(mode, n, seed):
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-100, 100, (n, 3))
    pos = positions_in_mode(xyz, mode, 200.0 / 65535)
    back = parse_positions(pack_positions(pos), n)
    assert back.mode == mode
    np.testing.assert_array_equal(back.data, pos.data)          # lossless storage (of the codes)
    np.testing.assert_array_equal(back.decode(), pos.decode())
    if mode == PositionMode.QUANT16 and n:                       # error bound of the mode
        assert np.abs(back.decode() - xyz).max() <= 200.0 / 65535 / 2 + 1e-4


def test_quant16_is_delta_coded_so_sorted_runs_are_small():
    q = np.arange(1000, dtype=np.uint16)[:, None].repeat(3, 1)
    pos = PatchPositions(PositionMode.QUANT16, q, np.zeros(3, np.float32), np.ones(3, np.float32))
    stored = np.frombuffer(pack_positions(pos)[28:], dtype="<u2")
    assert set(stored[1:1000].tolist()) == {2}                    # zigzag(+1) == 2


def test_position_checks():
    pos = PatchPositions.float32(np.zeros((3, 3)))
    raw = pack_positions(pos)
    assert _code(lambda: parse_positions(raw, 4)) == "bad-section"
    assert _code(lambda: parse_positions(bytes([7, 0, 0, 0]), 0)) == "bad-value"
    assert _code(lambda: parse_positions(bytes([2, 1, 0, 0]), 0)) == "reserved-nonzero"
    nan = PatchPositions.float32(np.full((2, 3), np.nan))
    assert _code(lambda: parse_positions(pack_positions(nan), 2)) == "bad-value"
    huge = PatchPositions(PositionMode.QUANT16, np.zeros((1, 3), np.uint16),
                          np.zeros(3, np.float32), np.full(3, 1e38, np.float32))
    assert _code(lambda: parse_positions(pack_positions(huge), 1)) == "bad-value"


def test_draco_positions_must_hold_the_layer_count():
    import DracoPy
    blob = DracoPy.encode(np.random.default_rng(0).normal(size=(10, 3)).astype(np.float32),
                          preserve_order=True)
    raw = pack_positions(PatchPositions.draco(blob, np.zeros((10, 3))))
    assert len(parse_positions(raw, 10)) == 10
    assert _code(lambda: parse_positions(raw, 11)) == "draco-failed"
    assert _code(lambda: parse_positions(raw[:-3], 10)) == "draco-failed"


def test_draco_header_is_checked_before_draco_allocates(monkeypatch):
    """[R-47], [R-58], [R-60]: a blob whose header could make Draco allocate is refused first.

    Found by fuzzing: a 300-byte blob whose point count field said ~2^31 made DracoPy allocate
    gigabytes (the process was killed by the kernel); relabelled bitstream versions did the same.
    """
    import struct

    import DracoPy
    points = np.random.default_rng(1).normal(size=(10, 3)).astype(np.float32)
    blob = DracoPy.encode(points, preserve_order=True)
    assert len(parse_positions(pack_positions(PatchPositions.draco(blob, points)), 10)) == 10

    def edited(offset: int, fmt: str, value: int) -> bytes:
        out = bytearray(blob)
        struct.pack_into(fmt, out, offset, value)
        return bytes(out)

    hostile = [edited(11, "<i", 0x7FFFFFFF), edited(11, "<i", -1), edited(11, "<i", 11),
               edited(6, "B", 0), edited(5, "B", 1), edited(7, "B", 1), edited(8, "B", 9),
               edited(9, "<H", 0x8000), blob[:14], b"DRICO" + blob[5:]]

    class Reached(BaseException):
        """Not an Exception, so decode_points' own handler cannot swallow it."""

    def no_draco(*args, **kwargs):
        raise Reached("DracoPy.decode was reached")

    monkeypatch.setattr(DracoPy, "decode", no_draco)
    for bad in hostile:
        raw = pack_positions(PatchPositions.draco(bad, points))
        assert _code(lambda r=raw: parse_positions(r, 10)) == "draco-failed"


def test_draco_blobs_with_extra_attributes_are_refused():
    import DracoPy

    from spcodec.draco_io import decode_points
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(6, 3)).astype(np.float32)
    coloured = DracoPy.encode(pts, colors=(rng.random((6, 3)) * 255).astype(np.uint8))
    with pytest.raises(FormatError, match="carries 2 attributes") as err:
        decode_points(coloured, 6, "test blob")
    assert err.value.code == "draco-failed"


@pytest.mark.parametrize("byte, value, kdtree", [(17, 4, False), (17, 1, True), (18, 1, True)])
def test_draco_attribute_must_be_float32_positions(byte, value, kdtree):
    """[R-49] (correction): the one attribute must be POSITION with 3 float32 components. Draco
    decodes a blob whose attribute says GENERIC or NORMAL without complaint, and a kd-tree blob
    whose positions say int8 to points, so each is checked, not assumed."""
    import DracoPy

    from spcodec.draco_io import decode_points
    pts = np.random.default_rng(0).normal(size=(20, 3)).astype(np.float32)
    blob = bytearray(DracoPy.encode(pts, quantization_bits=14, preserve_order=not kdtree))
    assert blob[8] == int(kdtree) and tuple(blob[17:20]) == (0, 9, 3)  # POSITION, float32, 3
    decode_points(bytes(blob), 20, "good blob")
    blob[byte] = value
    assert DracoPy.decode(bytes(blob)).attributes[0]["attribute_type"] == blob[17]  # it decodes
    with pytest.raises(FormatError, match="expected POSITION with 3 float32 components") as err:
        decode_points(bytes(blob), 20, "forged blob")
    assert err.value.code == "draco-failed"
