"""The memory of recent compressions: the bytes are those a fresh compression gives, repeated
compressions are served from it, and it stays within its bound."""

from __future__ import annotations

import threading

from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec import codecs
from spcodec.container import Codec


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=3000), st.sampled_from([Codec.NONE, Codec.ZLIB, Codec.ZSTD]),
       st.sampled_from([None, 1, 9]), st.sampled_from([None, 1, 7, 100]))
def test_remembered_bytes_are_a_fresh_compression(raw, codec, level, columns):
    if codec == Codec.ZSTD and not codecs.zstd_available():
        codec = Codec.ZLIB
    first = codecs.compress(codec, raw, level, columns)
    again = codecs.compress(codec, bytearray(raw), level, columns)  # same content, another object
    expected = bytes(raw) if codec == Codec.NONE else codecs._compress(codec, raw, level, columns)
    assert first == again == expected
    assert codecs.decompress(codec, first, len(raw)) == raw


def test_a_repeated_compression_is_served_and_the_memory_is_bounded(monkeypatch):
    calls = []
    real = codecs._compress
    monkeypatch.setattr(codecs, "_compress", lambda *a: calls.append(a[1]) or real(*a))
    monkeypatch.setattr(codecs, "_RECENT", codecs._Recent(max_bytes=4000))
    payloads = [bytes([k]) * 20_000 + bytes(range(256)) * k for k in range(40)]
    for raw in payloads:
        codecs.compress(Codec.ZLIB, raw, 9)
    codecs.compress(Codec.ZLIB, payloads[-1], 9)
    assert len(calls) == len(payloads)  # the last one came back from memory
    codecs.compress(Codec.ZLIB, payloads[-1], 6)  # another level is another compression
    assert len(calls) == len(payloads) + 1
    recent = codecs._RECENT
    assert recent.size == sum(map(len, recent.entries.values())) <= recent.max_bytes
    codecs.compress(Codec.ZLIB, payloads[0], 9)  # dropped long ago: compressed again
    assert len(calls) == len(payloads) + 2


def test_threads_compressing_at_once_get_their_own_bytes():
    payloads = [bytes(range(k, 256)) * 300 for k in range(16)]
    results: dict[int, bytes] = {}

    def work(k: int) -> None:
        for _ in range(5):
            results[k] = codecs.compress(Codec.ZLIB, payloads[k], 9, 100)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(codecs.decompress(Codec.ZLIB, results[k], len(p)) == p
               for k, p in enumerate(payloads))
