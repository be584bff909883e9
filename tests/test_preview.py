"""The preview of spec 1.1 (7.4): embedding it, decoding it, and the scene never reading it."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import spcodec
from spcodec.cli import main
from spcodec.container import Codec, SectionType
from spcodec.errors import FormatError, TruncatedError, UsageError
from spcodec.preview import attach_preview
from spcodec.synthetic import random_encoded_scene
from spcodec.writer import Preview, SectionSpec, WriteOptions, build_bitstream

scenes = st.builds(random_encoded_scene, seed=st.integers(0, 10_000), clusters=st.integers(0, 3),
                   patch_layers=st.integers(0, 3), patch_size=st.integers(0, 40),
                   sh_degree=st.integers(0, 3),
                   metadata=st.one_of(st.none(), st.just({"k": "v"})))
small_files = st.builds(lambda seed, sh: build_bitstream(random_encoded_scene(
    seed, clusters=1, patch_layers=1, patch_size=12, sh_degree=sh)),
    st.integers(0, 10_000), st.integers(0, 3))


def _preview_bytes(seed: int = 3) -> bytes:
    return build_bitstream(random_encoded_scene(seed, clusters=1, patch_layers=1, patch_size=20,
                                                sh_degree=1))


def _scene_bytes(seed: int = 5, gzip: bool = False) -> bytes:
    return build_bitstream(random_encoded_scene(seed, patch_layers=3, patch_size=30,
                                                metadata={"k": "v"}), WriteOptions(gzip=gzip))


@settings(max_examples=25, deadline=None)
@given(scenes, small_files, st.data(), st.booleans())
def test_a_preview_changes_no_gaussian_of_the_scene_or_its_prefixes(scene, small, data, wrap):
    """[R-102], [R-11]: the scene and every layer prefix decode as without the preview; the
    preview decodes to the embedded file's Gaussians; the file says version 1.1."""
    plain = build_bitstream(scene, WriteOptions(gzip=wrap))
    layers = 1 + len(scene.patch_layers)
    takeover = data.draw(st.integers(0, layers - 1))
    with_preview = attach_preview(plain, small, takeover)
    assert spcodec.decode(with_preview).equals(spcodec.decode(plain))
    for k in range(layers):
        assert spcodec.decode(with_preview, max_layer=k).equals(spcodec.decode(plain, max_layer=k))
    info = spcodec.inspect(with_preview).to_json()
    assert info["version"] == "1.1" and info["gzip"] == wrap
    inner_ends = [layer.get("inner_end_offset", layer["end_offset"]) for layer in info["layers"]]
    inner = spcodec.decoder.api._unwrap(with_preview, spcodec.Limits())[0]
    for k, end in enumerate(inner_ends):
        assert spcodec.decode(bytes(inner[:end])).equals(spcodec.decode(plain, max_layer=k))
    preview = spcodec.decode_preview(with_preview)
    assert preview.takeover_layer == takeover and preview.cloud.equals(spcodec.decode(small))
    assert info["preview"] == {"end_offset": preview.section.end, "complete": True,
                               "takeover_layer": takeover, "bytes": len(small),
                               "gaussians": len(preview.cloud)}
    assert spcodec.inspect(plain).to_json().get("preview") is None
    assert spcodec.decode_preview(plain) is None


def test_the_preview_arrives_before_the_sketch_and_decodes_from_its_prefix():
    """[R-104]: writers put it after the metadata, so the bytes up to its end show it."""
    data = attach_preview(_scene_bytes(), _preview_bytes(), 2)
    header = spcodec.decode_layers(data).header
    types = [sec.type for sec in header.layers[0].sections]
    assert types[:2] == [SectionType.METADATA, SectionType.PREVIEW]
    section = spcodec.decoder.find_preview(header)
    assert section.end < header.layers[0].end_offset
    prefix = data[:section.end]
    assert spcodec.decode_preview(prefix).cloud.equals(spcodec.decode(_preview_bytes()))
    with pytest.raises(TruncatedError):
        spcodec.decode(prefix)
    with pytest.raises(TruncatedError, match="inside the PREVIEW section"):
        spcodec.decode_preview(data[:section.end - 1])


def test_attaching_again_replaces_the_preview_and_keeps_gzip_as_the_scene_had_it():
    scene = _scene_bytes(gzip=True)
    once = attach_preview(scene, _preview_bytes(3), 1)
    twice = attach_preview(once, _preview_bytes(4), 2)
    assert once[:2] == twice[:2] == b"\x1f\x8b"
    assert twice == attach_preview(scene, _preview_bytes(4), 2)
    plain = attach_preview(scene, _preview_bytes(4), 2, gzip=False)
    assert plain.startswith(b"\x89SPC") and spcodec.decode(plain).equals(spcodec.decode(scene))
    # a gzip-wrapped preview is stored unwrapped
    wrapped_preview = build_bitstream(random_encoded_scene(4, clusters=1, patch_layers=1,
                                                           patch_size=20, sh_degree=1),
                                      WriteOptions(gzip=True))
    assert attach_preview(scene, wrapped_preview, 2) == twice


@pytest.mark.parametrize("case, message", [
    ("prefix scene", "the scene is a prefix"),
    ("prefix preview", "the preview is a prefix"),
    ("nested", "cannot nest"),
    ("nested late", "cannot nest"),
    ("takeover", "not a layer of the scene"),
])
def test_attach_refuses_what_would_make_a_bad_preview(case, message):
    scene, small = _scene_bytes(), _preview_bytes()
    ends = [layer["end_offset"] for layer in spcodec.inspect(scene).to_json()["layers"]]
    takeover = 1
    if case == "prefix scene":
        scene = scene[:ends[1]]
    elif case == "prefix preview":
        small = small[:spcodec.inspect(small).to_json()["layers"][0]["end_offset"]]
    elif case == "nested":
        small = attach_preview(small, _preview_bytes(9), 0)
    elif case == "nested late":  # not a preview of its own, but refuses it all the same
        small = _with_late_preview()
    else:
        takeover = len(ends)
    with pytest.raises(UsageError, match=message):
        attach_preview(scene, small, takeover)


# -------------------------------------------------------------------- preview errors
def _with_preview_payload(payload: bytes, codec: Codec = Codec.NONE, *, crc: int | None = None,
                          extra: list[SectionSpec] = ()) -> bytes:
    """The conformance scene with a PREVIEW section of ``payload`` in layer 0 (and ``extra``)."""
    from spcodec.conformance.preview_cases import preview_section, scene_draft

    draft = scene_draft(41)
    section = preview_section(payload, codec)
    section.crc = crc
    draft.sections.insert(1, section)
    for sec in extra:
        draft.insert_after_layer(sec.layer, sec)
    return draft.build()


def _payload(file: bytes, takeover: int = 1, reserved: int = 0) -> bytes:
    return struct.pack("<HH", takeover, reserved) + file


def _flipped(data: bytes, offset: int) -> bytes:
    """``data`` with one bit of byte ``offset`` changed (no CRC repaired)."""
    out = bytearray(data)
    out[offset] ^= 1
    return bytes(out)


def _nested() -> bytes:
    return attach_preview(_preview_bytes(), _preview_bytes(8), 0)


@pytest.mark.parametrize("data, code", [
    (lambda: _with_preview_payload(b"\x01\x00\x00"), "bad-section"),
    (lambda: _with_preview_payload(_payload(_preview_bytes(), reserved=1)), "reserved-nonzero"),
    (lambda: _with_preview_payload(_payload(_preview_bytes(), takeover=3)), "bad-value"),
    (lambda: _with_preview_payload(_payload(build_bitstream(random_encoded_scene(
        2, clusters=1, patch_layers=1), WriteOptions(gzip=True)))), "bad-section"),
    (lambda: _with_preview_payload(_payload(_preview_bytes() + b"\0")), "bad-section"),
    (lambda: _with_preview_payload(_payload(_preview_bytes()[:-1])), "bad-section"),
    (lambda: _with_preview_payload(_payload(_nested())), "bad-section"),
    (lambda: _with_preview_payload(_payload(_flipped(_preview_bytes(), 26))), "header-crc"),
    (lambda: _with_preview_payload(_payload(_preview_bytes()), crc=0), "section-crc"),
    (lambda: _with_preview_payload(_payload(_preview_bytes()), Codec.ZLIB, extra=[SectionSpec(
        SectionType.PREVIEW, 0, _payload(_preview_bytes()), Codec.NONE, required=False)]),
     "duplicate-section"),
], ids=["short", "reserved", "takeover", "gzip", "longer", "shorter", "nested", "inner-header",
        "crc", "twice"])
def test_a_bad_preview_is_refused_with_its_code_and_the_scene_still_decodes(data, code):
    """[R-103] outcomes, and [R-102]: none of them touches the scene (but a CRC mismatch, which
    is the layer's, [R-7])."""
    data = data()
    with pytest.raises(FormatError) as err:
        spcodec.decode_preview(data)
    assert err.value.code == code
    info = spcodec.inspect(data).to_json()
    assert "error" in info["preview"]
    if code == "section-crc":
        with pytest.raises(FormatError, match="CRC"):
            spcodec.decode(data)
    else:
        assert len(spcodec.decode(data)) == spcodec.decode_layers(data).header.gaussian_count


def _with_late_preview() -> bytes:
    """The conformance scene with a PREVIEW section in layer 2 only."""
    from spcodec.conformance.preview_cases import scene_draft

    draft = scene_draft(44)
    draft.insert_after_layer(2, SectionSpec(SectionType.PREVIEW, 2, _payload(_preview_bytes()),
                                            Codec.NONE, required=False))
    return draft.build()


def test_only_layer_zero_holds_a_preview():
    """[R-103]: a PREVIEW section in a later layer is not a preview."""
    data = _with_late_preview()
    assert spcodec.decode_preview(data) is None
    assert "preview" not in spcodec.inspect(data).to_json()


def test_the_conformance_vector_holds_a_preview_that_decodes():
    """The runner cannot ask for a preview ([R-101]); the reference decoder's test does."""
    from spcodec.conformance.manifest import load_manifest

    manifest = load_manifest()
    vector = next(v for v in manifest.vectors if v.id == "preview-section")
    data = manifest.path(vector.input_path).read_bytes()
    preview = spcodec.decode_preview(data)
    assert preview.takeover_layer == 1 and len(preview.cloud) == 7 + 5
    assert preview.header.version == (1, 0)


# ---------------------------------------------------------------------------------- the CLI
def test_decode_preview_and_info_on_the_command_line(tmp_path, capsys):
    src, out = tmp_path / "p.spc", tmp_path / "p.ply"
    src.write_bytes(attach_preview(_scene_bytes(), _preview_bytes(), 2))
    assert main(["decode", str(src), "-o", str(out), "--preview"]) == 0
    assert "the preview, shown until layer 2" in capsys.readouterr().out
    assert spcodec.read_ply(out).equals(spcodec.decode(_preview_bytes()))
    assert main(["info", str(src)]) == 0
    assert "shown until layer 2 arrives" in capsys.readouterr().out
    assert main(["info", str(src), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["preview"]["takeover_layer"] == 2


def test_decode_preview_of_a_file_without_one_is_a_one_line_error(tmp_path, capsys):
    src, out = tmp_path / "p.spc", tmp_path / "p.ply"
    src.write_bytes(_scene_bytes())
    assert main(["decode", str(src), "-o", str(out), "--preview"]) != 0
    err = capsys.readouterr().err
    assert "has no preview" in err and err.count("\n") == 1 and not out.exists()
    assert main(["decode", str(src), "-o", str(out), "--preview", "--max-layer", "1"]) != 0
    assert "give one of them" in capsys.readouterr().err and not out.exists()


@pytest.mark.slow  # a sized encode with its preview: 12 s
def test_encode_with_a_preview_keeps_the_whole_file_within_the_target(tmp_path, capsys):
    """--preview-size: the scene is made for what the preview leaves; without retraining there
    are no prefix scores, so the preview shows until the last layer."""
    from spcodec.synthetic import make_scene

    ply, out, stats = tmp_path / "s.ply", tmp_path / "s.spc", tmp_path / "s.json"
    spcodec.write_ply(ply, make_scene(1, curves=2, per_curve=60, blobs=1500).cloud)
    code = main(["encode", str(ply), "-o", str(out), "--no-retrain", "--quiet",
                 "--target-size", "20k", "--preview-size", "6k", "--stats", str(stats)])
    assert code == 0, capsys.readouterr().err
    data = out.read_bytes()
    doc = json.loads(stats.read_text())
    assert len(data) == doc["bytes"] and len(data) <= 20_000 * 1.02
    preview = spcodec.decode_preview(data)
    assert doc["preview"]["bytes"] == preview.header.file_size <= 6_000 * 1.02
    layers = spcodec.inspect(data).to_json()["layers"]
    assert preview.takeover_layer == len(layers) - 1 == doc["preview"]["takeover_layer"]
    assert doc["layer_ends"] == [layer["end_offset"] for layer in layers]
    assert "preview:" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--target-size", "20k", "--preview-size", "15k"], "less than the preview"),
    (["--preview-size", "40"], "holds nothing"),
    (["--preview-size", "1k"], "the preview (--preview-size)"),
])
def test_encode_refuses_a_preview_it_cannot_make(tmp_path, capsys, argv, message):
    from spcodec.synthetic import make_scene

    ply, out = tmp_path / "s.ply", tmp_path / "s.spc"
    spcodec.write_ply(ply, make_scene(1, curves=2, per_curve=60, blobs=1500).cloud)
    assert main(["encode", str(ply), "-o", str(out), "--no-retrain", "--quiet", *argv]) != 0
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and not out.exists()


def test_takeover_is_the_first_prefix_that_beats_the_preview():
    from spcodec.encoder.preview import takeover_layer
    from spcodec.encoder.statistics import RetrainStats

    scene = RetrainStats("blend", prefix_psnr=[{"layer": 1, "psnr": 20.0},
                                                {"layer": 2, "psnr": 30.0},
                                                {"layer": 3, "psnr": 40.0}])
    preview = RetrainStats("blend", prefix_psnr=[{"layer": 1, "psnr": 25.0}])
    assert takeover_layer(scene, 4, preview) == 2
    assert takeover_layer(scene, 4, RetrainStats("blend", psnr_finished=45.0)) == 3
    assert takeover_layer(scene, 4, None) == 3
    assert takeover_layer(scene, 4, RetrainStats("blend", psnr_quantized=10.0)) == 1


def test_preview_payload_layout():
    """7.4: u16 takeover, u16 reserved, then the file."""
    payload = Preview(b"FILE", 513).payload()
    assert payload == b"\x01\x02\x00\x00FILE"
    assert np.frombuffer(payload[:2], "<u2")[0] == 513


def test_attach_preview_on_the_command_line_takes_over_where_the_metadata_says(tmp_path, capsys):
    """`spcodec attach-preview`: the takeover layer from both files' recorded prefix PSNR, or
    as given; the scene decodes unchanged."""
    scene = build_bitstream(random_encoded_scene(5, patch_layers=3, patch_size=30, metadata={
        "stats": {"prefix_psnr": [{"layer": 1, "psnr": 20.0}, {"layer": 2, "psnr": 31.0},
                                  {"layer": 3, "psnr": 40.0}]}}))
    small = build_bitstream(random_encoded_scene(3, clusters=1, patch_layers=1, patch_size=20,
                                                 metadata={"stats": {"prefix_psnr": [
                                                     {"layer": 1, "psnr": 30.5}]}}))
    paths = {name: tmp_path / f"{name}.spc" for name in ("scene", "small", "out", "given")}
    paths["scene"].write_bytes(scene)
    paths["small"].write_bytes(small)
    assert main(["attach-preview", str(paths["scene"]), str(paths["small"]), "-o",
                 str(paths["out"])]) == 0
    assert "until layer 2 arrives" in capsys.readouterr().out
    data = paths["out"].read_bytes()
    assert spcodec.decode_preview(data).takeover_layer == 2
    assert spcodec.decode(data).equals(spcodec.decode(scene))
    assert main(["attach-preview", str(paths["scene"]), str(paths["small"]), "-o",
                 str(paths["given"]), "--takeover", "1"]) == 0
    assert spcodec.decode_preview(paths["given"].read_bytes()).takeover_layer == 1
    capsys.readouterr()
    assert main(["attach-preview", str(paths["scene"]), str(paths["small"]), "-o",
                 str(tmp_path / "bad.spc"), "--takeover", "9"]) != 0
    err = capsys.readouterr().err
    assert "not a layer of the scene" in err and err.count("\n") == 1
    assert not (tmp_path / "bad.spc").exists()


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_a_damaged_preview_is_refused_with_a_spec_error_never_a_crash(data):
    """Untrusted input: any bytes of the payload, its CRC made right so the checks behind it run,
    give a preview or a SpcodecError with a code; the scene decodes all the same ([R-102])."""
    from spcodec.errors import SpcodecError

    payload = bytearray(_payload(_preview_bytes()))
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(payload) - 1))
        payload[at] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        payload = payload[:data.draw(st.integers(0, len(payload)))]
    damaged = _with_preview_payload(bytes(payload))
    try:
        spcodec.decode_preview(damaged)
    except SpcodecError as exc:
        assert exc.code
    assert len(spcodec.decode(damaged)) == spcodec.decode_layers(damaged).header.gaussian_count
