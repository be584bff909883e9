"""The encoder's memory of recent compressions: the bytes are those a fresh compression gives,
repeated compressions are served from it, it stays within its bound, and the format layer's
``compress`` keeps no memory of its own."""

from __future__ import annotations

import threading

from hypothesis import given, settings
from hypothesis import strategies as st

from encoder import compressions
from encoder.compressions import RecentCompressions
from spcodec import codecs
from spcodec.container import Codec


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=3000), st.sampled_from([Codec.NONE, Codec.ZLIB, Codec.ZSTD]),
       st.sampled_from([None, 1, 9]), st.sampled_from([None, 1, 7, 100]))
def test_remembered_bytes_are_a_fresh_compression(raw, codec, level, columns):
    if codec == Codec.ZSTD and not codecs.zstd_available():
        codec = Codec.ZLIB
    recent = RecentCompressions(1 << 20)
    first = recent(codec, raw, level, columns)
    again = recent(codec, bytearray(raw), level, columns)  # same content, another object
    expected = codecs.compress(codec, bytes(raw), level, columns)
    assert first == again == expected
    assert codecs.decompress(codec, first, len(raw)) == raw


def test_a_repeated_compression_is_served_and_the_memory_is_bounded(monkeypatch):
    calls = []
    real = codecs.compress
    monkeypatch.setattr(compressions, "compress", lambda *a: calls.append(a[1]) or real(*a))
    recent = RecentCompressions(max_bytes=4000)
    payloads = [bytes([k]) * 20_000 + bytes(range(256)) * k for k in range(40)]
    for raw in payloads:
        recent(Codec.ZLIB, raw, 9)
    recent(Codec.ZLIB, payloads[-1], 9)
    assert len(calls) == len(payloads)  # the last one came back from memory
    recent(Codec.ZLIB, payloads[-1], 6)  # another level is another compression
    assert len(calls) == len(payloads) + 1
    assert recent.size == sum(map(len, recent.entries.values())) <= recent.max_bytes
    recent(Codec.ZLIB, payloads[0], 9)  # dropped long ago: compressed again
    assert len(calls) == len(payloads) + 2


def test_threads_compressing_at_once_get_their_own_bytes():
    payloads = [bytes(range(k, 256)) * 300 for k in range(16)]
    recent = RecentCompressions(1 << 20)
    results: dict[int, bytes] = {}

    def work(k: int) -> None:
        for _ in range(5):
            results[k] = recent(Codec.ZLIB, payloads[k], 9, 100)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(codecs.decompress(Codec.ZLIB, results[k], len(p)) == p
               for k, p in enumerate(payloads))


def test_the_format_layer_keeps_no_memory():
    assert not any(isinstance(v, RecentCompressions) for v in vars(codecs).values())
    assert not hasattr(codecs, "_RECENT")


def test_the_encoders_writer_compresses_through_the_memory(monkeypatch):
    from encoder.stages import SceneWriter
    from spcodec.writer import WriteOptions

    seen = []
    monkeypatch.setattr(compressions.RECENT, "put", lambda key, stored: seen.append(key))
    SceneWriter(0, [], {"note": "x" * 500}, WriteOptions()).write(None)
    assert seen  # the metadata section went through the encoder's memory
