"""The no-retrain encoder end to end: structure recovered, determinism, bad inputs, real scenes."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import spcodec
from spcodec.cli import main
from spcodec.cloud import GaussianCloud
from spcodec.encoder.config import EncoderConfig, PatchConfig
from spcodec.encoder.pipeline import encode
from spcodec.encoder.ratecontrol import FIT_SLACK
from spcodec.errors import FormatError, UsageError
from spcodec.synthetic import make_scene

from conftest import real_file

FAST = EncoderConfig(patch=PatchConfig(kmeans_iterations=10, kmeans_samples=20_000))


def sketch_mask(result, n: int) -> np.ndarray:
    mask = np.zeros(n, bool)
    mask[result.source_index[:result.stats.sketch_gaussians]] = True
    return mask


@pytest.mark.parametrize("seed", [0, 1])
def test_structured_gaussians_become_sketch(seed):
    scene = make_scene(seed)
    # structure recovery itself, without the cap on the sketch layer's share of the file (the
    # synthetic curves are 60 % of the Gaussians and would fill half the file)
    result = encode(scene.cloud, dataclasses.replace(FAST, max_sketch_share=None))
    sketch = sketch_mask(result, len(scene.cloud))
    true_pos = (sketch & scene.structured).sum()
    assert true_pos / sketch.sum() >= 0.9, "precision"
    assert true_pos / scene.structured.sum() >= 0.9, "recall"


def test_every_gaussian_is_encoded_exactly_once_and_decodes():
    scene = make_scene(3, blobs=1500)
    result = encode(scene.cloud, FAST)
    assert np.array_equal(np.sort(result.source_index), np.arange(len(scene.cloud)))
    decoded = spcodec.decode(result.data)
    assert len(decoded) == len(scene.cloud) and decoded.is_finite()
    # Patch Gaussians keep their positions to within half a QUANT16 step.
    k = result.stats.sketch_gaussians
    patch_src = result.source_index[k:]
    err = np.abs(decoded.means[k:] - scene.cloud.means[patch_src]).max()
    assert err < 1e-4
    # Sketch models meet the error the refinement promised, as measured on decoded Gaussians.
    error = result.stats.sketch_error
    assert error["position_rel_diameter"]["mean"] <= FAST.sketch.position_error * 1.2
    assert error["color_dc_abs"]["mean"] < 0.05


def test_encode_is_deterministic_for_a_seed():
    scene = make_scene(4, curves=6, blobs=800)
    a = encode(scene.cloud, FAST).data
    b = encode(scene.cloud, FAST).data
    assert a == b
    c = encode(scene.cloud, dataclasses.replace(FAST, seed=5)).data
    assert spcodec.decode(c).sh_degree == 3


def test_scene_without_structure_is_all_patch_and_valid():
    rng = np.random.default_rng(0)
    blobs = make_scene(0, curves=0, blobs=3000).cloud
    assert len(blobs) == 3000
    result = encode(blobs, FAST)
    assert result.stats.sketch_gaussians == 0
    info = spcodec.inspect(result.data).to_json()
    assert info["layers"][0]["gaussians"] == 0 and len(spcodec.decode(result.data)) == 3000
    tiny = blobs.subset(rng.choice(3000, 5, replace=False))
    assert len(spcodec.decode(encode(tiny, FAST).data)) == 5


def test_the_sketch_layer_is_capped_to_its_share_of_the_file():
    """The first picture of a streaming viewer comes after at most max_sketch_share of the bytes:
    sketch clusters of least importance go to the patch until it does."""
    scene = make_scene(5, curves=16, per_curve=300, blobs=1200)
    free = encode(scene.cloud, dataclasses.replace(FAST, max_sketch_share=None))
    capped = encode(scene.cloud, dataclasses.replace(FAST, max_sketch_share=0.1))

    def first_share(result) -> float:
        return result.stats.layer_ends[0] / result.stats.bytes

    assert first_share(free) > 0.15 and free.stats.sketch.moved_to_patch_for_share == 0
    assert 0.0 < first_share(capped) <= 0.1
    moved = capped.stats.sketch.moved_to_patch_for_share
    assert moved > 0 and capped.stats.sketch_gaussians <= free.stats.sketch_gaussians - moved
    assert len(spcodec.decode(capped.data)) == len(scene.cloud)
    assert np.array_equal(np.sort(capped.source_index), np.arange(len(scene.cloud)))



def test_a_target_size_caps_the_sketch_to_its_share_of_the_target():
    """Rate control makes the file the target's size whatever the sketch keeps, so the cap is
    judged against the target: left alone, a small target would be mostly sketch."""
    scene = make_scene(5, curves=16, per_curve=300, blobs=1200)
    target = len(encode(scene.cloud, FAST).data) // 2
    free = encode(scene.cloud, dataclasses.replace(FAST, max_sketch_share=None, target_size=target))
    capped = encode(scene.cloud, dataclasses.replace(FAST, max_sketch_share=0.1, target_size=target))
    assert free.stats.layer_ends[0] > 0.3 * target
    assert 0.0 < capped.stats.layer_ends[0] <= 0.1 * target
    assert capped.stats.sketch.moved_to_patch_for_share > 0
    assert target * (1 - FIT_SLACK) <= len(capped.data) <= target
    assert len(spcodec.decode(capped.data)) < len(scene.cloud)  # pruned to fit, sketch and all


@pytest.mark.parametrize("sh_degree", [0, 1, 2])
def test_every_sh_degree_encodes(sh_degree):
    scene = make_scene(6, curves=4, per_curve=200, blobs=500, sh_degree=sh_degree)
    decoded = spcodec.decode(encode(scene.cloud, FAST).data)
    assert decoded.sh_degree == sh_degree and len(decoded) == len(scene.cloud)


def test_bad_inputs_get_one_line_errors():
    cloud = make_scene(0, curves=2, blobs=100).cloud
    bad = cloud.subset(slice(None))
    bad.scales[3, 1] = np.nan
    with pytest.raises(FormatError, match="NaN or infinite scales"):
        encode(bad, FAST)
    bad = cloud.subset(slice(None))
    bad.means[0, 0] = np.inf
    with pytest.raises(FormatError, match="means"):
        encode(bad, FAST)
    with pytest.raises(UsageError, match="no Gaussians"):
        encode(GaussianCloud.empty(), FAST)
    with pytest.raises(UsageError, match="codec"):
        encode(cloud, dataclasses.replace(FAST, codec="lzma"))


def test_cli_encode(tmp_path, capsys):
    scene = make_scene(2, curves=4, per_curve=200, blobs=600)
    ply = tmp_path / "in.ply"
    spcodec.write_ply(ply, scene.cloud)
    out, stats = tmp_path / "out.spc", tmp_path / "stats.json"
    code = main(["encode", str(ply), "-o", str(out), "--no-retrain", "--quiet", "--stats",
                 str(stats), "--codec", "zstd", "--gzip", "--patch-layers", "2"])
    printed = capsys.readouterr().out
    assert code == 0 and "ratio vs input PLY" in printed and "sketch:" in printed
    assert len(spcodec.decode(out)) == len(scene.cloud)
    doc = json.loads(stats.read_text())
    assert doc["gaussians"] == len(scene.cloud) and doc["patch_layers"] == 2
    assert spcodec.inspect(out).to_json()["gzip"]


@pytest.mark.parametrize("argv, message", [
    (["--no-retrain", "-o", "{tmp}/x.spc"], None),
    (["--no-retrain", "--iterations", "5"], "only apply to retraining"),
    (["--preset", "transparent", "--iterations", "5"],
     "drop --preset transparent (it never retrains) or them"),
    (["--preset", "transparent", "--patch-downsample", "2"], "need retraining"),
    (["--no-retrain", "--position-bits", "40"], "an integer in 8..30"),
    (["--no-retrain", "-o", "{tmp}/missing/x.spc"], "does not exist"),
])
def test_cli_encode_errors(tmp_path, capsys, argv, message):
    ply = tmp_path / "in.ply"
    if message is None:  # a PLY without the 3DGS properties
        ply.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n")
        message = "lacks the 3DGS properties"
    else:
        spcodec.write_ply(ply, make_scene(0, curves=1, blobs=50).cloud)
    args = [a.format(tmp=tmp_path) for a in argv]
    if "-o" not in args:
        args += ["-o", str(tmp_path / "x.spc")]
    code = main(["encode", str(ply), *args])
    err = capsys.readouterr().err
    assert code != 0 and message in err and err.count("\n") == 1
    assert not (tmp_path / "x.spc").exists()


@pytest.mark.slow  # real scenes: 3-8 s each
@pytest.mark.parametrize("scene", ["pdal_fourth_st_spz/fourth_st_inria.ply",
                                   "playcanvas_biker_guitar/biker_from_spz_inria.ply",
                                   "v3dg_donut_mipsplatting/fused.ply"])
def test_real_scene_encode_decode(scene):
    cloud = spcodec.read_ply(real_file(scene))
    result = encode(cloud, FAST)
    decoded = spcodec.decode(result.data)
    assert len(decoded) == len(cloud) and decoded.is_finite()
    assert np.array_equal(np.sort(result.source_index), np.arange(len(cloud)))
    assert result.stats.bytes < cloud.nbytes() / 5
    for layer in spcodec.inspect(result.data).to_json()["layers"]:  # every prefix decodes
        assert len(spcodec.decode(result.data[:layer["end_offset"]])) > 0 or layer["index"] == 0


def test_defaults_are_the_balanced_preset_and_presets_order_by_size():
    from spcodec.encoder.presets import PRESETS, preset_config
    default, balanced = EncoderConfig(), preset_config("balanced")
    assert default.patch.entry_dims == balanced.patch.entry_dims
    assert default.refine.tau_max == balanced.refine.tau_max
    scene = make_scene(8, curves=4, per_curve=200, blobs=1500)
    sizes = {name: len(encode(scene.cloud, preset_config(name, FAST)).data) for name in PRESETS}
    assert sizes["lowrate"] < sizes["balanced"] < sizes["highrate"] < sizes["transparent"]
    with pytest.raises(ValueError, match="unknown preset"):
        preset_config("ultra")


def test_transparent_keeps_every_gaussian_as_patch_with_scalar_codebooks(tmp_path, capsys):
    """The near-lossless point: no sketch, no pruning, one 256-level codebook per component;
    it never retrains, and the command line says so instead of training."""
    from spcodec.encoder.presets import preset_config
    scene = make_scene(9, curves=3, per_curve=150, blobs=800)
    config = preset_config("transparent", FAST)
    assert set(config.patch.entry_dims.values()) == {1} and not config.use_sketch
    assert config.patch.position_bits == 14
    result = encode(scene.cloud, config)
    decoded = spcodec.decode(result.data)
    assert result.stats.sketch_gaussians == 0 and len(decoded) == len(scene.cloud)
    order = result.source_index
    assert np.abs(decoded.opacities - scene.cloud.opacities[order]).max() < 0.05
    with pytest.raises(ValueError, match="never retrains"):
        preset_config("transparent", retrain=True)
    ply, out = tmp_path / "in.ply", tmp_path / "out.spc"
    spcodec.write_ply(ply, scene.cloud)
    assert main(["encode", str(ply), "-o", str(out), "--preset", "transparent", "--quiet"]) == 0
    assert len(spcodec.decode(out)) == len(scene.cloud)


def test_rate_control_without_retraining_renders_no_training_targets():
    """`--no-retrain --target-size` took 8-10 minutes on kacytran: it rendered 48 distillation
    targets that only retraining uses."""
    scene = make_scene(3, blobs=1500).cloud
    result = encode(scene, dataclasses.replace(FAST, target_size=30_000))
    assert "targets" not in result.stats.seconds and result.stats.psnr_input is None
    assert 30_000 * (1 - FIT_SLACK) <= len(result.data) <= 30_000


def test_a_scene_that_is_all_one_sketch_curve_encodes():
    """Every Gaussian on one curve: a trial of the file leaves the patch empty, whose SH columns
    once failed to reshape (a tileset's small nodes met it); the file keeps every Gaussian."""
    scene = make_scene(0, curves=1, per_curve=50, blobs=0, sh_degree=1).cloud
    result = encode(scene)
    assert len(spcodec.decode(result.data)) == len(scene) == 50
