"""Nested retraining (encoder/retraining/nested.py): layers fixed before training, every step training one
layer prefix, and the layers kept as trained by rate control and the writer."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import spcodec
from spcodec.cli import build_parser, main
from spcodec.cli.encode import encode_config
from spcodec.encoder.config import (
    RETRAINED_MAX_SKETCH_SHARE,
    RETRAINED_PATCH_LAYERS,
    EncoderConfig,
    PatchConfig,
    RetrainConfig,
    geometric_fractions,
)
from spcodec.encoder.pipeline import encode
from spcodec.encoder.retraining.nested import NestedEncoder, layer_priority, layers_of, prefix_schedule
from spcodec.synthetic import make_scene

QUICK = RetrainConfig(iterations=45, finish_iterations=10, views=8, resolution=64,
                      importance_views=8, patch_downsample=3.0, close_views=4,
                      close_resolution=128, close_crop=48, nested=True)

pytestmark = pytest.mark.usefixtures("single_torch_thread")


@pytest.fixture(scope="module")
def scene():
    return make_scene(5, curves=4, per_curve=150, blobs=900, sh_degree=1).cloud


# ------------------------------------------------------------------------ the layer score
@given(st.lists(st.tuples(st.floats(0, 1e6), st.integers(0, 9)), min_size=1, max_size=60),
       st.integers(0, 5))
def test_the_priority_keeps_each_layer_and_orders_layers_first(rows, spare):
    importance = np.array([r[0] for r in rows])
    layer_of = np.array([r[1] for r in rows])
    layers = int(layer_of.max()) + 1 + spare
    priority = layer_priority(importance, layer_of, layers)
    assert np.array_equal(layers_of(priority, layers), layer_of)
    order = np.argsort(-priority, kind="stable")
    assert np.all(np.diff(layer_of[order]) >= 0)  # earlier layers first, whole
    same = layer_of[:, None] == layer_of[None, :]  # within a layer, never against importance
    more = importance[:, None] > importance[None, :]
    first, second = np.broadcast_arrays(priority[:, None], priority[None, :])
    assert np.all(first[same & more] >= second[same & more])


@given(st.integers(1, 12), st.floats(0.5, 3.0))
def test_geometric_layers_grow_by_one_ratio_and_fill_the_patch(layers, ratio):
    shares = geometric_fractions(layers, ratio)
    assert len(shares) == layers and abs(sum(shares) - 1) < 1e-12
    assert np.allclose(np.divide(shares[1:], shares[:-1]), ratio)


@given(st.lists(st.integers(0, 50), min_size=1, max_size=8), st.integers(0, 2**32 - 1),
       st.floats(0, 1))
def test_the_schedule_draws_a_shorter_prefix_or_the_whole_file(sizes, seed, share):
    ends = np.cumsum(sizes).tolist()
    visible = prefix_schedule(ends, seed, share)
    shorter = {e for e in ends[:-1] if 0 < e < ends[-1]}
    drawn = [visible(step) for step in range(200)]
    assert drawn == [visible(step) for step in range(200)]  # seeded per step: resumable
    assert all(d is None or d in shorter for d in drawn)
    if not shorter:
        assert all(d is None for d in drawn)
    elif share == 0:
        assert None not in drawn
    elif share == 1:
        assert set(drawn) == {None}


def test_half_the_steps_train_the_whole_file_and_every_shorter_prefix_gets_its_turn():
    visible = prefix_schedule([10, 30, 60, 100], seed=2, full_share=0.5)
    drawn = [visible(step) for step in range(4000)]
    assert 0.45 < drawn.count(None) / len(drawn) < 0.55
    for end in (10, 30, 60):
        assert 0.13 < drawn.count(end) / len(drawn) < 0.20


def test_the_nested_encoder_stores_the_layers_the_priority_names(scene):
    from spcodec.encoder.patch import PatchEncoder

    cloud = scene.subset(np.arange(300))
    config = PatchConfig(layers=4)
    quantized = PatchEncoder(config, seed=1).quantize(cloud)
    rng = np.random.default_rng(5)
    layer_of = rng.integers(0, 3, len(cloud))  # layer 3 stays empty
    priority = layer_priority(rng.random(len(cloud)), layer_of, 4)
    encoding = NestedEncoder(config, seed=1).layer(cloud, quantized, priority)
    assert len(encoding.layers) == 4
    for k, order in enumerate(encoding.order):
        assert sorted(order.tolist()) == np.flatnonzero(layer_of == k).tolist()
    with pytest.raises(ValueError, match="layer the configuration does not have"):
        NestedEncoder(PatchConfig(layers=2), seed=1).layer(cloud, quantized, priority)


# ------------------------------------------------------------------------ end to end
def test_a_training_step_renders_only_the_prefix_it_draws(scene):
    import torch

    from spcodec.imaging.render import RenderSettings
    from spcodec.imaging.training.loop import FitLoop
    from spcodec.imaging.training.optim import FreeGaussians
    from spcodec.imaging.training.targets import distillation_targets
    from spcodec.imaging.views import sample_views

    cloud = scene.subset(np.arange(200))
    settings = RenderSettings()
    targets = distillation_targets(cloud, sample_views(cloud, 2, resolution=(32, 32)), settings,
                                   torch.device("cpu"))
    model = FreeGaussians(cloud, torch.device("cpu"), QUICK.rates, targets.extent)
    before = [t.detach().clone() for t in model.params().tensors()]
    FitLoop(model, targets, settings, 1, visible=lambda step: 50).run()
    after = model.params().tensors()
    for old, new in zip(before, after):
        assert torch.equal(old[50:], new[50:])  # outside the prefix: no gradient, no step
    assert any(not torch.equal(old[:50], new[:50]) for old, new in zip(before, after))


@pytest.mark.training
def test_a_nested_encode_stores_the_layers_fixed_before_training(scene):
    from spcodec.encoder.patch import split_layers

    config = EncoderConfig(seed=3, retrain=QUICK, max_sketch_share=None)
    result = encode(scene, config)
    stored = [layer["gaussians"] for layer in spcodec.inspect(result.data).to_json()["layers"][1:]]
    expected = [len(g) for g in split_layers(np.arange(sum(stored), dtype=np.float64),
                                             config.patch.layer_fractions, config.patch.layers)]
    assert stored == expected
    prefix = result.stats.retrain.prefix_psnr
    assert [p["layer"] for p in prefix] == [1, 2, 3] and prefix[-1]["psnr"] > prefix[0]["psnr"]
    stored_stats = spcodec.inspect(result.data).to_json()["metadata"]["stats"]
    assert stored_stats["prefix_psnr"] == prefix  # what a viewer reads to choose where to stop
    assert len(spcodec.decode(result.data)) == len(result.source_index)


@pytest.mark.training
def test_a_plain_retrained_encode_records_what_each_of_its_prefixes_shows(scene):
    """Not only nested files: every retrained file of several layers says, per prefix, what it
    scored on the training views, for a viewer choosing where to stop on a slow link."""
    config = EncoderConfig(seed=3, retrain=dataclasses.replace(QUICK, nested=False),
                           max_sketch_share=None,
                           patch=dataclasses.replace(PatchConfig(), layers=4,
                                                     layer_fractions=geometric_fractions(4)))
    result = encode(scene, config)
    layers = spcodec.inspect(result.data).to_json()["layers"][1:]
    prefix = result.stats.retrain.prefix_psnr
    assert [p["layer"] for p in prefix] == [k + 1 for k, layer in enumerate(layers)
                                            if layer["gaussians"]]
    assert len(prefix) == 4 and prefix[-1]["psnr"] > prefix[0]["psnr"]
    # the last prefix is the whole file, which the finish scored on the same views (with its
    # positions on their grid, the prefixes without: a few hundredths of a dB apart)
    assert prefix[-1]["psnr"] == pytest.approx(result.stats.retrain.psnr_finished, abs=0.25)
    assert spcodec.inspect(result.data).to_json()["metadata"]["stats"]["prefix_psnr"] == prefix


@pytest.mark.training
def test_rate_control_drops_from_the_last_layer_first(scene):
    config = EncoderConfig(seed=3, retrain=QUICK, max_sketch_share=None)
    free = encode(scene, config)
    sized = encode(scene, dataclasses.replace(config, target_size=int(0.8 * len(free.data))))
    stored = [layer["gaussians"] for layer in spcodec.inspect(sized.data).to_json()["layers"][1:]]
    trained = np.diff([0] + sized.stats.retrain.nested_layers).tolist()
    assert sum(stored) < sum(trained)
    last = max(k for k, count in enumerate(stored) if count)
    assert stored[:last] == trained[:last] and stored[last] <= trained[last]


def test_nested_needs_retraining(tmp_path, scene, capsys):
    ply = tmp_path / "in.ply"
    spcodec.write_ply(ply, scene)
    out = tmp_path / "out.spc"
    assert main(["encode", str(ply), "-o", str(out), "--no-retrain", "--nested"]) == 2
    assert "--nested only apply to retraining" in capsys.readouterr().err
    assert not out.exists()


def test_the_full_share_reaches_the_training_and_needs_nested(tmp_path, scene, capsys):
    args = build_parser().parse_args(["encode", "in.ply", "-o", "out.spc", "--nested",
                                      "--nested-full-share", "0.6"])
    assert encode_config(args).retrain.nested_full_share == 0.6
    ply = tmp_path / "in.ply"
    spcodec.write_ply(ply, scene)
    out = tmp_path / "out.spc"
    assert main(["encode", str(ply), "-o", str(out), "--nested-full-share", "0.6"]) == 2
    assert "--nested-full-share sets how --nested trains" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        build_parser().parse_args(["encode", "in.ply", "-o", "out.spc", "--nested",
                                   "--nested-full-share", "1.5"])
    assert "in 0..1" in capsys.readouterr().err
    assert not out.exists()


def test_a_library_caller_gets_the_layout_the_command_line_writes():
    """preset_config(..., retrain=True) and sized() hold the retrained defaults, so a library
    encode and ``spcodec encode --target-size`` describe the same file; a caller's own layer
    count still wins through with_layers."""
    from spcodec.encoder import preset_config, sized
    from spcodec.encoder.config import TARGET_GROUPS_PER_ENTRY
    from spcodec.encoder.presets import with_layers
    library = sized(preset_config("balanced", EncoderConfig(seed=7), retrain=True), 50_000)
    args = build_parser().parse_args(["encode", "in.ply", "-o", "out.spc", "--seed", "7",
                                      "--target-size", "50000"])
    assert library == encode_config(args)
    assert library.patch.layers == RETRAINED_PATCH_LAYERS
    assert library.max_sketch_share == RETRAINED_MAX_SKETCH_SHARE
    assert library.patch.groups_per_entry == TARGET_GROUPS_PER_ENTRY
    plain = preset_config("balanced", EncoderConfig(seed=7))
    assert plain.patch.layers == PatchConfig().layers
    assert plain.max_sketch_share == EncoderConfig().max_sketch_share
    three = with_layers(library.patch, PatchConfig().layers)
    assert three.layer_fractions == PatchConfig().layer_fractions
    assert with_layers(three, 8).layer_fractions == geometric_fractions(8)


@pytest.mark.parametrize("extra, layers", [
    ([], RETRAINED_PATCH_LAYERS),
    (["--nested"], RETRAINED_PATCH_LAYERS),
    (["--no-retrain"], PatchConfig().layers),
    (["--nested", "--patch-layers", "4"], 4),
    (["--patch-layers", str(PatchConfig().layers)], PatchConfig().layers),
    (["--no-retrain", "--patch-layers", "6"], 6),
])
def test_retrained_encodes_take_finer_layers_unless_told(extra, layers):
    """Six layers and a small sketch when retraining; three and a tenth without."""
    args = build_parser().parse_args(["encode", "in.ply", "-o", "out.spc", *extra])
    config = encode_config(args)
    patch = config.patch
    assert patch.layers == layers
    assert config.max_sketch_share == (EncoderConfig().max_sketch_share if "--no-retrain" in extra
                                       else RETRAINED_MAX_SKETCH_SHARE)
    default = layers == PatchConfig().layers
    assert patch.layer_fractions == (PatchConfig().layer_fractions if default
                                     else geometric_fractions(layers))
