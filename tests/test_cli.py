"""The command line: outputs, one-line errors with non-zero exit codes, no partial files."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import spcodec
from spcodec.cli import main


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_decode_writes_a_ply(capsys, tmp_path, small_file):
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    code, out, _ = run(capsys, "decode", str(src), "-o", str(tmp_path / "s.ply"))
    assert code == 0 and "decoded" in out
    assert spcodec.read_ply(tmp_path / "s.ply").equals(spcodec.decode(small_file))
    code, _, _ = run(capsys, "decode", str(src), "-o", str(tmp_path / "l0.ply"), "--max-layer", "0")
    assert code == 0
    assert len(spcodec.read_ply(tmp_path / "l0.ply")) == \
        spcodec.decode_layers(small_file).header.layers[0].gaussian_count


def test_info_json_has_the_contract_fields(capsys, tmp_path, small_file):
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    code, out, _ = run(capsys, "info", str(src), "--json")
    doc = json.loads(out)
    assert code == 0 and doc["version"] == "1.0"
    assert doc["gaussians"] == len(spcodec.decode(small_file))
    assert all({"type", "codec", "offset", "length"} <= s.keys() for s in doc["sections"])
    assert [set(layer) >= {"index", "gaussians", "end_offset"} for layer in doc["layers"]] == \
        [True] * len(doc["layers"])
    code, out, _ = run(capsys, "info", str(src))
    assert code == 0 and "SKETCH_CLUSTERS" in out


@pytest.mark.parametrize("content", [b"", b"garbage", None])
def test_bad_inputs_fail_with_one_line_and_leave_no_output(capsys, tmp_path, small_file, content):
    src = tmp_path / "bad.spc"
    if content is None:
        src.write_bytes(small_file[: len(small_file) // 2])
    else:
        src.write_bytes(content)
    out_ply = tmp_path / "out.ply"
    code, out, err = run(capsys, "decode", str(src), "-o", str(out_ply))
    assert code != 0 and not out_ply.exists()
    assert err.count("\n") == 1 and err.startswith("spcodec: error:") and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.spc"]


def test_missing_input_and_unwritable_output(capsys, tmp_path, small_file):
    code, _, err = run(capsys, "info", str(tmp_path / "nope.spc"))
    assert code != 0 and "no such file" in err and err.count("\n") == 1
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    code, _, err = run(capsys, "decode", str(src), "-o", str(tmp_path / "no" / "dir" / "x.ply"))
    assert code == 2 and "does not exist" in err


def test_demo_runs_end_to_end(capsys, tmp_path):
    code, out, _ = run(capsys, "demo", "-o", str(tmp_path / "demo"))
    assert code == 0
    cloud = spcodec.decode(tmp_path / "demo" / "demo.spc")
    assert spcodec.read_ply(tmp_path / "demo" / "demo.ply").equals(cloud)
    assert "layer 0" in out


def test_console_script_entry_point(tmp_path):
    done = subprocess.run([sys.executable, "-m", "spcodec.cli", "info", str(tmp_path / "x.spc")],
                          capture_output=True, text=True)
    assert done.returncode == 1 and done.stderr.startswith("spcodec: error:")


def test_a_missing_extra_is_named_in_one_line():
    from spcodec.cli import describe_error
    message = describe_error(ModuleNotFoundError("No module named 'torch'", name="torch"))
    assert message == "this command needs 'torch': pip install 'spcodec[encoder]'"
    assert "zstd" in describe_error(ModuleNotFoundError("x", name="zstandard"))


def test_encoder_api_is_reachable_without_loading_heavy_modules_eagerly():
    code = ("import sys, spcodec.encoder, spcodec.encoder.cameras; "
            "assert 'sklearn' not in sys.modules and 'torch' not in sys.modules; "
            "from spcodec.encoder import encode, EncoderConfig; assert callable(encode)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
