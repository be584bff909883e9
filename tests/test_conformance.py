"""The conformance suite: the reference decoder passes it, wrong decoders fail it (naming the
vectors), it exercises every checkable requirement and every error code, and the committed vectors
are exactly what the generator makes."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import warnings
import zlib
from importlib import metadata as package_metadata
from pathlib import Path

import numpy as np
import pytest

import spcodec
from spcodec.cli import main
from spcodec.conformance import (
    SUITE_DIR,
    Decode,
    ExternalDecoder,
    InProcessDecoder,
    load_manifest,
    run_suite,
)
from spcodec.conformance.outputs import OutputError, read_output_ply
from spcodec.conformance.runner import FORMAT_CODES

from test_spec import DEFINED, checkable_requirements

SUITE = load_manifest()


class ShiftX(InProcessDecoder):
    """A decoder that gets every position 0.05 off along x."""

    name = "shift-x"

    def decode(self, path, max_layer, sh_degree):
        out = super().decode(path, max_layer, sh_degree)
        if out.properties is not None:
            out.properties["x"] = out.properties["x"] + np.float32(0.05)
        return out


class AcceptsEverything(InProcessDecoder):
    """A decoder that outputs nothing instead of rejecting an invalid file."""

    name = "accepts-everything"

    def decode(self, path, max_layer, sh_degree):
        out = super().decode(path, max_layer, sh_degree)
        if out.error is None:
            return out
        return Decode(properties={"x": np.zeros(0, np.float32)})


class OneCodeForAll(InProcessDecoder):
    """A decoder that rejects what it should, always with the same code."""

    name = "one-code"

    def decode(self, path, max_layer, sh_degree):
        out = super().decode(path, max_layer, sh_degree)
        return out if out.error is None else Decode(error="bad-section")


# ------------------------------------------------------------------------------ passing
def test_the_reference_decoder_passes_every_vector():
    report = run_suite(InProcessDecoder())
    assert report.ok, report.summary()
    assert len(report.results) == sum(len(v.outcomes) for v in SUITE.vectors)
    assert report.count("pass") == len(report.results)


def test_a_decoder_without_zstd_passes_when_the_runner_is_told(monkeypatch):
    """[R-23], ID-1: decodes that need zstd expect codec-unavailable under --without-zstd; told
    nothing, the runner fails exactly those (so the manifest's "needs" are right)."""
    monkeypatch.setattr("spcodec.codecs._zstd", None)
    needing = {v.id for v in SUITE.vectors for o in v.outcomes if "zstd" in o.needs}
    assert {"sh2-zstd-draco-patch", "zstd-frames-with-checksums"} <= needing
    # the zstd vectors, and others that hold zstd data a decoder never inflates
    only = sorted(needing) + ["unknown-optional-sections", "expansion-beyond-1024x", "sh0-*"]
    assert run_suite(InProcessDecoder(), only=only, without_zstd=True).ok
    assert set(run_suite(InProcessDecoder(), only=only).failed_vectors) == needing


# ----------------------------------------------------------------------- proof it can fail
def test_a_decoder_that_shifts_x_fails_naming_the_vectors():
    report = run_suite(ShiftX())
    decoding = {v.id for v in SUITE.vectors if any(o.accepts and o.gaussians for o in v.outcomes)}
    assert set(report.failed_vectors) == decoding
    failures = [r for r in report.results if r.status == "fail"]
    assert all(r.reason.startswith("x[") for r in failures), failures[0].reason
    text = report.table()
    assert all(vector in text.splitlines()[-1] for vector in decoding)


def test_a_decoder_that_accepts_invalid_files_fails():
    report = run_suite(AcceptsEverything())
    rejecting = {v.id for v in SUITE.vectors if any(not o.accepts for o in v.outcomes)}
    assert {v.id for v in SUITE.vectors if v.kind == "invalid"} <= rejecting
    assert set(report.failed_vectors) == rejecting
    assert all(r.reason.startswith("accepted an input it must reject with [")
               for r in report.results if r.status == "fail")


def test_a_rejection_is_checked_for_its_reason():
    report = run_suite(OneCodeForAll())
    wrong = {v.id for v in SUITE.vectors for o in v.outcomes
             if not o.accepts and "bad-section" not in {o.error, *o.also_accepted}}
    assert set(report.failed_vectors) == wrong
    assert any("rejected with [bad-section], expected [section-crc]" in r.reason
               for r in report.results)


class EndOffsetsFirst(InProcessDecoder):
    """A decoder that compares layers' end offsets before it looks for their sections (as one
    written from the spec alone did): a layer without sections is bad-layout to it."""

    name = "end-offsets-first"

    def decode(self, path, max_layer, sh_degree):
        out = super().decode(path, max_layer, sh_degree)
        return Decode(error="bad-layout") if out.error == "missing-section" and \
            "without-sections" in str(path) else out


def test_a_layer_without_sections_is_either_code():
    """[R-9], spec 1.1.1: a layer without sections fails missing-section and its end offset
    check; no order between them is prescribed, so the vector accepts both codes, and a decoder
    that checks end offsets first passes it."""
    vector = next(v for v in SUITE.vectors if v.id == "layer-without-sections")
    outcome = vector.outcomes[0]
    assert (outcome.error, outcome.also_accepted) == ("missing-section", ("bad-layout",))
    assert run_suite(EndOffsetsFirst(), only=["layer-without-sections"]).ok
    assert run_suite(OneCodeForAll(), only=["layer-without-sections"]).failed_vectors == \
        ["layer-without-sections"]


def test_the_vectors_of_spec_1_1_1_pin_both_sides():
    """spec 1.1.1: the decisions of its CHANGELOG entry, one vector per side of each line."""
    outcomes = {v.id: v.outcomes[0] for v in SUITE.vectors}
    valid = ["gzip-cut-after-empty-code-length-code", "zstd-match-beyond-window"]
    invalid = {"gzip-empty-code-length-code-read-out": "bad-gzip",
               "zstd-literal-stream-bits-left": "decompression-failed",
               "zstd-block-over-maximum": "decompression-failed",
               "zstd-match-before-frame-start": "decompression-failed",
               "zstd-literals-length-past-literals": "decompression-failed",
               "zstd-sequence-bits-left": "decompression-failed"}
    assert all(outcomes[v].accepts for v in valid)
    assert {v: outcomes[v].error for v in invalid} == invalid
    assert all("zstd" in outcomes[v].needs for v in invalid if v.startswith("zstd"))
    assert SUITE.spec_version == "1.2.1"  # the latest text revision the vectors follow


# -------------------------------------------------------------------------------- coverage
def test_every_checkable_requirement_is_exercised_by_a_vector():
    """Annex D: each requirement a decoder can check is cited by at least one vector."""
    cited = {r for v in SUITE.vectors for r in v.requirements}
    assert checkable_requirements() - cited == set()
    assert {r[2:] for r in cited} <= DEFINED


def test_every_error_code_is_exercised():
    """Section 12: every code is some vector's expected outcome, save two that no decoder with
    zstd that only decodes can report: codec-unavailable (the zstd vectors under
    --without-zstd) and bad-metadata (a valid vector whose metadata is not JSON)."""
    codes = {o.error for v in SUITE.vectors for o in v.outcomes if o.error}
    assert codes == FORMAT_CODES - {"codec-unavailable", "bad-metadata"}
    assert any("zstd" in o.needs for v in SUITE.vectors for o in v.outcomes)
    metadata = next(v for v in SUITE.vectors if v.id == "metadata-not-json")
    assert metadata.kind == "valid" and "bad-metadata" in spcodec.inspect(
        SUITE.path(metadata.input_path)).metadata_error


FUZZ_FINDINGS = {
    "Draco header claiming ~2^31 points": "draco-point-count-claim",
    "layer table claiming 60 M Gaussians": "layer-count-claim-density",
    "layer claim within the density limit": "layer-count-claim",
    "sketch models overflowing to inf": "sketch-model-overflow",
    "rotation norms overflowing": "sketch-rotation-norm-overflow",
    "deeply nested metadata JSON": "metadata-not-json",
    "gzip SP offsets shorter than the layer table": "gzip-layer-offsets-malformed",
    "zstd section with a skippable frame": "zstd-skippable-frame",
    "zstd section with a second frame": "zstd-two-frames",
    "metadata over its limit": "metadata-over-16-mib",
    "gzip bomb of garbage": "gzip-bomb-of-zeros",
    "gzip bomb after a valid file": "gzip-inflates-past-file-size",
    "corrupt section reported before its CRC": "section-crc-sketch-clusters",
    "100 000 one-point clusters in a small file": "many-tiny-clusters",
    "cluster count claim": "cluster-count-claim",
    "codebook claim": "codebook-entries-claim",
}
"""docs/LOG.md section 6: each fuzzing finding that a file can express, and its vector (the
one left out, a file object read in one 4 GiB call, concerns the API, not a file)."""


def test_past_fuzz_findings_are_vectors():
    ids = {v.id for v in SUITE.vectors}
    assert set(FUZZ_FINDINGS.values()) <= ids


def test_vectors_are_kilobytes():
    sizes = [v.input_size for v in SUITE.vectors]
    assert max(sizes) < 64 * 1024
    files = [p for p in (SUITE_DIR / "vectors").rglob("*") if p.is_file()]
    assert sum(p.stat().st_size for p in files) < 1024 * 1024


def test_every_kind_of_content_is_covered():
    """The issue's coverage list, read back from the vectors' files."""
    infos = {v.id: spcodec.inspect(SUITE.path(v.input_path)) for v in SUITE.vectors
             if v.kind == "valid"}
    sections = [s for info in infos.values() for s in info.header.sections]
    assert {(s.type, s.codec) for s in sections if s.type < 0x100} >= {
        (t, c) for t in (0x10, 0x11, 0x12, 0x20, 0x21, 0x22) for c in (0, 1, 2)}
    assert {info.header.sh_degree for info in infos.values()} == {0, 1, 2, 3}
    assert {info.gzip for info in infos.values()} == {False, True}
    decoded_layers = {len(spcodec.decode_layers(SUITE.path(v.input_path)).layers)
                      for v in SUITE.vectors if v.kind == "valid"}
    assert decoded_layers >= set(range(1, 9))
    assert {s.type for s in sections} - {0x01, 0x10, 0x11, 0x12, 0x20, 0x21, 0x22}  # unknown ones
    modes = {spcodec.decoder.layers.section_payload(_inner(v), s)[0]
             for v in SUITE.vectors if v.kind == "valid"
             for s in spcodec.inspect(SUITE.path(v.input_path)).header.sections
             if s.type == 0x21 and s.end <= len(_inner(v))}
    assert modes == {0, 1, 2, 3}


def _inner(vector) -> bytes:
    data = SUITE.path(vector.input_path).read_bytes()
    return spcodec.codecs.gunzip(data, 1 << 30).inner if data[:2] == b"\x1f\x8b" else data


# ------------------------------------------------------------------------------ generation
def test_committed_vectors_equal_a_fresh_generation(tmp_path):
    """One command regenerates every byte. The bytes depend on the zlib, zstd and Draco
    encoders: with the versions the manifest records they must match exactly; with others the
    vectors must still mean the same (ids, requirements, outcomes) and the test says why it
    could not compare bytes."""
    from spcodec.conformance.generate import generate, generator_versions

    fresh = generate(tmp_path)
    if generator_versions() != SUITE.generator:
        warnings.warn(f"encoder versions {generator_versions()} differ from the manifest's "
                      f"{SUITE.generator}: compared meaning, not bytes", stacklevel=1)
        assert [(v.id, v.kind, v.requirements, v.outcomes) for v in fresh.vectors] == \
            [(v.id, v.kind, v.requirements, v.outcomes) for v in SUITE.vectors]
        return
    assert (tmp_path / "manifest.json").read_bytes() == (SUITE_DIR / "manifest.json").read_bytes()
    made = {p.relative_to(tmp_path) for p in (tmp_path / "vectors").rglob("*") if p.is_file()}
    have = {p.relative_to(SUITE_DIR) for p in (SUITE_DIR / "vectors").rglob("*") if p.is_file()}
    assert made == have
    for path in sorted(made):
        assert (tmp_path / path).read_bytes() == (SUITE_DIR / path).read_bytes(), path


def test_the_manifest_reads_back_to_the_same_text():
    assert SUITE.dumps() == (SUITE_DIR / "manifest.json").read_text(encoding="utf-8")
    assert SUITE.generator["zlib"] and SUITE.generator["dracopy"]
    assert package_metadata.version("DracoPy") and zlib.ZLIB_RUNTIME_VERSION


def test_a_damaged_suite_fails_its_vectors(tmp_path):
    shutil.copytree(SUITE_DIR / "vectors", tmp_path / "vectors")
    shutil.copy(SUITE_DIR / "manifest.json", tmp_path)
    victim = next(v for v in SUITE.vectors if v.id == "sh1-none-float32")
    path = tmp_path / victim.input_path
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF
    path.write_bytes(bytes(data))
    report = run_suite(InProcessDecoder(), load_manifest(tmp_path), only=["sh1-*"])
    assert report.failed_vectors == ["sh1-none-float32"]
    assert "suite damaged" in report.results[0].reason


# ------------------------------------------------------------------- the external contract
def _cli(*template: str) -> str:
    return " ".join([sys.executable, "-m", "spcodec.cli", *template])


def test_the_command_line_decoder_meets_the_external_contract(capsys):
    only = ["sh0-zlib-two-layers-prefix-0", "empty-input"]
    status = main(["conformance", "--decoder", _cli("decode", "{input}", "-o", "{output}"),
                   "--max-layer-arg", "--max-layer {k}", "--only", *only])
    out = capsys.readouterr().out
    assert status == 0, out
    assert "0 failed, 0 not run" in out


CONTRACT_BREAKERS = r'''
import os, shutil, signal, sys
mode, source, output = sys.argv[1], sys.argv[2], sys.argv[3]
if mode == "crash":
    os.kill(os.getpid(), signal.SIGKILL)
if mode == "no-code":
    sys.exit("could not decode")
if mode == "leave-output":
    open(output + ".part", "w").write("half")
    sys.exit("[bad-section]")
if mode == "ascii":
    open(output, "w").write("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nend_header\n")
'''


@pytest.mark.parametrize("mode, vector, reason", [
    ("crash", "empty-input", "killed by signal"),
    ("no-code", "empty-input", "without an [error-code] on stderr"),
    ("leave-output", "empty-input", "left output.ply.part behind"),
    ("ascii", "empty-scene", "not binary_little_endian"),
])
def test_external_decoders_that_break_the_contract_fail(tmp_path, capsys, mode, vector, reason):
    script = tmp_path / "breaker.py"
    script.write_text(CONTRACT_BREAKERS)
    status = main(["conformance", "--decoder", f"{sys.executable} {script} {mode} {{input}} "
                   f"{{output}}", "--only", vector])
    out = capsys.readouterr().out
    assert status == 1 and reason in out and f"failed: {vector}" in out


def test_decodes_needing_max_layer_are_not_run_without_the_argument_and_do_not_pass(capsys):
    """Skipping 228 of 420 decodes and exiting 0 let a decoder that cannot stop at a layer
    claim conformance."""
    status = main(["conformance", "--decoder", _cli("decode", "{input}", "-o", "{output}"),
                   "--only", "empty-scene", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert status == 1 and doc["passed"] == 1 and doc["not_run"] == 2 and doc["failed"] == 0
    main(["conformance", "--decoder", _cli("decode", "{input}", "-o", "{output}"),
          "--only", "empty-scene"])
    assert "give --max-layer-arg" in capsys.readouterr().out


def test_the_in_process_decoder_without_zstandard_expects_codec_unavailable(capsys, monkeypatch):
    """A plain `pip install spcodec` (no zstd extra) failed the zstd vectors of its own suite."""
    import importlib.util

    from spcodec.conformance.runner import InProcessDecoder

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "zstandard" else real(name, *a))
    monkeypatch.setitem(sys.modules, "zstandard", None)  # importing it now fails
    assert InProcessDecoder().lacks_zstd
    status = main(["conformance", "--only", "*zstd*", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert status == 0 and doc["failed"] == 0 and doc["decodes"] > 0
    assert "not installed" in doc["without_zstd"]


@pytest.mark.parametrize("argv", [
    ["--only", "no-such-vector"],
    ["--max-layer-arg", "--max-layer {k}"],
    ["--decoder", "decode-without-placeholders"],
    ["--decoder", "x {input} {output}", "--max-layer-arg=--max-layer"],
    ["--decoder", "no-such-program-here {input} {output}", "--only", "empty-input"],
    ["--suite", "/nonexistent"],
])
def test_usage_errors_exit_2_with_one_line(capsys, argv):
    assert main(["conformance", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("spcodec: error: ")


def test_output_plys_are_read_under_the_contract(tmp_path):
    from plyfile import PlyData, PlyElement

    def write(names, dtype="f4", text=False):
        rec = np.zeros(2, dtype=[(n, dtype) for n in names])
        path = tmp_path / "out.ply"
        PlyData([PlyElement.describe(rec, "vertex")], text=text).write(str(path))
        return path

    base = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
            "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert len(read_output_ply(write(base), 0)["x"]) == 2
    assert len(read_output_ply(write(base + ["nx", "ny", "nz"]), 0)) == 17
    for names, dtype, text, message in [
        (base + [f"f_rest_{i}" for i in range(45)], "f4", False, "does not allow"),
        (base, "f8", False, "not float32"),
        (base, "f4", True, "binary_little_endian"),
        (base[1:], "f4", False, "lacks x"),
        (base + ["nx"], "f4", False, "not all of nx"),
    ]:
        with pytest.raises(OutputError, match=message):
            read_output_ply(write(names, dtype, text), 0)


def test_external_templates_are_split_like_a_shell_would(tmp_path):
    decoder = ExternalDecoder("tool --in '{input}' --out={output}", "-k {k}")
    args = decoder.command(Path("/a b/in.spc"), Path("/o/out.ply"), 3)
    assert args == ["tool", "--in", "/a b/in.spc", "--out=/o/out.ply", "-k", "3"]


def test_the_runner_imports_no_heavy_packages():
    """The runner is a decoder-side tool ([R-95] for the decoder it drives)."""
    code = ("import sys; from spcodec.conformance import run_suite, InProcessDecoder; "
            "report = run_suite(InProcessDecoder(), only=['sh1-*', 'gzip-*']); "
            "heavy = [m for m in ('torch', 'sklearn', 'scipy') if m in sys.modules]; "
            "print(heavy, report.ok); sys.exit(1 if heavy or not report.ok else 0)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


FAKE_MYDEC = r'''#!PYTHON
"""A decoder with another interface: mydec -i IN -o OUT [-k K]; errors as 'ERROR <code>'."""
import argparse, sys
import spcodec
parser = argparse.ArgumentParser()
parser.add_argument("-i"); parser.add_argument("-o"); parser.add_argument("-k", type=int)
args = parser.parse_args()
try:
    cloud = spcodec.decode(args.i, max_layer=args.k)
except spcodec.FormatError as exc:
    sys.exit(f"ERROR {exc.code}: {exc.args[0]}")
spcodec.write_ply(args.o, cloud)
'''


def test_the_readme_worked_example_plugs_in_another_decoder(tmp_path, monkeypatch, capsys):
    """The wrapper script of conformance/README.md, run as written, meets the contract."""
    readme = (SUITE_DIR / "README.md").read_text(encoding="utf-8")
    start = readme.index("#!/bin/sh\n# mydec-conformance")
    wrapper = tmp_path / "mydec-conformance"
    wrapper.write_text(readme[start:readme.index("```", start)])
    tools = tmp_path / "bin"
    tools.mkdir()
    (tools / "mydec").write_text(FAKE_MYDEC.replace("PYTHON", sys.executable))
    (tools / "mydec-to-ply").write_text('#!/bin/sh\ncp "$1" "$2"\n')
    for path in (wrapper, tools / "mydec", tools / "mydec-to-ply"):
        path.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tools}:{__import__('os').environ['PATH']}")
    status = main(["conformance", "--decoder", f"{wrapper} {{input}} {{output}}",
                   "--max-layer-arg", "{k}", "--only", "cut-inside-layer-1", "gzip-magic-only"])
    out = capsys.readouterr().out
    assert status == 0 and "4 passed, 0 failed" in out, out
