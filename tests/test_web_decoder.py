"""Cross-check of the JavaScript decoder (web/) against the reference decoder.

Files written by the Python writer in every mode (each codec, gzip wrapper on and off, SH degree 0
to 3, every patch position mode, Draco runs, an empty sketch, empty patch layers, sketch-only,
many layers, metadata) are decoded by ``node web/bin/spc-decode.mjs`` whole, with ``--max-layer``
and as layer prefixes; its PLY must equal the reference decoder's within the tolerances of the
spec's section 15 ([R-96]). Corrupt files (the structure-aware mutants of tests/fuzzing/,
which repair checksums so the damage reaches the parsers) must be rejected by both decoders with
the same error code, and accepted by both with the same number of Gaussians.

Skipped, with the reason, where node or web/node_modules is missing (``cd web && npm ci``).
"""

from __future__ import annotations

import hashlib
import json
import random
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
import zstandard

import spcodec
from spcodec.attributes import SketchAttribute
from spcodec.codecs import read_gzip_layer_ends
from spcodec.container import Codec, PositionMode, SectionType
from spcodec.decoder.api import _LayerDecoder, _unwrap
from spcodec.decoder.header import read_header
from spcodec.limits import DEFAULT_LIMITS
from spcodec.ply import read_ply
from spcodec.polynomial import features, normalize_positions
from spcodec.sections import read_coefficients
from spcodec.synthetic import random_codebooks, random_patch_layer, random_sketch
from spcodec.writer import EncodedScene, WriteOptions, build_bitstream, layer_end_offsets

import fuzzing
from conftest import REPO

WEB = REPO / "web"
CLI = WEB / "bin" / "spc-decode.mjs"
BATCH = WEB / "test" / "decode-batch.mjs"


def _node_missing() -> str | None:
    if shutil.which("node") is None:
        return "node is not installed"
    if not (WEB / "node_modules" / "draco3d").is_dir():
        return "web/node_modules is missing (run `npm ci` in web/)"
    return None


pytestmark = pytest.mark.skipif(_node_missing() is not None, reason=_node_missing() or "")

Q, F16, F32, DRACO = (PositionMode.QUANT16, PositionMode.FLOAT16, PositionMode.FLOAT32,
                      PositionMode.DRACO)
CASES = [
    # name, scene seed, SH degree, codec, gzip, clusters, patch modes, patch sizes, metadata
    ("sh0-none", 11, 0, Codec.NONE, False, 4, [Q, F16], [60, 30], None),
    ("sh1-zlib-gzip", 12, 1, Codec.ZLIB, True, 5, [F32, DRACO, Q], [50, 40, 20], {"a": 1}),
    ("sh2-zstd", 13, 2, Codec.ZSTD, False, 3, [DRACO, F16], [45, 25], None),
    ("sh3-none-gzip", 14, 3, Codec.NONE, True, 4, [F16, Q, F32, DRACO], [40, 30, 20, 10],
     {"m": [1, 2]}),
    ("sh0-zlib-empty-draco-layer", 15, 0, Codec.ZLIB, False, 6, [DRACO, DRACO], [70, 0], None),
    ("sh1-zstd-gzip", 16, 1, Codec.ZSTD, True, 2, [Q], [80], None),
    ("sh2-zlib-empty-sketch", 17, 2, Codec.ZLIB, False, 0, [F32, Q], [50, 0], None),
    ("sh3-zstd-sketch-only", 18, 3, Codec.ZSTD, False, 7, [], [], {"only": "sketch"}),
    ("sh3-zlib-six-layers", 19, 3, Codec.ZLIB, False, 5, [Q] * 6, [30, 25, 20, 15, 10, 5], None),
    ("sh2-none-gzip-empty-patch", 20, 2, Codec.NONE, True, 3, [F16, F16], [0, 40], None),
]


def _scene(seed, sh, clusters, modes, sizes, metadata) -> EncodedScene:
    rng = np.random.default_rng(seed)
    sketch = random_sketch(rng, sh, clusters)
    books = random_codebooks(rng, sh) if modes else []
    layers = [random_patch_layer(rng, books, n, mode) for mode, n in zip(modes, sizes)]
    return EncodedScene(sh, sketch, books, layers, metadata)


def _run_cli(inp: Path, out: Path, max_layer: int | None = None) -> subprocess.CompletedProcess:
    cmd = ["node", str(CLI), str(inp), str(out)]
    if max_layer is not None:
        cmd += ["--max-layer", str(max_layer)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


# ------------------------------------------------------------------------- tolerances ([R-96])
def _sketch_bounds(data: bytes, sh: int) -> dict[str, np.ndarray]:
    """Per sketch Gaussian, how far each PLY property may be from the reference's ([R-96]).

    The coded value of a model output may differ by 1e-6 (1 + S), S the sum of the absolute
    values of its terms; scale, colour and SH rest are the coded values, rotations are normalized
    and opacities go through a logit, whose slopes carry the bound over. A binary32 rounding of
    the result may add one ulp, which the comparison adds.
    """
    inner, _ = _unwrap(data, DEFAULT_LIMITS)
    header = read_header(inner, DEFAULT_LIMITS)
    dec = _LayerDecoder(header, DEFAULT_LIMITS)
    plan = dec.prepare(dec.load(inner, 0), 0)
    points = np.concatenate(plan.points) if plan.points else np.zeros((0, 3), np.float32)
    counts = plan.layout.records["point_count"].astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)])
    n, k = len(points), 3 * ((sh + 1) ** 2 - 1)
    bound = {"scale": np.zeros((n, 3)), "rot": np.zeros((n, 4)), "opacity": np.zeros(n),
             "dc": np.zeros((n, 3)), "rest": np.zeros((n, k))}
    for c in range(len(counts)):
        rows = slice(starts[c], starts[c + 1])
        rec = plan.layout.records[c]
        x = normalize_positions(points[rows], rec["center"], rec["half_extent"])
        terms, values = {}, {}
        for attr in SketchAttribute:
            coeffs = read_coefficients(plan.coefficients, plan.layout, c, attr, sh)
            if coeffs is None:
                continue
            phi = features(x, int(rec["degrees"][attr]))
            c64 = coeffs.astype(np.float64)
            terms[attr] = 1e-6 * (1.0 + np.abs(phi) @ np.abs(c64))
            values[attr] = phi @ c64
        bound["scale"][rows] = terms[SketchAttribute.SCALE]
        bound["dc"][rows] = terms[SketchAttribute.COLOR_DC]
        if SketchAttribute.SH_REST in terms:
            bound["rest"][rows] = terms[SketchAttribute.SH_REST]
        tol = np.linalg.norm(terms[SketchAttribute.ROTATION], axis=1)
        norm = np.linalg.norm(values[SketchAttribute.ROTATION], axis=1)
        near_identity = norm - tol < 1e-7  # the identity threshold of may flip
        bound["rot"][rows] = np.where(near_identity, 2.0, 2.0 * tol / np.maximum(norm - tol, 1e-300))[:, None]
        a = values[SketchAttribute.OPACITY][:, 0]
        t = terms[SketchAttribute.OPACITY][:, 0]
        lo = np.clip(a - t, 1e-4, 1 - 1e-4)
        hi = np.clip(a + t, 1e-4, 1 - 1e-4)
        slope = np.maximum(1 / (lo * (1 - lo)), 1 / (hi * (1 - hi)))
        bound["opacity"][rows] = t * slope
    return bound


def _assert_close(got: np.ndarray, want: np.ndarray, bound: np.ndarray | float, what: str) -> None:
    ulp = np.spacing(np.abs(want).astype(np.float32)).astype(np.float64)
    diff = np.abs(got.astype(np.float64) - want.astype(np.float64))
    bad = diff > np.asarray(bound) + ulp
    assert not bad.any(), (f"{what}: {int(bad.sum())} values off, worst "
                           f"{float((diff - bound - ulp).max()):.3g} past the bound")


def _compare(js_ply: Path, ref: spcodec.GaussianCloud, bounds: dict[str, np.ndarray],
             what: str) -> None:
    """The JS decoder's PLY against the reference's cloud, within [R-96]."""
    got = read_ply(js_ply)
    assert len(got) == len(ref), f"{what}: {len(got)} Gaussians, the reference {len(ref)}"
    assert got.sh_rest.shape == ref.sh_rest.shape, f"{what}: SH layout differs"
    ns = min(len(bounds["opacity"]), len(ref))
    sk, pa = slice(0, ns), slice(ns, len(ref))
    assert np.array_equal(got.means, ref.means), f"{what}: positions differ"
    for name, g, r, b in [("scale", got.scales, ref.scales, bounds["scale"][:ns]),
                          ("rot", got.quats, ref.quats, bounds["rot"][:ns]),
                          ("opacity", got.opacities, ref.opacities, bounds["opacity"][:ns]),
                          ("f_dc", got.sh_dc, ref.sh_dc, bounds["dc"][:ns]),
                          ("f_rest", got.sh_rest.reshape(len(got), bounds["rest"].shape[1]),
                           ref.sh_rest.reshape(len(ref), bounds["rest"].shape[1]),
                           bounds["rest"][:ns])]:
        _assert_close(g[sk], r[sk], b, f"{what}: sketch {name}")
        patch_bound = 0.0  # exact, except one ulp for rotations and opacities (added anyway)
        if name in ("scale", "f_dc", "f_rest"):
            assert np.array_equal(g[pa], r[pa]), f"{what}: patch {name} differs"
        else:
            _assert_close(g[pa], r[pa], patch_bound, f"{what}: patch {name}")


# ------------------------------------------------------------------------------ valid files
@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_js_decoder_matches_reference(case, tmp_path):
    name, seed, sh, codec, gz, clusters, modes, sizes, metadata = case
    data = build_bitstream(_scene(seed, sh, clusters, modes, sizes, metadata),
                           WriteOptions(codec=codec, gzip=gz))
    inp = tmp_path / f"{name}.spc"
    inp.write_bytes(data)
    bounds = _sketch_bounds(data, sh)
    inner, _ = _unwrap(data, DEFAULT_LIMITS)
    layers = len(layer_end_offsets(inner))
    runs: list[tuple[str, Path, int | None]] = [("whole", inp, None), ("max-layer 0", inp, 0)]
    middle = layers // 2
    if middle:
        runs.append((f"max-layer {middle}", inp, middle))
    ends = read_gzip_layer_ends(data) if gz else layer_end_offsets(inner)
    for k in sorted({0, middle}):
        prefix = tmp_path / f"{name}-prefix{k}.spc"
        prefix.write_bytes(data[:ends[k]])
        runs.append((f"prefix to layer {k}", prefix, None))
    for what, path, max_layer in runs:
        out = tmp_path / "out.ply"
        result = _run_cli(path, out, max_layer)
        assert result.returncode == 0, f"{name} {what}: {result.stderr}"
        ref = spcodec.decode(path.read_bytes(), max_layer=max_layer)
        _compare(out, ref, bounds, f"{name} {what}")
        header = out.read_bytes()[:out.read_bytes().index(b"end_header\n")]
        expected_header = spcodec.ply.ply_bytes(ref)[0]
        assert header + b"end_header\n" == expected_header, f"{name} {what}: PLY header differs"
        out.unlink()


def test_max_layer_past_the_bytes_is_truncated_in_both(tmp_path):
    data = build_bitstream(_scene(30, 1, 3, [Q, Q], [20, 20], None))
    ends = layer_end_offsets(data)
    inp = tmp_path / "prefix.spc"
    inp.write_bytes(data[:ends[0]])
    with pytest.raises(spcodec.FormatError) as ref:
        spcodec.decode(inp.read_bytes(), max_layer=1)
    result = _run_cli(inp, tmp_path / "out.ply", 1)
    assert result.returncode != 0 and f"[{ref.value.code}]" in result.stderr
    assert not (tmp_path / "out.ply").exists()


# ------------------------------------------------------------------------------ corrupt files
MUTANTS = 240


def _reference_outcome(data: bytes) -> tuple[str, int]:
    try:
        return "ok", len(spcodec.decode(data))
    except spcodec.FormatError as exc:
        return exc.code, 0


def _inner_prefix(data: bytes) -> bytes:
    """What a gzip wrapper inflates to before its first error (all of it when it has none)."""
    inflater, out = zlib.decompressobj(wbits=31), []
    try:
        for at in range(len(data)):  # byte by byte: a failing call returns nothing
            out.append(inflater.decompress(data[at:at + 1]))
    except zlib.error:
        pass
    return b"".join(out)


def _also_valid(data: bytes, js_code: str) -> bool:
    """Whether a rejection that differs from the reference's names another defect of the input.

    A wrapped file can be damaged both in its wrapper and in the inner header block. The
    reference inflates up to 176 KiB before it reads the inner header, so on small files it meets
    a broken wrapper first; the JS decoder reads the header as soon as it is inflated. Section 12
    lets a decoder report either defect: the JS code is accepted when the reference gives it for
    the inner bytes the wrapper yields.
    """
    if not spcodec.codecs.is_gzip(data):
        return False
    return _reference_outcome(_inner_prefix(data))[0] == js_code


def test_js_decoder_rejects_what_the_reference_rejects(tmp_path):
    """Fuzz mutants with repaired checksums: same accept/reject, same code (or, for an input with
    two defects, see _also_valid), same counts."""
    fz = fuzzing
    seeds = fz.build_seeds()
    chooser = fz.RandomChooser(random.Random(1313))
    files, expected = [], {}
    for i in range(MUTANTS):
        kind, data = fz.make_mutant(seeds, chooser)
        path = tmp_path / f"m{i:04d}-{kind}.spc"
        path.write_bytes(data)
        files.append(path)
        expected[str(path)] = _reference_outcome(data)
    result = subprocess.run(["node", str(BATCH), *map(str, files)], capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    got = {line["input"]: line for line in map(json.loads, result.stdout.splitlines())}
    differ = []
    for path in files:
        code, count = expected[str(path)]
        js = got[str(path)]
        assert js["code"] != "crash", f"{path.name}: the JS decoder threw {js['message']}"
        if (js["code"], js.get("count", 0)) != (code, count) and not (
                code != "ok" and js["code"] != "ok" and _also_valid(path.read_bytes(), js["code"])):
            differ.append(f"{path.name}: reference {code} ({count}), JS {js['code']} "
                          f"({js.get('count', 0)}) {js.get('message', '')}")
    codes = {c for c, _ in expected.values()}
    assert len(codes) >= 10, f"the mutants reach too few checks: {sorted(codes)}"
    assert not differ, "\n".join(differ)


ZSTD_BATCH = r"""
import { readFileSync } from 'node:fs';
import { createHash } from 'node:crypto';
import { inflateZstd } from 'ZSTD_JS';
for (const line of readFileSync(process.argv[1], 'utf8').split('\n').filter(Boolean)) {
  const { hex, raw } = JSON.parse(line);
  let out;
  try {
    const bytes = inflateZstd(new Uint8Array(Buffer.from(hex, 'hex')), raw);
    out = { code: 'ok', sha: createHash('sha256').update(bytes).digest('hex') };
  } catch (err) {
    out = { code: err.code ?? 'crash', message: String(err && err.message) };
  }
  process.stdout.write(JSON.stringify(out) + '\n');
}
"""


def _zstd_mutants(rng: random.Random, count: int) -> list[tuple[bytes, int]]:
    """Frames of libzstd (every literal and sequence mode its levels use, repeat tables,
    treeless literals, checksums) and hand-made ones (windows of 1 KiB, raw and RLE blocks,
    Huffman streams, RLE-coded sequences), with bytes changed: where libzstd and fzstd differed."""
    from spcodec.conformance.zstd_bits import (
        NO_SEQUENCES,
        block,
        frame_header,
        huffman_literals,
        rle_sequences,
    )

    frames = []
    for i in range(24):
        n = rng.choice([40, 700, 5000, 60000, 200000])
        alphabet = rng.choice([b"ab", b"abcdefghij   eeettt", bytes(range(256))])
        text = bytes(rng.choice(alphabet) for _ in range(n // 2))
        raw = text + text[: n // 4] + bytes(rng.randrange(256) for _ in range(n - n // 2 - n // 4))
        level = rng.choice([1, 3, 12, 19])
        frames.append((zstandard.ZstdCompressor(level=level, write_content_size=True,
                                                 write_checksum=i % 3 == 0).compress(raw), len(raw)))
    sixteen = {97 + i: 1 for i in range(16)}
    for _ in range(24):
        literals = bytes(rng.choice(b"abcdefghijklmnop") for _ in range(rng.choice([6, 40, 300])))
        section = huffman_literals(literals, sixteen, streams=rng.choice([1, 4]))
        ll = rng.randrange(len(literals) + 1)
        ml = rng.choice([3, 5, 100])
        sequences = rng.choice([NO_SEQUENCES, rle_sequences(ll, ml, rng.choice([1, 2, 3, 4, 9]))])
        size = len(literals) + (0 if sequences == NO_SEQUENCES else ml)
        body = block(0, b"xyz" * 100, False) + block(1, b"q", False, 50)
        frames.append((frame_header(size + 350, 10) + body + block(2, section + sequences, True),
                       size + 350))
    mutants = []
    for _ in range(count):
        frame, size = rng.choice(frames)
        data = bytearray(frame)
        for _ in range(rng.choice([1, 1, 2, 4])):
            data[rng.randrange(len(data))] = rng.randrange(256)
        mutants.append((bytes(data), size))
    return mutants


def test_zstd_frames_decode_alike_in_both_decoders(tmp_path):
    """[R-22], spec 1.1.1: on frames with bytes changed (a section CRC would be repaired), the
    two decoders agree on every frame: the same bytes, or decompression-failed, or
    length-mismatch. (libzstd and fzstd, which they used to rely on, differed on about one such
    frame in three.)"""
    from spcodec.codecs import decompress

    mutants = _zstd_mutants(random.Random(1717), 2500)
    batch = tmp_path / "frames.jsonl"
    batch.write_text("".join(json.dumps({"hex": d.hex(), "raw": n}) + "\n" for d, n in mutants))
    script = ZSTD_BATCH.replace("ZSTD_JS", (WEB / "src" / "zstd.js").as_uri())
    result = subprocess.run(["node", "--input-type=module", "-e", script, str(batch)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    js = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(js) == len(mutants)
    outcomes, differ = {}, []
    for (data, size), got in zip(mutants, js):
        try:
            want = {"code": "ok", "sha": hashlib.sha256(decompress(Codec.ZSTD, data, size))
                    .hexdigest()}
        except spcodec.FormatError as exc:
            want = {"code": exc.code}
        outcomes[want["code"]] = outcomes.get(want["code"], 0) + 1
        if (got["code"], got.get("sha")) != (want["code"], want.get("sha")):
            differ.append(f"{data.hex()} ({size}): reference {want['code']}, JS {got['code']} "
                          f"{got.get('message', '')}")
    assert not differ, "\n".join(differ[:5])
    assert outcomes.get("ok", 0) > 300 and outcomes.get("decompression-failed", 0) > 300, outcomes


def test_cli_rejects_corrupt_files_with_the_reference_code(tmp_path):
    """Through the CLI itself: non-zero exit, one stderr line with [code], no output file."""
    data = build_bitstream(_scene(31, 2, 3, [Q, DRACO], [30, 20], {"k": 1}))
    header_end = spcodec.inspect(data).header.header_size
    info = spcodec.inspect(data).header
    sketch = next(s for s in info.sections if s.type == SectionType.SKETCH_CLUSTERS)
    corrupt = {
        "bad-magic": b"PK\x03\x04" + data[4:],
        "truncated": data[:header_end + 3],
        "trailing-data": data + b"\0",
        "header-crc": data[:30] + bytes([data[30] ^ 1]) + data[31:],
        "section-crc": data[:sketch.offset] + bytes([data[sketch.offset] ^ 1]) + data[sketch.offset + 1:],
        "unsupported-version": data[:8] + b"\x02\x00" + data[10:],
        "bad-gzip": spcodec.codecs.gzip_wrap(data, [])[:-8] + b"\0" * 8,
    }
    for code, bad in corrupt.items():
        inp = tmp_path / f"{code}.spc"
        inp.write_bytes(bad)
        with pytest.raises(spcodec.FormatError) as ref:
            spcodec.decode(bad)
        assert ref.value.code == code, f"the reference says {ref.value.code} for {code}"
        out = tmp_path / f"{code}.ply"
        result = _run_cli(inp, out)
        assert result.returncode != 0, code
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].endswith(f"[{code}]"), f"{code}: {result.stderr!r}"
        assert sorted(p.name for p in tmp_path.iterdir() if p.suffix != ".spc") == [], \
            f"{code}: the CLI left files behind"


# ------------------------------------------------------------------------- conformance suite
CONFORMANCE_COMMAND = ["conformance", "--decoder", "node web/bin/spc-decode.mjs {input} {output}",
                       "--max-layer-arg", "--max-layer {k}"]


@pytest.mark.slow
def test_js_decoder_passes_the_conformance_suite():
    """`spcodec conformance --decoder 'node web/bin/spc-decode.mjs {input} {output}'
    --max-layer-arg '--max-layer {k}'`, exactly: every vector, every max_layer, must pass."""
    spcodec_cli = Path(sys.executable).with_name("spcodec")
    command = [str(spcodec_cli) if spcodec_cli.exists() else "spcodec", *CONFORMANCE_COMMAND]
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=1800)
    summary = "\n".join(result.stdout.strip().splitlines()[-3:])
    assert result.returncode == 0, f"{summary}\n{result.stderr[-2000:]}"
    assert " 0 failed, 0 not run" in summary, summary
