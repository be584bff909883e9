"""The command line: outputs, one-line errors with non-zero exit codes, no partial files."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

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
    # `spcodec tile` runs its nodes on Dask (extra `tiling`), imported only once the nodes run
    for module in ("dask", "dask.distributed", "distributed"):
        assert describe_error(ModuleNotFoundError("x", name=module)) == \
            f"this command needs '{module}': pip install 'spcodec[tiling]'"


def test_encoder_api_is_reachable_without_loading_heavy_modules_eagerly():
    code = ("import sys, spcodec.encoder, spcodec.imaging.cameras; "
            "assert 'sklearn' not in sys.modules and 'torch' not in sys.modules; "
            "from spcodec.encoder import encode, EncoderConfig; assert callable(encode)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


# ------------------------------------------------------------------- outputs that cannot be written
def one_line_error(err: str) -> bool:
    return err.count("\n") == 1 and err.startswith("spcodec: error:") and "Traceback" not in err


def _forbid_work(monkeypatch) -> None:
    """Make every command's real work fail loudly, so an error proves it came first."""
    import spcodec.cli.scenes
    import spcodec.decoder
    import spcodec.ply

    def started(*args, **kwargs):
        raise AssertionError("the work started before the output was checked")

    monkeypatch.setattr(spcodec.decoder, "decode_layers", started)
    monkeypatch.setattr(spcodec.ply, "read_ply", started)
    monkeypatch.setattr(spcodec.cli.scenes, "load_model", started)


@pytest.mark.parametrize("argv, named", [
    (["decode", "{spc}", "-o", "/proc/x.ply"], "/proc/x.ply"),
    (["encode", "{ply}", "-o", "/proc/x.spc", "--no-retrain"], "/proc/x.spc"),
    (["encode", "{ply}", "-o", "{tmp}/x.spc", "--no-retrain", "--stats", "/proc/s.json"],
     "/proc/s.json"),
    (["render", "{ply}", "-o", "/proc/x.png"], "/proc/x.png"),
    (["eval", "{ply}", "--reference", "{ply}", "--save-renders", "/proc/renders"],
     "/proc/renders"),
])
def test_an_unwritable_output_fails_before_the_work_naming_the_users_path(
        capsys, tmp_path, monkeypatch, small_file, argv, named):
    """/proc refuses new files even to root, whom os.access lets through: only trying tells."""
    if not Path("/proc/self").is_dir():
        pytest.skip("needs Linux's /proc")  # pragma: no cover
    (tmp_path / "s.spc").write_bytes(small_file)
    spcodec.write_ply(tmp_path / "s.ply", spcodec.decode(small_file))
    _forbid_work(monkeypatch)
    code, out, err = run(capsys, *[a.format(spc=tmp_path / "s.spc", ply=tmp_path / "s.ply",
                                            tmp=tmp_path) for a in argv])
    assert code == 2 and one_line_error(err), err
    assert f"cannot write {named}" in err and ".part" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.ply", "s.spc"]


def test_a_failure_while_writing_names_the_users_path_and_leaves_nothing(tmp_path, monkeypatch):
    import errno

    from spcodec.fileio import atomic_write

    def full_disk(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("os.fsync", full_disk)
    with pytest.raises(OSError) as caught:
        atomic_write(tmp_path / "out.spc", b"data")
    assert caught.value.filename == str(tmp_path / "out.spc")
    assert caught.value.errno == errno.ENOSPC
    from spcodec.cli import describe_error
    assert describe_error(caught.value) == f"{tmp_path / 'out.spc'}: No space left on device"
    assert list(tmp_path.iterdir()) == []


def test_check_writable_folder_creates_nothing(tmp_path):
    from spcodec.fileio import check_writable_folder

    assert check_writable_folder(tmp_path / "a" / "b") == tmp_path / "a" / "b"
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_bytes(b"")
    with pytest.raises(spcodec.UsageError, match="not a folder"):
        check_writable_folder(tmp_path / "file" / "renders")


# ----------------------------------------------------------------------------- truncated files
def _cut(small_file: bytes, gzip: bool = False) -> tuple[bytes, list[int]]:
    """The file (gzip-wrapped when asked) and its inner layer ends."""
    data = small_file
    if gzip:
        from spcodec.synthetic import random_encoded_scene
        from spcodec.writer import WriteOptions, build_bitstream
        data = build_bitstream(random_encoded_scene(seed=7, clusters=4, patch_layers=2,
                                                    patch_size=150, sh_degree=3),
                               WriteOptions(gzip=True))
    ends = [layer.end_offset for layer in spcodec.decode_layers(data).header.layers]
    return data, ends


@pytest.mark.parametrize("stats, shown", [
    ({"prefix_psnr": [{"layer": 1, "psnr": 24.5}, {"layer": 2, "psnr": 30.25}]},
     {1: "24.50", 2: "30.25"}),
    ({"prefix_psnr": [{"layer": 1, "psnr": "24 dB"}, {"layer": 2.0, "psnr": 30},
                      {"layer": 2, "psnr": float("nan")}]}, {}),
    ({"prefix_psnr": "36 dB"}, {}),
    ("stats", {}),
])
def test_info_shows_what_the_encoder_measured_for_each_prefix(capsys, tmp_path, small_scene,
                                                               stats, shown):
    """A layer's line carries the prefix PSNR the metadata records for it; metadata is
    untrusted, so malformed entries are left out rather than failing the command."""
    import dataclasses

    from spcodec.writer import build_bitstream
    src = tmp_path / "scored.spc"
    src.write_bytes(build_bitstream(dataclasses.replace(
        small_scene, metadata={**small_scene.metadata, "stats": stats})))
    code, out, _ = run(capsys, "info", str(src))
    lines = {int(line.split()[0][1:]): line for line in out.splitlines()
             if line.startswith("  L")}
    assert code == 0 and len(lines) == 3
    for layer, line in lines.items():
        assert ("dB" in line) == (layer in shown), line
        if layer in shown:
            assert line.endswith(f"layers 0..{layer}: {shown[layer]} dB on the encoder's "
                                 "training views"), line


def test_info_says_which_layers_a_truncated_file_holds(capsys, tmp_path, small_file):
    data, ends = _cut(small_file)
    assert len(ends) == 3
    cases = {  # stored bytes -> (complete layers, truncated)
        len(data): (3, False),
        ends[1]: (2, False),          # a prefix at a layer boundary: valid, not truncated
        ends[1] + 10: (2, True),      # inside layer 2
        ends[0] - 1: (0, True),       # inside the sketch layer
    }
    for size, (complete, truncated) in cases.items():
        src = tmp_path / "cut.spc"
        src.write_bytes(data[:size])
        code, out, _ = run(capsys, "info", str(src), "--json")
        doc = json.loads(out)
        assert code == 0 and (doc["complete_layers"], doc["truncated"]) == (complete, truncated)
        assert doc["available_bytes"] == size and doc["stored_size"] == size
        assert [layer["complete"] for layer in doc["layers"]] == [k < complete for k in range(3)]
        assert [layer["end_offset"] for layer in doc["layers"]] == ends  # the old fields stay
        code, out, _ = run(capsys, "info", str(src))
        assert code == 0
        if truncated:
            assert f"TRUNCATED: the data ends inside layer {complete}" in out
            assert (f"--max-layer {complete - 1}" in out) == (complete > 0)
        elif complete < 3:
            assert "PREFIX" in out and f"layers 0..{complete - 1} are complete" in out
        else:
            assert "TRUNCATED" not in out and "PREFIX" not in out and "INCOMPLETE" not in out
        assert out.count("INCOMPLETE") == 3 - complete


def test_info_on_a_truncated_gzip_file_counts_inflated_bytes(capsys, tmp_path, small_file):
    data, ends = _cut(small_file, gzip=True)
    src = tmp_path / "cut.spc.gz"
    src.write_bytes(data[:-300])  # the last layer's compressed bytes and the trailer are gone
    code, out, _ = run(capsys, "info", str(src), "--json")
    doc = json.loads(out)
    available = len(spcodec.codecs.gunzip(data[:-300], 1 << 30).inner)
    assert code == 0 and doc["gzip"] and doc["available_bytes"] == available
    assert doc["complete_layers"] == sum(end <= available for end in ends) == 2
    assert doc["truncated"]


def test_a_truncated_file_error_suggests_the_complete_prefix(capsys, tmp_path, small_file):
    data, ends = _cut(small_file)
    src = tmp_path / "cut.spc"
    src.write_bytes(data[:ends[1] + 10])
    code, _, err = run(capsys, "decode", str(src), "-o", str(tmp_path / "out.ply"))
    assert code == 1 and one_line_error(err) and "[truncated]" in err
    assert "decode layers 0..1 with --max-layer 1" in err
    assert not (tmp_path / "out.ply").exists()
    code, _, _ = run(capsys, "decode", str(src), "-o", str(tmp_path / "out.ply"), "--max-layer", "1")
    assert code == 0 and len(spcodec.read_ply(tmp_path / "out.ply")) == \
        len(spcodec.decode(data, max_layer=1))
    src.write_bytes(data[:ends[0] - 1])  # nothing whole: nothing to suggest
    code, _, err = run(capsys, "decode", str(src), "-o", str(tmp_path / "out.ply"))
    assert code == 1 and "no layer is complete" in err and "--max-layer" not in err


def test_the_truncation_error_carries_the_complete_layer_count(small_file):
    data, ends = _cut(small_file)
    with pytest.raises(spcodec.TruncatedError) as caught:
        spcodec.decode(data[:ends[2] - 1])
    assert caught.value.complete_layers == 2
    dec = spcodec.StreamDecoder()
    dec.feed(data[:ends[1] + 5])
    with pytest.raises(spcodec.TruncatedError) as caught:
        dec.close()
    assert caught.value.complete_layers == 2


# ------------------------------------------------------------------------------ --help, ranges
def _subparsers():
    from spcodec.cli import build_parser
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return parser, action.choices


def test_help_gives_every_option_its_default_and_range():
    from spcodec.cli.options import Bounded
    parser, commands = _subparsers()
    assert {"decode", "info", "demo", "encode", "eval", "render"} <= commands.keys()
    for name, sub in [("spcodec", parser), *commands.items()]:
        text = sub.format_help()
        for action in sub._actions:
            if not action.option_strings or action.help == argparse.SUPPRESS or \
                    action.dest in ("help", "version"):
                continue
            shown = " ".join(action.help.split()).lower()
            assert action.required or "default" in shown or "required" in shown, \
                (name, action.dest, shown)
            if isinstance(action.type, Bounded):
                assert str(action.type) in " ".join(text.split()), (name, action.dest)


def _help(command: str) -> str:
    """``spcodec COMMAND --help`` as one line of single spaces (argparse wraps it)."""
    return " ".join(_subparsers()[1][command].format_help().split())


def _option_help(command: str, dest: str) -> str:
    """The help of one option of ``command``, as --help shows it (``%(type)s`` filled in)."""
    sub = _subparsers()[1][command]
    action = next(a for a in sub._actions if a.dest == dest)
    return " ".join(sub._get_formatter()._expand_help(action).split())


def test_help_shows_the_encoders_defaults():
    """--help reads its defaults from the encoder's configuration (no copies to keep equal):
    each configured value appears where the option's help names its default."""
    from spcodec.cli.encode import CHECKPOINT_EVERY
    from spcodec.encoder import config
    from spcodec.encoder.presets import PRESETS
    from spcodec.encoder.retraining.control import RunControl
    from spcodec.imaging.evaluate import EvalConfig
    from spcodec.imaging.render.settings import BLUR_VARIANCE

    text, retrain, patch = _help("encode"), config.RetrainConfig(), config.PatchConfig()
    for dest, value in [("iterations", retrain.iterations),
                        ("finish_iterations", retrain.finish_iterations),
                        ("views", retrain.views), ("close_views", retrain.close_views),
                        ("resolution", retrain.resolution), ("downscale", retrain.downscale),
                        ("nested_full_share", retrain.nested_full_share),
                        ("prune", retrain.prune),
                        ("checkpoint_every", RunControl().checkpoint_every)]:
        shown = _option_help("encode", dest)
        assert shown.endswith(f"(default: {value})"), (dest, shown)
    assert CHECKPOINT_EVERY == RunControl().checkpoint_every  # the one copy: retrain needs torch
    assert f"(default: {config.RETRAINED_PATCH_LAYERS} when retraining, {patch.layers} with " \
        "--no-retrain)" in text
    assert f"default: {config.RETRAINED_POSITION_BITS} of the scene's extent when retraining, " \
        f"{config.DEFAULT_POSITION_BITS} without, {PRESETS['transparent']['position_bits']} " \
        "for --preset transparent" in text
    assert f"(default: {config.VIEWER_BLUR_VARIANCE}, the viewer's, when distilling; " \
        f"{config.DATASET_BLUR_VARIANCE} with --dataset" in text
    assert "default: set by --preset: " + ", ".join(
        f"{name} {PRESETS[name]['retrain']['patch_downsample']:g}"
        for name in ("lowrate", "balanced", "highrate")) in text
    assert _option_help("eval", "blur_variance").endswith(
        f"(default: {EvalConfig().blur_variance})")
    assert EvalConfig().blur_variance == config.DATASET_BLUR_VARIANCE == \
        config.EncoderConfig().low_pass(dataset=True) == BLUR_VARIANCE
    assert config.VIEWER_BLUR_VARIANCE == config.EncoderConfig().low_pass(dataset=False)


def test_the_help_follows_a_changed_configuration(monkeypatch):
    """The defaults are read when the parser is built, not copied: change one, the help follows."""
    import dataclasses

    from spcodec.encoder import config

    defaults = config.RetrainConfig
    monkeypatch.setattr(config, "RETRAINED_PATCH_LAYERS", 9)
    monkeypatch.setattr(config, "RetrainConfig", lambda: dataclasses.replace(defaults(),
                                                                             iterations=1234))
    assert "(default: 9 when retraining" in _help("encode")
    assert _option_help("encode", "iterations").endswith("(default: 1234)")


def test_decode_and_info_never_load_the_encoders_heavy_modules(tmp_path, small_file):
    """The parser reads the encoder's configuration, which must stay light: a decode through the
    command line loads neither torch nor scikit-learn."""
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    code = ("import sys; from spcodec.cli import main; "
            f"assert main(['decode', {str(src)!r}, '-o', {str(tmp_path / 'o.ply')!r}]) == 0; "
            f"assert main(['info', {str(src)!r}]) == 0; "
            "heavy = sorted(m for m in ('torch', 'sklearn', 'scipy') if m in sys.modules); "
            "assert not heavy, heavy")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("argv, message", [
    (["render", "{spc}", "-o", "{tmp}/x.png", "--turntable", "0"],
     "argument --turntable: must be an integer in 1..64, got 0"),
    (["render", "{spc}", "-o", "{tmp}/x.png", "--view", "999"],
     "--view must be in 0..7 (the --views 8 sampled views), got 999"),
    (["render", "{spc}", "-o", "{tmp}/x.png", "--view", "-1"], "argument --view: must be"),
    (["render", "{spc}", "-o", "{tmp}/x.png", "--resolution", "4"], "an integer in 8..8192"),
    (["render", "{spc}", "-o", "{tmp}/x.png", "--up", "w"], "argument --up: invalid choice"),
    (["eval", "{spc}", "--reference", "{spc}", "--views", "x"], "expected an integer >= 1"),
    (["encode", "{spc}", "-o", "{tmp}/x.spc", "--no-retrain", "--tau-max", "nan"],
     "argument --tau-max: must be a number > 0"),
    (["encode", "{spc}", "-o", "{tmp}/x.spc", "--no-retrain", "--seed", "-1"], "--seed"),
    (["encode", "{spc}", "-o", "{tmp}/x.spc", "--blur-variance", "-0.1"],
     "argument --blur-variance: must be a number >= 0, got -0.1"),
    (["decode", "{spc}", "-o", "{tmp}/x.ply", "--max-layer", "-1"], "an integer >= 0"),
    (["decode", "{spc}"], "the following arguments are required: -o/--output"),
])
def test_bad_arguments_are_refused_up_front_in_one_line(capsys, tmp_path, monkeypatch, small_file,
                                                        argv, message):
    (tmp_path / "s.spc").write_bytes(small_file)
    _forbid_work(monkeypatch)
    code, out, err = run(capsys, *[a.format(spc=tmp_path / "s.spc", tmp=tmp_path) for a in argv])
    assert code == 2 and one_line_error(err) and message in err, err
    assert out == "" and sorted(p.name for p in tmp_path.iterdir()) == ["s.spc"]


def test_warnings_reach_the_command_line_as_one_line(capsys, monkeypatch):
    import warnings

    import spcodec.cli

    def handler(args):
        warnings.warn("something is off\nsecond line", UserWarning, stacklevel=1)
        return 0

    monkeypatch.setitem(spcodec.cli.COMMANDS, "info", ("x", spcodec.cli.COMMANDS["info"][1],
                                                       handler))
    code, _, err = run(capsys, "info", "x.spc")
    assert code == 0 and err == "spcodec: warning: something is off\n"


# ------------------------------------------------------------------- outputs are written, not replaced
def _spcodec(*argv, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "spcodec.cli", *map(str, argv)],
                          capture_output=True, **kwargs)


def test_dash_writes_the_ply_to_standard_output_and_the_report_to_stderr(tmp_path, small_file):
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    done = _spcodec("decode", src, "-o", "-")
    assert done.returncode == 0 and done.stdout.startswith(b"ply\n")
    assert b"decoded" in done.stderr and b"decoded" not in done.stdout
    import io
    assert spcodec.read_ply(io.BytesIO(done.stdout)).equals(spcodec.decode(small_file))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.spc"]


def test_devices_and_pipes_are_written_through_not_replaced(tmp_path, small_file):
    """-o /dev/stdout once turned the link into a regular file (as root); a FIFO is written to."""
    import os
    import threading

    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    link = tmp_path / "stdout"
    link.symlink_to("/dev/stdout")
    done = _spcodec("decode", src, "-o", link)
    assert done.returncode == 0 and link.is_symlink() and done.stdout.startswith(b"ply\n")
    assert b"decoded" in done.stderr  # the report does not go into the PLY
    assert _spcodec("decode", src, "-o", "/dev/null").returncode == 0
    assert Path("/dev/null").is_char_device()
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    got = {}
    reader = threading.Thread(target=lambda: got.setdefault("bytes", fifo.read_bytes()))
    reader.start()
    assert _spcodec("decode", src, "-o", fifo).returncode == 0
    reader.join(30)
    assert got["bytes"].startswith(b"ply\n") and fifo.is_fifo()


def test_a_link_to_a_file_stays_a_link(tmp_path, small_file):
    src, real = tmp_path / "s.spc", tmp_path / "real.ply"
    src.write_bytes(small_file)
    real.write_bytes(b"old")
    link = tmp_path / "link.ply"
    link.symlink_to(real)
    assert _spcodec("decode", src, "-o", link).returncode == 0
    assert link.is_symlink() and real.read_bytes().startswith(b"ply\n")


def test_output_equal_to_the_input_is_refused(tmp_path, capsys):
    from spcodec.synthetic import make_scene

    ply = tmp_path / "scene.ply"
    spcodec.write_ply(ply, make_scene(1, curves=1, per_curve=40, blobs=100).cloud)
    before = ply.read_bytes()
    alias = tmp_path / "alias.ply"
    alias.symlink_to(ply)
    for output in (ply, alias):
        code, _, err = run(capsys, "encode", str(ply), "-o", str(output), "--no-retrain")
        assert code != 0 and "is also the input" in err and err.count("\n") == 1
    assert ply.read_bytes() == before


def test_decode_refuses_names_of_formats_it_does_not_write(tmp_path, capsys, small_file):
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    for name in ("x.splat", "y.spc"):
        code, _, err = run(capsys, "decode", str(src), "-o", str(tmp_path / name))
        assert code == 2 and "decode writes a 3DGS PLY" in err and not (tmp_path / name).exists()


def test_an_spc_given_to_encode_is_named_for_what_it_is(tmp_path, capsys, small_file):
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    code, _, err = run(capsys, "encode", str(src), "-o", str(tmp_path / "o.spc"), "--no-retrain")
    assert code != 0 and "this is an .spc file, not a PLY" in err and "'ascii' codec" not in err


def test_a_reader_that_leaves_early_ends_the_command_quietly(tmp_path, small_file):
    """`spcodec info X.spc | head -1` printed 'error: Broken pipe' and exited 1."""
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    cli = f"{sys.executable} -m spcodec.cli"
    for command in (f"{cli} info {src} | head -1 >/dev/null",
                    f"{cli} decode {src} -o - | head -c 10 >/dev/null"):
        done = subprocess.run(["bash", "-c", command + "; echo ${PIPESTATUS[0]}"],
                              capture_output=True, text=True)
        assert "error" not in done.stderr and done.stdout.strip() in ("0", "141"), (command, done)


def test_bits_per_gaussian_count_the_gaussians_the_file_stores(tmp_path, capsys):
    from spcodec.synthetic import make_scene

    ply, out = tmp_path / "scene.ply", tmp_path / "o.spc"
    cloud = make_scene(2, curves=2, per_curve=60, blobs=600).cloud
    spcodec.write_ply(ply, cloud)
    full = len(cloud)
    code, report, _ = run(capsys, "encode", str(ply), "-o", str(out), "--no-retrain",
                          "--target-size", "8k", "--quiet")
    stored = len(spcodec.decode(out.read_bytes()))
    assert code == 0 and stored < full
    size = out.stat().st_size
    assert f"for {stored:,} Gaussians ({8 * size / stored:.1f} bits per Gaussian; {full:,} in " \
        "the input)" in report.splitlines()[0]


def _tiny_ply(tmp_path) -> Path:
    from spcodec.synthetic import make_scene

    ply = tmp_path / "scene.ply"
    spcodec.write_ply(ply, make_scene(1, curves=1, per_curve=40, blobs=150).cloud)
    return ply


def test_a_missing_gpu_is_reported_before_any_work(tmp_path, capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA: --device cuda is valid here")
    ply, out = _tiny_ply(tmp_path), tmp_path / "o.spc"
    code, report, err = run(capsys, "encode", str(ply), "-o", str(out), "--device", "cuda")
    assert code == 2 and err.count("\n") == 1 and "--device cuda" in err
    assert "internal error" not in err and "[1]" not in err and not out.exists()


def test_training_options_without_retraining_are_refused_not_ignored(tmp_path, capsys):
    ply, out = _tiny_ply(tmp_path), tmp_path / "o.spc"
    code, _, err = run(capsys, "encode", str(ply), "-o", str(out), "--no-retrain",
                       "--checkpoint-every", "5", "--downscale", "2")
    assert code == 2 and "--checkpoint-every, --downscale only apply to retraining" in err


def test_the_up_axis_is_stored_in_the_file(tmp_path, capsys):
    ply, out = _tiny_ply(tmp_path), tmp_path / "o.spc"
    assert run(capsys, "encode", str(ply), "-o", str(out), "--no-retrain", "--up=+z")[0] == 0
    assert spcodec.inspect(out).to_json()["metadata"]["up"] == "+z"


def test_an_encode_runs_one_torch_thread_unless_told(tmp_path):
    """On the busy 2-core machine the default thread count made retraining 4-8x slower than
    --threads 1: the encoder now takes one thread unless --threads says otherwise."""
    import torch

    from spcodec.cli import build_parser
    from spcodec.cli.encode import run_control

    before = torch.get_num_threads()
    try:
        parser = build_parser()
        for argv, threads in ((["--no-retrain"], 1), (["--threads", "2"], 2)):
            args = parser.parse_args(["encode", "in.ply", "-o", str(tmp_path / "o.spc"), *argv])
            run_control(args, retraining=not args.no_retrain)
            assert torch.get_num_threads() == threads
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("command", ["render", "eval"])
def test_render_and_eval_run_one_torch_thread_unless_told(capsys, tmp_path, small_file, command,
                                                           monkeypatch):
    """Two threads (torch's default here) made eval 4x slower than one on the busy 2-core
    machine: render and eval take --threads as encode does, and one thread unless told."""
    import torch

    spc = tmp_path / "s.spc"
    spc.write_bytes(small_file)
    asked = []
    monkeypatch.setattr(torch, "set_num_threads", asked.append)
    tail = ["-o", str(tmp_path / "r.png")] if command == "render" else \
        ["--reference", str(spc), "--closeup-resolution", "16", "--quiet", "--no-cache"]
    for extra in ([], ["--threads", "3"]):
        assert run(capsys, command, str(spc), *tail, "--resolution", "16", *extra)[0] == 0
    assert asked[-2:] == [1, 3]
