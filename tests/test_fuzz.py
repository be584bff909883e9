"""Mutation fuzzing of the decoder: every malformed input is a FormatError, quickly, in bounded memory.

Byte flips alone die at the CRC checks ([R-7], [R-8]), so the mutants here come from the
structure-aware mutators of ``tests/fuzzing/``, which edit payloads, stored bytes, header fields,
section lists and the gzip wrapper and then *repair the checksums*, so that the cluster table,
codebook, position, Draco, metadata and gzip parsers behind the CRCs are reached.
Hypothesis drives the mutators' choices (and shrinks a failure to a small mutation).

Each mutant goes through ``decode_layers``, ``decode(max_layer=k)``, ``inspect`` (and its JSON)
and the ``StreamDecoder`` fed in random chunks. The oracle (``check_input``): each either succeeds
with finite arrays of consistent length or raises ``FormatError`` with a code of the spec's list;
nothing else, no warning; the stream decoder accepts exactly what ``decode_layers`` accepts, with
the same layers. On top, every example has a time bound, and mutants that claim huge counts or
lengths have a memory bound.

``HYPOTHESIS_PROFILE=long python -m pytest tests/test_fuzz.py`` runs many more examples;
``python bench/fuzz_decoder.py`` runs the same mutators and oracle for as long as you like.
"""

from __future__ import annotations

import time
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import spcodec

import fuzzing as fz

TIME_BOUND_S = 3.0
"""Seconds one mutant may take through every entry point (inputs are a few KB; a correct
decoder answers in milliseconds, so only a hang or a runaway loop gets near this)."""

SEEDS = fz.build_seeds()
EXAMPLES = settings().max_examples * 3
"""Three times the profile's example count: mutants are cheap (a few ms each)."""


class DrawChooser:
    """The mutators' decisions drawn from hypothesis, so a failure shrinks to a small mutation."""

    def __init__(self, data: st.DataObject) -> None:
        self.data = data

    def integer(self, lo: int, hi: int) -> int:
        return self.data.draw(st.integers(lo, hi))

    def blob(self, size: int) -> bytes:
        return self.data.draw(st.binary(min_size=size, max_size=size))


def check_mutant(data: st.DataObject, kind: str) -> tuple[bytes, dict[str, str]]:
    """Build one mutant of ``kind`` and hold every entry point to the contract and time bound."""
    ch = DrawChooser(data)
    _, mutant = fz.make_mutant(SEEDS, ch, kind)
    start = time.perf_counter()
    outcome = fz.check_input(mutant, ch)
    elapsed = time.perf_counter() - start
    assert elapsed < TIME_BOUND_S, f"{elapsed:.2f} s for a {len(mutant)}-byte {kind} mutant"
    return mutant, outcome.results


# ------------------------------------------------------------------------------ the corpus
def test_the_seed_corpus_is_valid_and_varied():
    """The mutants start from valid files covering every SH degree, codec, mode and gzip."""
    for seed in SEEDS:
        result = spcodec.decode_layers(seed.data)
        assert result.complete and result.cloud.is_finite()
    assert {s.sh_degree for s in SEEDS} == {0, 1, 2, 3}
    assert {int(sec.codec) for s in SEEDS for sec in s.sections} == {0, 1, 2}
    assert any(s.gzip for s in SEEDS) and any(not s.gzip for s in SEEDS)


def test_the_oracle_flags_contract_breaks(monkeypatch):
    """The harness can fail: a stray exception type and a non-finite output are findings."""
    data = SEEDS[0].data
    ch = fz.RandomChooser(__import__("random").Random(0))
    assert fz.check_input(data, ch).results["decode_layers"] == "ok"
    real = spcodec.decode_layers

    def leaky(*args, **kwargs):
        raise KeyError("not a FormatError")

    monkeypatch.setattr(spcodec, "decode_layers", leaky)
    with pytest.raises(fz.Finding, match="KeyError"):
        fz.check_input(data, ch)

    def poisoned(*args, **kwargs):
        result = real(*args, **kwargs)
        result.cloud.scales[0, 0] = np.inf
        return result

    monkeypatch.setattr(spcodec, "decode_layers", poisoned)
    with pytest.raises(fz.Finding, match="non-finite"):
        fz.check_input(data, ch)


# --------------------------------------------------------------------------------- mutants
@settings(max_examples=EXAMPLES)
@given(data=st.data())
def test_payload_mutants_with_repaired_crcs(data):
    """Cluster records, codebooks, positions, Draco headers, coefficients, indices, metadata
    ([R-40]..[R-58], [R-70]) edited field by field, recompressed, CRCs derived."""
    check_mutant(data, "payload")


@settings(max_examples=EXAMPLES)
@given(data=st.data())
def test_stored_byte_mutants_with_repaired_crcs(data):
    """Compressed bytes and Draco blobs damaged behind a valid CRC ([R-22]..[R-25], [R-47])."""
    check_mutant(data, "stored")


@settings(max_examples=EXAMPLES)
@given(data=st.data())
def test_header_field_mutants_with_repaired_header_crc(data):
    """Any field of the fixed header, layer table or TOC: lengths, counts, offsets, codecs, CRCs
    ([R-4]..[R-15])."""
    check_mutant(data, "header")


@settings(max_examples=EXAMPLES)
@given(data=st.data(), kind=st.sampled_from(["sections", "splice"]))
def test_section_list_mutants_and_splices(data, kind):
    """Sections dropped, duplicated, swapped, retyped, moved, spliced from other files, given
    other codecs or flags; layers added or dropped ([R-9], [R-10], [R-13], [R-14], [R-20])."""
    check_mutant(data, kind)


@settings(max_examples=EXAMPLES)
@given(data=st.data(), kind=st.sampled_from(["truncate", "append", "flip"]))
def test_truncated_extended_and_flipped_files(data, kind):
    """Cuts at and around every layer end, trailing bytes, unrepaired flips ([R-4], [R-12])."""
    check_mutant(data, kind)


@settings(max_examples=EXAMPLES)
@given(data=st.data())
def test_gzip_wrapped_mutants(data):
    """Mutated inner files re-wrapped, and the wrapper itself damaged: header fields with FHCRC
    repaired, the SP offsets, deflate bytes, trailer, extra members ([R-80]..[R-84])."""
    check_mutant(data, "gzip")


# ------------------------------------------------------------------------- memory bounds
CLAIM_MEMORY_FACTOR = 64
CLAIM_MEMORY_SLACK = 8 * 2**20


@settings(max_examples=EXAMPLES)
@given(data=st.data())
def test_huge_claims_do_not_allocate_what_they_claim(data):
    """[R-60]..[R-62]: a file claiming millions of Gaussians, a huge raw length, cluster count
    or codebook is refused before anything is sized from the claim: the traced peak stays
    within a small multiple of the input's size."""
    ch = DrawChooser(data)
    _, mutant = fz.make_mutant(SEEDS, ch, "claim")
    tracemalloc.start()
    try:
        fz.check_input(mutant, ch)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    bound = CLAIM_MEMORY_FACTOR * len(mutant) + CLAIM_MEMORY_SLACK
    assert peak < bound, f"traced peak {peak / 2**20:.1f} MiB for a {len(mutant)}-byte file"


# ------------------------------------------------------------------------------- streaming
@settings(max_examples=EXAMPLES)
@given(data=st.data(), kind=st.sampled_from(["payload", "header", "truncate", "gzip"]))
def test_stream_decoder_agrees_with_decode_on_mutants(data, kind):
    """The StreamDecoder, fed the mutant in random chunk sizes, accepts exactly what
    decode_layers accepts and returns the same layers (checked inside check_input); here also
    byte by byte, the smallest chunks, on the mutant's first layer."""
    mutant, results = check_mutant(data, kind)
    dec = spcodec.StreamDecoder(max_layer=0)
    try:
        got = []
        for i in range(len(mutant)):
            got += dec.feed(mutant[i:i + 1])
            if dec.complete:
                break
        dec.close()
    except spcodec.FormatError:
        return
    if results["decode_layers"] == "ok":
        assert [layer.index for layer in got] == [0]
        assert got[0].cloud.equals(spcodec.decode(mutant, max_layer=0))
