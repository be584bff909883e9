"""Scene files of other tools (spcodec.formats): each reader against small files written by that
format's own tool (tests/data/formats, see its README), detection by content, the SPZ and .splat
writers, one-line errors for damaged files, the CLI hooks, and the real files of the data folder."""

from __future__ import annotations

import gzip
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from spcodec.cli import main
from spcodec.cloud import GaussianCloud
from spcodec.errors import FormatError
from spcodec.formats import detect, read_scene, spz
from spcodec.formats import splat as splat_format
from spcodec.ply import read_ply, write_ply

from conftest import real_file

FIXTURES = Path(__file__).resolve().parent / "data" / "formats"
SOURCE = FIXTURES / "tiny_sh3.ply"  # what every fixture was made from


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def matched(cloud: GaussianCloud, reference: GaussianCloud) -> GaussianCloud:
    """``reference`` reordered to ``cloud`` by nearest centre (SOG, .splat and .ksplat writers
    reorder the Gaussians)."""
    d = ((cloud.means[:, None].astype(np.float64) - reference.means[None]) ** 2).sum(-1)
    idx = d.argmin(axis=1)
    assert len(np.unique(idx)) == len(cloud)
    return reference.subset(idx)


def assert_close(cloud, reference, *, means, scales, dot, alpha, dc, rest, degree=None):
    assert len(cloud) == len(reference)
    np.testing.assert_allclose(cloud.means, reference.means, atol=means, rtol=0)
    np.testing.assert_allclose(cloud.scales, reference.scales, atol=scales, rtol=0)
    qa = cloud.quats / np.linalg.norm(cloud.quats, axis=1, keepdims=True)
    qb = reference.quats / np.linalg.norm(reference.quats, axis=1, keepdims=True)
    assert np.abs((qa * qb).sum(axis=1)).min() >= dot
    sig = lambda x: 1 / (1 + np.exp(-x.astype(np.float64)))  # noqa: E731
    np.testing.assert_allclose(sig(cloud.opacities), sig(reference.opacities), atol=alpha, rtol=0)
    np.testing.assert_allclose(cloud.sh_dc, reference.sh_dc, atol=dc, rtol=0)
    k = cloud.sh_rest.shape[1]
    if degree is not None:
        assert cloud.sh_degree == degree
    if rest is not None and k:
        np.testing.assert_allclose(cloud.sh_rest, reference.sh_rest[:, :k], atol=rest, rtol=0)


def same_scene(a: GaussianCloud, b: GaussianCloud, quat_dot: float = 1 - 1e-6) -> bool:
    """Equal arrays, with quaternions equal up to sign (q and -q are one rotation)."""
    if len(a) != len(b) or a.sh_degree != b.sh_degree:
        return False
    arrays_b = b.arrays()
    if not all(np.array_equal(v, arrays_b[k]) for k, v in a.arrays().items() if k != "quats"):
        return False
    qa = a.quats / np.linalg.norm(a.quats, axis=1, keepdims=True)
    qb = b.quats / np.linalg.norm(b.quats, axis=1, keepdims=True)
    return bool(np.abs((qa * qb).sum(axis=1)).min() >= quat_dot)


@pytest.fixture(scope="module")
def source() -> GaussianCloud:
    return read_ply(SOURCE)


# ------------------------------------------------------------ readers vs the tools' own files
@pytest.mark.parametrize("name", ["tiny_sh3.v3.spz", "tiny_sh3.v4.spz"])
def test_spz_written_by_splat_transform_decodes_to_the_source(name, source):
    cloud = read_scene(FIXTURES / name)
    # SPZ keeps the order; the tolerances are its quantization steps (positions 1/4096, log-scales
    # 1/16, colour 1/(255*0.15), SH 4-5 bits, quaternion 9 bits, alpha 1/255)
    assert_close(cloud, source, means=0.5 / 4096 + 1e-6, scales=1 / 32 + 1e-6, dot=0.9999,
                 alpha=0.5 / 255 + 1e-6, dc=0.5 / (255 * 0.15) + 1e-5, rest=0.07, degree=3)


def test_splat_written_by_convert_py_decodes_to_the_source(source):
    cloud = read_scene(FIXTURES / "tiny_sh3.splat")
    # convert.py truncates colour and quaternion bytes, so up to a whole step off
    assert_close(cloud, matched(cloud, source), means=0, scales=1e-6, dot=0.999,
                 alpha=1 / 255 + 1e-6, dc=1 / (255 * 0.2820948) + 1e-5, rest=None, degree=0)


def test_sog_written_by_splat_transform_decodes_to_the_source(source):
    cloud = read_scene(FIXTURES / "tiny_sh1.sog")
    assert_close(cloud, matched(cloud, source), means=2e-3, scales=0.05, dot=0.999,
                 alpha=1 / 255 + 1e-6, dc=0.02, rest=0.02, degree=1)


@pytest.mark.parametrize("mode", [0, 1, 2])
def test_ksplat_written_by_gaussian_splats_3d_decodes_to_the_source(mode, source):
    cloud = read_scene(FIXTURES / f"tiny_sh3.mode{mode}.ksplat")
    # GaussianSplats3D keeps SH degree <= 2; modes 1-2 store float16 and bucket-relative centres
    assert_close(cloud, matched(cloud, source), means=1e-4, scales=2e-3 if mode else 1e-6,
                 dot=0.9999, alpha=1 / 255 + 1e-6, dc=1 / (255 * 0.2820948) + 1e-5,
                 rest=[1e-6, 2e-3, 0.01][mode], degree=2)


def test_an_unbundled_sog_folder_reads_like_the_bundle(tmp_path):
    with zipfile.ZipFile(FIXTURES / "tiny_sh1.sog") as z:
        z.extractall(tmp_path / "scene")
    bundled = read_scene(FIXTURES / "tiny_sh1.sog")
    for path in (tmp_path / "scene", tmp_path / "scene" / "meta.json"):
        assert detect(path).key == "sog"
        assert read_scene(path).equals(bundled)


# ---------------------------------------------------------------------- detection by content
@pytest.mark.parametrize("name,key", [
    ("tiny_sh3.v3.spz", "spz"), ("tiny_sh3.v4.spz", "spz"), ("tiny_sh3.splat", "splat"),
    ("tiny_sh1.sog", "sog"), ("tiny_sh3.mode0.ksplat", "ksplat"),
    ("tiny_sh3.mode2.ksplat", "ksplat"), ("tiny_sh3.ply", "ply")])
def test_formats_are_recognized_by_content_not_by_name(tmp_path, name, key):
    misnamed = tmp_path / "scene.ply" if key != "ply" else tmp_path / "scene.splat"
    shutil.copy(FIXTURES / name, misnamed)
    assert detect(misnamed).key == key
    assert len(read_scene(misnamed)) == 32


def test_a_gzip_wrapped_spz_is_no_spc_and_a_gzip_spc_no_spz(tmp_path, small_file):
    from spcodec.cli.scenes import is_spc

    assert not is_spc(str(FIXTURES / "tiny_sh3.v3.spz"))
    wrapped = tmp_path / "s.spc"
    wrapped.write_bytes(gzip.compress(small_file))
    assert is_spc(str(wrapped)) and detect(wrapped).key == "spc"


def test_the_splat_sniffer_refuses_what_is_not_splats(tmp_path):
    rng = np.random.default_rng(0)
    noise = tmp_path / "noise.bin"
    noise.write_bytes(rng.integers(0, 256, 32 * 64, dtype=np.uint8).tobytes())
    zeros = tmp_path / "zeros.bin"
    zeros.write_bytes(bytes(32 * 64))
    odd = tmp_path / "odd.splat"
    odd.write_bytes((FIXTURES / "tiny_sh3.splat").read_bytes()[:-1])
    for path in (noise, zeros, odd):
        assert detect(path) is None


# --------------------------------------------------------------------------------- writers
@pytest.mark.parametrize("version", [2, 3, 4])
def test_spz_writer_round_trips_and_matches_the_reference_writer(tmp_path, source, version):
    path = tmp_path / "x.spz"
    spz.write(path, source, version=version)
    cloud = read_scene(path)
    assert_close(cloud, source, means=0.5 / 4096 + 1e-6, scales=1 / 32 + 1e-6,
                 dot=0.999 if version == 2 else 0.9999, alpha=0.5 / 255 + 1e-6,
                 dc=0.5 / (255 * 0.15) + 1e-5, rest=0.07, degree=3)
    again = tmp_path / "y.spz"
    spz.write(again, cloud, version=version)  # decoded values re-encode to themselves
    assert same_scene(read_scene(again), cloud)
    if version >= 3:  # same bytes, so the same decode, as splat-transform's writer
        assert cloud.equals(read_scene(FIXTURES / f"tiny_sh3.v{version}.spz"))


def test_spz_writer_narrows_fixed_point_for_large_scenes(tmp_path, source):
    big = GaussianCloud(**dict(source.arrays(), means=source.means * 5000))
    spz.write(tmp_path / "big.spz", big)
    back = read_scene(tmp_path / "big.spz")
    assert np.abs(back.means - big.means).max() < 0.01 * 5000


def test_splat_writer_is_byte_identical_to_convert_py(source):
    assert splat_format.splat_bytes(source) == (FIXTURES / "tiny_sh3.splat").read_bytes()


# -------------------------------------------------------------------------- damaged inputs
def _damaged(tmp_path) -> dict[str, Path]:
    out = {}
    for name, cut in (("tiny_sh3.v3.spz", 200), ("tiny_sh3.v4.spz", 300), ("tiny_sh1.sog", 3000),
                      ("tiny_sh3.mode1.ksplat", 6000)):
        path = tmp_path / f"cut_{name}"
        path.write_bytes((FIXTURES / name).read_bytes()[:cut])
        out[name] = path
    flipped = bytearray((FIXTURES / "tiny_sh3.v4.spz").read_bytes())
    flipped[200:260] = bytes(60)
    out["zeroed v4"] = tmp_path / "zeroed.spz"
    out["zeroed v4"].write_bytes(bytes(flipped))
    out["text"] = tmp_path / "notes.ply"
    out["text"].write_text("hello\n")
    out["png"] = tmp_path / "x.spz"
    out["png"].write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    out["empty"] = tmp_path / "empty.splat"
    out["empty"].write_bytes(b"")
    return out


def test_damaged_files_are_one_line_format_errors(tmp_path):
    for label, path in _damaged(tmp_path).items():
        with pytest.raises(FormatError) as info:
            read_scene(path)
        assert "\n" not in str(info.value), label
    with pytest.raises(FormatError, match="looks like a PNG image"):
        read_scene(tmp_path / "x.spz")
    with pytest.raises(FormatError, match="looks like text"):
        read_scene(tmp_path / "notes.ply")


def test_the_cli_names_damaged_inputs_in_one_line(tmp_path, capsys):
    for label, path in _damaged(tmp_path).items():
        code, _, err = run(capsys, "encode", path, "-o", tmp_path / "o.spc", "--no-retrain")
        assert code != 0 and err.count("\n") == 1 and "Traceback" not in err, (label, err)
        assert "internal error" not in err, (label, err)


# ---------------------------------------------------------------------------------- the CLI
def test_encode_eval_render_decode_take_other_formats(tmp_path, capsys):
    splat = FIXTURES / "tiny_sh3.splat"
    out = tmp_path / "y.spc"
    code, _, err = run(capsys, "encode", splat, "-o", out, "--no-retrain", "--quiet")
    assert code == 0, err
    code, text, err = run(capsys, "eval", out, "--reference", splat, "--views", "1",
                          "--resolution", "32", "--closeups", "none", "--device", "cpu")
    assert code == 0 and "PSNR" in text, err
    code, _, err = run(capsys, "render", FIXTURES / "tiny_sh3.v4.spz", "-o", tmp_path / "v.png",
                       "--resolution", "32", "--device", "cpu")
    assert code == 0 and (tmp_path / "v.png").exists(), err
    code, _, err = run(capsys, "decode", out, "-o", tmp_path / "z.spz")
    assert code == 0, err
    assert detect(tmp_path / "z.spz").key == "spz" and len(read_scene(tmp_path / "z.spz")) == 32
    code, text, _ = run(capsys, "info", FIXTURES / "tiny_sh3.v4.spz")
    assert code == 0 and "SPZ v4" in text and "32 Gaussians" in text


def test_encode_names_an_spc_input_for_what_it_is(tmp_path, capsys, small_file):
    src = tmp_path / "s.data"
    src.write_bytes(small_file)
    code, _, err = run(capsys, "encode", src, "-o", tmp_path / "o.spc", "--no-retrain")
    assert code != 0 and "this is an .spc file" in err and "decode it first" in err


# --------------------------------------------------------------------------- real files
def test_real_spz_v2_matches_its_ply_conversion(tmp_path):
    cloud = read_scene(real_file("pdal_fourth_st_spz/fourth_st.spz"))
    reference = read_ply(real_file("pdal_fourth_st_spz/fourth_st_inria.ply"))
    assert_close(cloud, reference, means=1e-6, scales=1e-6, dot=0.999999, alpha=1e-6, dc=1e-5,
                 rest=1e-6, degree=3)
    spz.write(tmp_path / "again.spz", cloud, version=2)  # re-encoding loses nothing more
    assert same_scene(read_scene(tmp_path / "again.spz"), cloud, quat_dot=0.9999)


def test_real_spz_v4_matches_its_ply_conversion():
    cloud = read_scene(real_file("playcanvas_biker_guitar/biker.spz"))
    reference = read_ply(real_file("playcanvas_biker_guitar/biker_from_spz_inria.ply"))
    assert_close(cloud, reference, means=1e-6, scales=1e-6, dot=0.999999, alpha=1e-6, dc=1e-5,
                 rest=None, degree=0)


def test_real_splat_reads_and_round_trips(tmp_path):
    path = real_file("kacytran_try_sh3/model_1.splat")
    assert detect(path).key == "splat"
    cloud = read_scene(path)
    assert len(cloud) == path.stat().st_size // 32 == 22764
    assert np.isfinite(cloud.means).all() and np.isfinite(cloud.scales).all()
    # the same region as the PLY of an earlier iteration of that scene
    ply = read_ply(real_file("kacytran_try_sh3/point_cloud_iteration_7000.ply"))
    assert np.allclose(np.median(cloud.means, axis=0), np.median(ply.means, axis=0),
                       atol=0.2 * np.ptp(ply.means, axis=0).max())
    write_ply(tmp_path / "x.ply", cloud)
    assert read_scene(tmp_path / "x.ply").equals(cloud)
