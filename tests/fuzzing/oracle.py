"""The oracle: every decoding entry point on one input either succeeds with finite arrays of
consistent length or raises ``FormatError`` with a code of the spec's list; nothing else, no
warning; the stream decoder accepts exactly what ``decode_layers`` accepts, with the same layers."""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from typing import Callable, TypeVar

import numpy as np

import spcodec
from spcodec.errors import ERROR_CODES, FormatError

from .choosers import Chooser

T = TypeVar("T")


class Finding(AssertionError):
    """The decoder broke its contract on an input: wrong exception type, bad output, too slow."""

    def __init__(self, target: str, problem: str, cause: BaseException | None = None) -> None:
        super().__init__(f"{target}: {problem}")
        self.target, self.problem, self.cause = target, problem, cause


@dataclass
class Outcome:
    """What the decoding entry points made of one input: 'ok' or an error code, per target."""

    results: dict[str, str]


def _code(exc: FormatError, target: str) -> str:
    if exc.code not in ERROR_CODES:
        raise Finding(target, f"FormatError with unknown code {exc.code!r}", exc)
    return exc.code


def _check_cloud(cloud: spcodec.GaussianCloud, expected: int, target: str) -> None:
    """Output contract: every array has the cloud's length and only finite values ([R-34])."""
    n = len(cloud)
    if n != expected:
        raise Finding(target, f"decoded {n} Gaussians, the decoded layers declare {expected}")
    for name, array in cloud.arrays().items():
        if array.shape[0] != n:
            raise Finding(target, f"{name} has {array.shape[0]} rows for {n} Gaussians")
        if not np.isfinite(array).all():
            raise Finding(target, f"{name} holds a non-finite value")


def _run(target: str, fn: Callable[[], T]) -> T | FormatError:
    """Call ``fn``; a FormatError is an answer, anything else (warnings included) a finding."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            return fn()
    except FormatError as exc:
        _code(exc, target)
        return exc
    except Finding:
        raise
    except BaseException as exc:  # noqa: B036 - the point is to catch everything
        if isinstance(exc, (KeyboardInterrupt, TimeoutError)):
            raise
        raise Finding(target, f"{type(exc).__name__}: {exc}", exc) from exc


def _stream(data: bytes, chunks: list[int]) -> list:
    dec = spcodec.StreamDecoder()
    got, pos, i = [], 0, 0
    while pos < len(data):
        step = chunks[i % len(chunks)]
        got += dec.feed(data[pos:pos + step])
        pos, i = pos + step, i + 1
    dec.close()
    return got


def check_input(data: bytes, ch: Chooser) -> Outcome:
    """Run every decoding entry point on ``data`` and enforce the contract; raise Finding."""
    results: dict[str, str] = {}
    full = _run("decode_layers", lambda: spcodec.decode_layers(data))
    if isinstance(full, FormatError):
        results["decode_layers"] = full.code
    else:
        _check_cloud(full.cloud, sum(layer.cloud.means.shape[0] for layer in full.layers),
                     "decode_layers")
        declared = sum(full.header.layers[k].gaussian_count for k in range(len(full.layers)))
        if len(full.cloud) != declared:
            raise Finding("decode_layers", f"{len(full.cloud)} Gaussians, header says {declared}")
        results["decode_layers"] = "ok"
        k = ch.integer(0, len(full.layers) - 1)
        part = _run("decode(max_layer)", lambda: spcodec.decode(data, max_layer=k))
        if isinstance(part, FormatError) or not part.equals(
                spcodec.GaussianCloud.concat([x.cloud for x in full.layers[:k + 1]],
                                             full.header.sh_degree)):
            raise Finding("decode(max_layer)", f"max_layer={k} disagrees with decode_layers")
    info = _run("inspect", lambda: json.dumps(spcodec.inspect(data).to_json()))
    results["inspect"] = info.code if isinstance(info, FormatError) else "ok"
    chunks = [ch.integer(1, 4096) for _ in range(ch.integer(1, 4))]
    layers = _run("StreamDecoder", lambda: _stream(data, chunks))
    results["stream"] = layers.code if isinstance(layers, FormatError) else "ok"
    _compare_stream(full, layers)
    return Outcome(results)


def _compare_stream(full, layers) -> None:
    """The stream decoder must accept exactly what decode_layers accepts, with the same layers.

    When both reject, the codes may differ: the stream decodes each layer as soon as its bytes
    are in, so it can report a fault of an early layer before it sees a later truncation,
    trailing bytes or a broken gzip trailer that decode_layers checks first.
    """
    if isinstance(full, FormatError) != isinstance(layers, FormatError):
        got = layers.code if isinstance(layers, FormatError) else "ok"
        want = full.code if isinstance(full, FormatError) else "ok"
        raise Finding("StreamDecoder", f"stream says {got}, decode_layers says {want}")
    if isinstance(full, FormatError):
        return
    if [x.index for x in layers] != [x.index for x in full.layers] or not all(
            a.cloud.equals(b.cloud) for a, b in zip(layers, full.layers)):
        raise Finding("StreamDecoder", "stream layers differ from decode_layers")
