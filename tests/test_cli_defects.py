"""Command-line defects found in review: the stored up axis, a missing GPU, .glb inputs, section
CRCs, unwritable outputs and the account of NaN/infinite values."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import spcodec
from spcodec.cli import main


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(err: str) -> bool:
    return err.count("\n") == 1 and err.startswith("spcodec: error:") and "Traceback" not in err


@pytest.fixture
def z_up(tmp_path, small_scene) -> Path:
    """The small scene as an .spc whose metadata says +z is up (what `encode --up +z` records)."""
    from spcodec.writer import build_bitstream

    path = tmp_path / "z.spc"
    path.write_bytes(build_bitstream(dataclasses.replace(
        small_scene, metadata={**small_scene.metadata, "up": "+z"})))
    return path


# ---------------------------------------------------------------- 1. the up axis the file stores
def test_render_uses_the_up_axis_the_spc_stores(capsys, tmp_path, z_up):
    """A z-up scene tumbled sideways unless --up was given again; an explicit --up still wins."""
    pngs = {}
    for name, up in (("stored", []), ("plus_z", ["--up=+z"]), ("minus_y", ["--up=-y"])):
        out = tmp_path / f"{name}.png"
        code, _, err = run(capsys, "render", z_up, "-o", out, "--resolution", "32", "--device",
                           "cpu", *up)
        assert code == 0, err
        pngs[name] = out.read_bytes()
    assert pngs["stored"] == pngs["plus_z"] != pngs["minus_y"]


def test_eval_uses_the_up_axis_the_spc_stores(capsys, tmp_path, monkeypatch, z_up):
    import spcodec.imaging.evaluate as evaluate

    seen = []

    class Report:
        def summary_lines(self, name):
            return ["judged"]

    def judge(model, reference, config):
        seen.append(config.up)
        return Report()

    monkeypatch.setattr(evaluate, "evaluate_against_reference", judge)
    ply = tmp_path / "z.ply"
    spcodec.write_ply(ply, spcodec.decode(z_up))
    for argv in ([z_up, "--reference", ply], [ply, "--reference", z_up],
                 [z_up, "--reference", ply, "--up=-x"], [ply, "--reference", ply]):
        code, _, err = run(capsys, "eval", *argv, "--device", "cpu")
        assert code == 0, err
    assert seen == ["+z", "+z", "-x", "-y"]


# ------------------------------------------------------------------------ 2. --device cuda, no GPU
@pytest.mark.parametrize("command", ["render", "eval", "encode"])
def test_a_missing_gpu_is_a_one_line_usage_error_for_every_command(capsys, tmp_path, monkeypatch,
                                                                    small_file, command):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    spc, ply = tmp_path / "s.spc", tmp_path / "s.ply"
    spc.write_bytes(small_file)
    spcodec.write_ply(ply, spcodec.decode(small_file))
    argv = {"render": ["render", spc, "-o", tmp_path / "x.png"],
            "eval": ["eval", spc, "--reference", ply],
            "encode": ["encode", ply, "-o", tmp_path / "x.spc", "--no-retrain"]}[command]
    code, out, err = run(capsys, *argv, "--device", "cuda")
    assert code == 2 and one_line_error(err), err
    assert "--device cuda" in err and "internal error" not in err and out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.ply", "s.spc"]


# --------------------------------------------------------------------------------- 3. .glb inputs
def test_info_and_decode_read_the_spc_that_embed_wrote(capsys, tmp_path, small_file):
    spc, glb = tmp_path / "s.spc", tmp_path / "s.glb"
    spc.write_bytes(small_file)
    assert run(capsys, "embed", spc, "-o", glb)[0] == 0
    code, out, err = run(capsys, "info", glb, "--json")
    doc = json.loads(out)
    assert code == 0 and doc["gaussians"] == len(spcodec.decode(small_file)), err
    assert doc["stored_size"] == len(small_file) and doc["embedded_in"] == "glb"
    code, out, _ = run(capsys, "info", glb)
    assert code == 0 and "embedded in a glTF" in out.splitlines()[0]
    code, _, err = run(capsys, "decode", glb, "-o", tmp_path / "s.ply")
    assert code == 0, err
    assert spcodec.read_ply(tmp_path / "s.ply").equals(spcodec.decode(small_file))


def test_a_glb_without_an_spc_is_named_as_a_gltf_file(capsys, tmp_path, small_file):
    spc, glb = tmp_path / "s.spc", tmp_path / "plain.glb"
    spc.write_bytes(small_file)
    assert run(capsys, "decode", spc, "-o", glb)[0] == 0  # splats as accessors, no .spc inside
    for argv in (["info", glb], ["decode", glb, "-o", tmp_path / "x.ply"]):
        code, out, err = run(capsys, *argv)
        assert code == 2 and one_line_error(err) and out == "", err
        assert "is a glTF file" in err and "spcodec serve" in err and "bad magic" not in err
    assert not (tmp_path / "x.ply").exists()


@pytest.mark.parametrize("content", [b"glTF", b"glTF\x02\x00\x00\x00" + b"\xff" * 40])
def test_a_malformed_glb_fails_in_one_line(capsys, tmp_path, content):
    glb = tmp_path / "bad.glb"
    glb.write_bytes(content)
    code, _, err = run(capsys, "info", glb)
    assert code == 1 and one_line_error(err) and "glTF" in err, err


# ---------------------------------------------------------------------------- 4. info --verify
def test_info_verify_names_the_damaged_section(capsys, tmp_path, small_file):
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    code, out, err = run(capsys, "info", src, "--verify")
    sections = spcodec.inspect(small_file).header.sections
    assert code == 0 and out.splitlines()[-1] == f"all {len(sections)} sections verified (CRC-32)"
    code, out, _ = run(capsys, "info", src, "--verify", "--json")
    assert code == 0 and json.loads(out)["verified_sections"] == len(sections)
    for section in (sections[2], sections[-1]):
        damaged = bytearray(small_file)
        damaged[section.offset + section.stored_length // 2] ^= 0x01
        src.write_bytes(bytes(damaged))
        assert run(capsys, "info", src)[0] == 0  # the header alone is fine
        code, out, err = run(capsys, "info", src, "--verify")
        assert code == 1 and one_line_error(err) and out == "", err
        assert f"layer {section.layer} section #{section.index} ({section.type_name}" in err


def test_info_verify_refuses_a_cut_file(capsys, tmp_path, small_file):
    src = tmp_path / "cut.spc"
    src.write_bytes(small_file[:-100])
    code, _, err = run(capsys, "info", src, "--verify")
    assert code == 1 and one_line_error(err) and "missing" in err and "--max-layer" not in err


# ----------------------------------------------------------------------- 5. unwritable outputs
def test_an_output_below_a_file_says_the_parent_is_a_file(capsys, tmp_path, small_file):
    src, blocker = tmp_path / "s.spc", tmp_path / "file.spc"
    src.write_bytes(small_file)
    blocker.write_bytes(b"")
    for output in (blocker / "x.ply", blocker / "deeper" / "x.ply"):
        code, _, err = run(capsys, "decode", src, "-o", output)
        assert code == 2 and one_line_error(err), err
        assert f"{blocker} is a file, not a folder" in err and "does not exist" not in err


def test_a_full_device_is_named_in_the_error(capsys, tmp_path, small_file):
    if not Path("/dev/full").is_char_device():
        pytest.skip("needs Linux's /dev/full")  # pragma: no cover
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    code, _, err = run(capsys, "decode", src, "-o", "/dev/full")
    assert code == 1 and one_line_error(err) and "/dev/full: No space left on device" in err


# -------------------------------------------------------------------- 6. every kind of bad value
@pytest.mark.parametrize("command", ["render", "encode"])
def test_every_kind_of_bad_value_is_named(capsys, tmp_path, small_file, command):
    cloud = spcodec.decode(small_file)
    cloud.means[3, 0] = np.nan
    cloud.opacities[5] = np.inf
    bad = tmp_path / "bad.ply"
    spcodec.write_ply(bad, cloud)
    output = tmp_path / ("x.png" if command == "render" else "x.spc")
    extra = ["--device", "cpu"] if command == "render" else ["--no-retrain", "--quiet"]
    code, _, err = run(capsys, command, bad, "-o", output, *extra)
    assert code == 1 and one_line_error(err), err
    assert "NaN in x; infinite value in opacity" in err and "[ply-invalid]" in err
    assert not output.exists()


def test_bad_values_are_named_by_their_ply_property():
    from spcodec.synthetic import make_scene

    cloud = make_scene(1, curves=1, per_curve=20, blobs=30).cloud
    k = cloud.sh_rest.shape[1]
    cloud.sh_rest[2, 1, 2] = -np.inf  # coefficient 1 of blue: f_rest_(2k + 1), channel-major
    cloud.scales[0, 2] = np.nan
    cloud.means[4, 1] = np.nan
    with pytest.raises(spcodec.FormatError) as caught:
        cloud.check_finite()
    assert str(caught.value).startswith(f"NaN in y, scale_2; infinite value in f_rest_{2 * k + 1}:")
    assert "\n" not in str(caught.value) and caught.value.code == "ply-invalid"
    make_scene(1, curves=1, per_curve=20, blobs=30).cloud.check_finite()
