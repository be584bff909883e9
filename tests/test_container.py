"""The construct definitions and the numpy dtypes derived from them describe the same bytes."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from spcodec.container import (
    CLUSTER_DTYPE,
    FIXED_HEADER_SIZE,
    LAYER_DTYPE,
    MAGIC,
    SECTION_DTYPE,
    ClusterRecord,
    FixedHeader,
    LayerEntry,
    SectionEntry,
    header_size,
)


def test_sizes_match_the_spec_tables():
    assert FIXED_HEADER_SIZE == 48
    assert LayerEntry.sizeof() == LAYER_DTYPE.itemsize == 16
    assert SectionEntry.sizeof() == SECTION_DTYPE.itemsize == 40
    assert ClusterRecord.sizeof() == CLUSTER_DTYPE.itemsize == 40
    assert header_size(3, 10) == 48 + 3 * 16 + 10 * 40 + 4
    assert len(MAGIC) == 8 and MAGIC[0] == 0x89


@given(st.integers(0, 2**16 - 1), st.integers(0, 255), st.integers(0, 255),
       st.integers(0, 2**16 - 1), st.integers(0, 2**64 - 1), st.integers(0, 2**64 - 1),
       st.integers(0, 2**64 - 1), st.integers(0, 2**32 - 1))
def test_section_entry_dtype_reads_what_construct_builds(type_, codec, flags, layer, offset,
                                                         stored, raw, crc):
    fields = dict(type=type_, codec=codec, flags=flags, layer=layer, reserved=0, offset=offset,
                  stored_length=stored, raw_length=raw, crc32=crc, reserved2=0)
    blob = SectionEntry.build(fields)
    row = np.frombuffer(blob, dtype=SECTION_DTYPE)[0]
    for name, value in fields.items():
        assert int(row[name]) == value
    parsed = SectionEntry.parse(blob)
    assert all(parsed[k] == v for k, v in fields.items())


@given(st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1),
       st.lists(st.floats(width=32, allow_nan=False), min_size=6, max_size=6),
       st.lists(st.integers(0, 255), min_size=5, max_size=5))
def test_cluster_record_dtype_reads_what_construct_builds(points, draco, floats, degrees):
    blob = ClusterRecord.build(dict(point_count=points, draco_length=draco, center=floats[:3],
                                    half_extent=floats[3:], degrees=degrees, reserved=b"\0\0\0"))
    row = np.frombuffer(blob, dtype=CLUSTER_DTYPE)[0]
    assert int(row["point_count"]) == points and int(row["draco_length"]) == draco
    np.testing.assert_array_equal(row["center"], np.float32(floats[:3]))
    np.testing.assert_array_equal(row["half_extent"], np.float32(floats[3:]))
    assert list(row["degrees"]) == degrees


def test_fixed_header_round_trips():
    fields = dict(magic=MAGIC, version_major=1, version_minor=3, flags=0, header_size=100,
                  layer_count=2, section_count=6, sh_degree=3, reserved=b"\0" * 7,
                  gaussian_count=12345, file_size=99999)
    blob = FixedHeader.build(fields)
    assert len(blob) == 48
    parsed = FixedHeader.parse(blob)
    assert all(parsed[k] == v for k, v in fields.items())
    assert blob[8:10] == b"\x01\x00"  # little-endian ([R-2])
