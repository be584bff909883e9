"""The parts of retraining (imaging/training, encoder/prune, encoder/ratecontrol): rates, views,
loss, pruning, the quantization-aware model, checkpoints and rate control's size search."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.encoder.config import PatchConfig
from spcodec.encoder.kmeans import nearest
from spcodec.encoder.patch import PatchEncoder, quantized_cloud
from spcodec.encoder.prune import (
    kept_count,
    prune_by_importance,
    prune_sampled,
    prune_uniform,
    select,
)
from spcodec.encoder.ratecontrol import FIT_SLACK, TOLERANCE, fit_count, parse_size, plan_count
from spcodec.encoder.retraining.quantaware import (
    CodebookGaussians,
    Snap,
    SnappedGaussians,
    coded_tensors,
    nearest_entry,
)
from spcodec.errors import UsageError
from spcodec.imaging.training.checkpoint import Checkpointer, checkpoint_path, fingerprint
from spcodec.imaging.training.loop import view_order
from spcodec.imaging.training.loss import photometric_loss
from spcodec.imaging.training.optim import (
    FreeGaussians,
    LearningRates,
    camera_extent,
    position_rate,
)
from spcodec.synthetic import make_scene

pytestmark = pytest.mark.usefixtures("single_torch_thread")


@pytest.fixture(scope="module")
def cloud():
    return make_scene(3, curves=2, per_curve=100, blobs=400, sh_degree=2).cloud


# ------------------------------------------------------------------------------ rates, views
def test_position_rate_decays_log_linearly_from_init_to_final_times_extent():
    rates = LearningRates()
    assert position_rate(rates, 2.0, 0, 100) == pytest.approx(2.0 * rates.position_init)
    assert position_rate(rates, 2.0, 100, 100) == pytest.approx(2.0 * rates.position_final)
    middle = math.sqrt(rates.position_init * rates.position_final) * 2.0
    assert position_rate(rates, 2.0, 50, 100) == pytest.approx(middle)
    assert position_rate(rates, 2.0, 500, 100) == pytest.approx(2.0 * rates.position_final)


def test_camera_extent_is_the_3dgs_rule():
    ring = np.array([[3.0, 0, 0], [-3.0, 0, 0], [0, 3.0, 0], [0, -3.0, 0]]) + 10.0
    assert camera_extent(ring) == pytest.approx(3.3)
    assert camera_extent(np.zeros((1, 3))) == 1.0


@given(st.integers(1, 40), st.integers(0, 3), st.integers(0, 2**31))
def test_each_epoch_shows_every_view_once(count, epoch, seed):
    shown = [view_order(count, epoch * count + i, seed) for i in range(count)]
    assert sorted(shown) == list(range(count))


def test_free_gaussians_round_trip_and_group_rates(cloud):
    model = FreeGaussians(cloud, "cpu", LearningRates(), extent=2.0)
    back = model.to_cloud()
    np.testing.assert_array_equal(back.means, cloud.means)
    np.testing.assert_array_equal(back.sh_rest, cloud.sh_rest)
    np.testing.assert_allclose(np.linalg.norm(back.quats, axis=1), 1.0, rtol=1e-6)
    lr = {g["name"]: g["lr"] for g in model.optimizer.param_groups}
    assert lr["sh_rest"] == pytest.approx(lr["sh_dc"] / 20)
    model.before_step(0, 10)
    assert {g["name"]: g["lr"] for g in model.optimizer.param_groups}["means"] == \
        pytest.approx(1.6e-4 * 2.0)


# ------------------------------------------------------------------------------------ loss
def test_loss_is_zero_on_the_target_and_masks_apply():
    target = torch.rand(16, 20, 3)
    assert float(photometric_loss(target, target)) == pytest.approx(0.0, abs=1e-6)
    wrong = target.clone()
    wrong[:, :10] = 1 - wrong[:, :10]
    mask = torch.zeros(16, 20, dtype=torch.bool)
    mask[:, 10:] = True
    assert float(photometric_loss(wrong, target, mask, dssim_weight=0)) == pytest.approx(0.0)
    assert float(photometric_loss(wrong, target)) > 0.1


# --------------------------------------------------------------------------------- pruning
@given(st.integers(0, 5000), st.floats(1.0, 25.0))
def test_kept_count_matches_the_factor(n, factor):
    keep = kept_count(n, factor)
    assert keep == 0 if n == 0 else 1 <= keep <= n
    if n:
        assert abs(keep - n / factor) <= 0.5 or keep == 1


def test_pruning_picks_the_heaviest_or_a_seeded_sample():
    weights = np.array([0.5, 3.0, 0.0, 2.0, 3.0, 1.0])
    np.testing.assert_array_equal(prune_by_importance(weights, 3), [1, 3, 4])
    a, b = prune_uniform(1000, 100, seed=4), prune_uniform(1000, 100, seed=4)
    assert np.array_equal(a, b) and len(np.unique(a)) == 100 and np.all(np.diff(a) > 0)
    assert not np.array_equal(a, prune_uniform(1000, 100, seed=5))
    with pytest.raises(ValueError, match="needs blend weights"):
        select("importance", 10, 5, 0)
    with pytest.raises(ValueError, match="unknown prune method"):
        select("random", 10, 5, 0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0, 1e3, allow_subnormal=False), min_size=1, max_size=80),
       st.data(), st.integers(0, 2**31))
def test_sampled_pruning_is_a_seeded_sample_that_prefers_weight(weights, data, seed):
    """Distinct sorted indices, the same for a seed; every positive weight before any zero."""
    w = np.array(weights)
    keep = data.draw(st.integers(0, len(w)))
    a = prune_sampled(w, keep, seed)
    assert np.array_equal(a, prune_sampled(w, keep, seed)) and len(a) == keep
    assert np.all(np.diff(a) > 0) and (keep == 0 or 0 <= a[0] <= a[-1] < len(w))
    assert np.count_nonzero(w[a] > 0) == min(keep, np.count_nonzero(w > 0))


def test_sampled_pruning_draws_in_proportion_to_weight():
    """Over many seeds a Gaussian with three times the weight survives about three times as
    often when few are kept, and none of them is certain, unlike ranking."""
    w = np.r_[np.full(10, 3.0), np.full(90, 1.0)]
    counts = np.zeros(len(w))
    for seed in range(400):
        counts[prune_sampled(w, 5, seed)] += 1
    heavy, light = counts[:10].mean(), counts[10:].mean()
    assert 2.4 < heavy / light < 3.4 and counts[:10].max() < 400
    assert sorted(select("sampled", 100, 5, 0, w)) == sorted(prune_sampled(w, 5, 0))


# ------------------------------------------------------------------------ quantization-aware
@pytest.mark.parametrize("dims", [
    {"SCALE": 1, "ROTATION": 2, "OPACITY": 1, "COLOR_DC": 3, "SH_BAND_1": 9, "SH_BAND_2": 15},
    {"SCALE": 3, "ROTATION": 4, "OPACITY": 1, "COLOR_DC": 1, "SH_BAND_1": 3, "SH_BAND_2": 3},
])
def test_codebook_model_renders_what_the_decoder_decodes(cloud, dims):
    """The finish optimizes exactly the values a decoder reconstructs from the codebooks."""
    encoder = PatchEncoder(PatchConfig(entry_dims=dims, codebook_size=32), seed=1)
    quantized = encoder.quantize(cloud)
    model = CodebookGaussians(cloud.means, quantized.codebooks, quantized.indices,
                              cloud.sh_degree, "cpu", position_bits=0)
    got = model.params()
    want = quantized_cloud(quantized, cloud.means, cloud.sh_degree)
    quats = got.quats.detach().numpy()
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    np.testing.assert_allclose(quats, want.quats, atol=1e-6)
    np.testing.assert_allclose(got.scales.detach().numpy(), want.scales, atol=1e-6)
    np.testing.assert_allclose(got.opacities.detach().numpy(), want.opacities, atol=1e-4)
    sh = got.sh.detach().numpy()
    np.testing.assert_allclose(sh[:, 0], want.sh_dc, atol=1e-6)
    np.testing.assert_allclose(sh[:, 1:], want.sh_rest, atol=1e-6)


def test_codebook_model_learns_entries_and_keeps_indices_and_float16(cloud):
    encoder = PatchEncoder(PatchConfig(codebook_size=16), seed=0)
    quantized = encoder.quantize(cloud)
    model = CodebookGaussians(cloud.means, quantized.codebooks, quantized.indices,
                              cloud.sh_degree, "cpu", position_rate=1e-3)
    loss = model.params().scales.sum() + model.params().means.sum()
    loss.backward()
    model.optimizer.step()
    model.clamp_entries()
    moved = [cb for cb, old in zip(model.codebooks(), quantized.codebooks)
             if not np.array_equal(cb.entries, old.entries)]
    assert moved and all(cb.entries.dtype == np.float16 for cb in model.codebooks())
    for attr, idx in model.index_arrays().items():
        np.testing.assert_array_equal(idx, quantized.indices[attr])
    assert not np.array_equal(model.positions(), cloud.means)
    opacity = next(cb for cb in model.codebooks() if cb.attribute.name == "OPACITY")
    assert opacity.entries.min() >= 0 and opacity.entries.max() <= 1


def test_positions_pass_through_the_16_bit_grid(cloud):
    encoder = PatchEncoder(PatchConfig(codebook_size=8), seed=0)
    quantized = encoder.quantize(cloud)
    model = CodebookGaussians(cloud.means, quantized.codebooks, quantized.indices,
                              cloud.sh_degree, "cpu", position_bits=16)
    rendered = model.params().means.detach().numpy().astype(np.float64)
    cells = (rendered - model.grid_origin.numpy()) / model.grid_step
    np.testing.assert_allclose(cells, np.round(cells), atol=1e-2)
    assert np.abs(rendered - cloud.means).max() <= model.grid_step


@given(st.integers(1, 5), st.integers(1, 40), st.integers(1, 300), st.integers(0, 2**31))
def test_snapping_picks_the_nearest_entry_as_the_encoder_does(dim, k, m, seed):
    rng = np.random.default_rng(seed)
    entries = np.unique(rng.normal(size=(k, dim)).astype(np.float16), axis=0).astype(np.float32)
    groups = rng.normal(size=(m, dim)).astype(np.float32)
    got = nearest_entry(torch.from_numpy(groups), torch.from_numpy(entries)).numpy()
    want = nearest(groups, entries)
    # equal, or a tie to within float32 rounding
    d = ((groups[:, None, :] - entries[None]) ** 2).sum(axis=2)
    np.testing.assert_allclose(d[np.arange(m), got], d[np.arange(m), want], rtol=1e-5, atol=1e-6)


def _snap_of(cloud, size: int = 16) -> Snap:
    codebooks = PatchEncoder(PatchConfig(codebook_size=size), seed=0).quantize(cloud).codebooks
    return Snap.from_codebooks(codebooks, torch.device("cpu"))


def test_snapped_values_are_entries_with_a_straight_through_gradient(cloud):
    from spcodec.imaging.render import GaussianParams

    params = GaussianParams.from_cloud(cloud, "cpu", requires_grad=True)
    snap = _snap_of(cloud)
    values = coded_tensors(params, list(snap.entries))
    snapped = snap.apply(values)
    for attr, value in snapped.items():
        rows = value.detach().reshape(-1, snap.entries[attr].shape[1]).numpy()
        assert {tuple(r) for r in rows} <= {tuple(e) for e in snap.entries[attr].numpy()}
    snapped[next(iter(snapped))].sum().backward()
    assert params.scales.grad is not None and torch.equal(params.scales.grad,
                                                          torch.ones_like(params.scales))


def test_refreshing_entries_never_increases_the_weighted_error(cloud):
    from spcodec.imaging.render import GaussianParams

    params = GaussianParams.from_cloud(cloud, "cpu")
    snap = _snap_of(cloud, size=8)
    values = {a: v + 0.05 for a, v in coded_tensors(params, list(snap.entries)).items()}
    weights = torch.rand(len(cloud), generator=torch.Generator().manual_seed(0)) + 0.1

    def error() -> float:
        total = 0.0
        for attr, v in snap.apply(values).items():
            per = ((v - values[attr]) ** 2).reshape(len(cloud), -1).sum(dim=1)
            total += float((per * weights).sum())
        return total

    before = error()
    snap.refresh(values, weights)
    after = error()
    assert after < before
    assert all(e.dtype == torch.float32 and torch.equal(e, e.half().float())
               for e in snap.entries.values())


def _snapped(cloud, start: int, keep=None) -> SnappedGaussians:
    encoder = PatchEncoder(PatchConfig(codebook_size=16), seed=0)

    def quantize(current):
        rows = keep
        part = current if rows is None else current.subset(rows)
        return rows, encoder.quantize(part).codebooks, np.ones(len(part))

    return SnappedGaussians(cloud, torch.device("cpu"), LearningRates(), 1.0, start=start,
                            refresh_every=3, quantize=quantize)


def test_snapped_gaussians_render_what_a_decoder_reconstructs(cloud):
    model = _snapped(cloud, start=2)
    free = model.params()
    np.testing.assert_array_equal(free.scales.detach().numpy(), cloud.scales)
    for step in range(3):
        model.before_step(step, 10)
    assert model.snapping
    got = model.params()
    codebooks, indices = model.quantized()
    from spcodec.encoder.patch import Quantized
    want = quantized_cloud(Quantized(codebooks, indices), cloud.means, cloud.sh_degree)
    np.testing.assert_allclose(got.scales.detach().numpy(), want.scales, atol=1e-6)
    np.testing.assert_allclose(got.sh.detach().numpy()[:, 0], want.sh_dc, atol=1e-6)
    np.testing.assert_allclose(got.opacities.detach().numpy(), want.opacities, atol=1e-4)
    origin, step = model.grid
    cells = (got.means.detach().numpy() - origin.numpy()) / step
    np.testing.assert_allclose(cells, np.round(cells), atol=1e-2)


def test_snapping_keeps_the_rows_rate_control_chose_and_checkpoints_them(cloud):
    keep = np.arange(0, len(cloud), 3)
    model = _snapped(cloud, start=1, keep=keep)
    for step in range(2):
        model.before_step(step, 10)
    assert len(model.params().means) == len(keep)
    np.testing.assert_array_equal(model.kept_rows(), keep)
    state = model.state_dict()
    again = _snapped(cloud, start=1, keep=keep)
    again.load_state_dict(state)
    np.testing.assert_array_equal(again.kept_rows(), keep)
    assert torch.equal(again.params().scales, model.params().scales)


# ----------------------------------------------------------------------------- checkpoints
def test_checkpoint_round_trip_refusals_and_atomicity(tmp_path, cloud):
    out = tmp_path / "scene.spc"
    path = checkpoint_path(out)
    assert path.name == "scene.spc.ckpt"
    key = fingerprint(cloud, {"a": 1})
    assert key == fingerprint(cloud, {"a": 1}) != fingerprint(cloud, {"a": 2})
    ckpt = Checkpointer(path, key)
    with pytest.raises(UsageError, match="no checkpoint"):
        ckpt.load()
    ckpt.refuse_stale()
    ckpt.save("retrain", 7, {"x": torch.arange(3)})
    data = ckpt.load()
    assert data["stage"] == "retrain" and data["step"] == 7
    assert torch.equal(data["state"]["x"], torch.arange(3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.spc.ckpt"]
    with pytest.raises(UsageError, match="--resume to continue"):
        ckpt.refuse_stale()
    with pytest.raises(UsageError, match="another input or other settings"):
        Checkpointer(path, fingerprint(cloud, {"a": 2})).load()
    path.write_bytes(b"not a checkpoint")
    with pytest.raises(UsageError, match="cannot be read"):
        ckpt.load()
    ckpt.remove()
    assert not path.exists()


# ---------------------------------------------------------------------------- rate control
@given(st.floats(1, 1e9, allow_nan=False), st.sampled_from(["", "k", "K", "M", "MB", "kb",
                                                          "KiB", "MiB", "G"]))
def test_parse_size_reads_decimal_and_binary_units(value, unit):
    factor = {"": 1, "k": 1e3, "K": 1e3, "M": 1e6, "MB": 1e6, "kb": 1e3, "KiB": 1024,
              "MiB": 1024 ** 2, "G": 1e9}[unit]
    text = f"{value:.3f}{unit}"
    if float(f"{value:.3f}") * factor < 1:
        with pytest.raises(UsageError):
            parse_size(text)
    else:
        assert parse_size(text) == round(float(f"{value:.3f}") * factor)


@pytest.mark.parametrize("text", ["", "abc", "12 parsecs", "-5k", "1e3"])
def test_parse_size_refuses_what_it_cannot_read(text):
    with pytest.raises(UsageError):
        parse_size(text)


def _size_model(fixed: int, per: float, wobble: float = 0.0):
    """A file that grows by ``per`` bytes per patch Gaussian, slightly non-linearly."""
    def size(count: int) -> int:
        return int(fixed + per * count * (1 + wobble * math.sin(count / 500)))
    return size


@given(st.integers(500, 20000), st.floats(4.0, 14.0), st.floats(0.05, 0.95),
       st.floats(0.0, 0.1))
def test_plan_count_lands_within_tolerance(fixed, per, share, wobble):
    n = 50_000
    size = _size_model(fixed, per, wobble)
    target = int(fixed + share * (size(n) - fixed))
    if target < size(16):
        return
    plan = plan_count(target, n, size)
    assert abs(size(plan.count) - target) <= TOLERANCE * target
    assert plan.predicted_bytes == size(plan.count) and plan.fixed_bytes == fixed


@given(st.integers(500, 5000), st.floats(200.0, 2000.0), st.floats(0.3, 0.7), st.floats(0.05, 0.95))
def test_plan_count_lands_within_tolerance_when_sizes_bend(fixed, scale, power, share):
    """Codebooks fill up and entropy coding gets cheaper per Gaussian as the count grows: the size
    bends (a small scene whose sketch is capped to a small target: 5.3 kB at 16 patch Gaussians,
    44 kB at 1,029, 72 kB at 5,732), and a line through the ends keeps landing on one side."""
    n = 6000

    def size(count: int) -> int:
        return fixed + int(scale * count ** power)

    target = int(size(16) + share * (size(n) - size(16)))
    plan = plan_count(target, n, size)
    assert abs(size(plan.count) - target) <= TOLERANCE * target


def test_plan_count_refuses_too_small_and_notes_too_large():
    size = _size_model(10_000, 10.0)
    with pytest.raises(UsageError, match="too small for this scene.*ask for at least"):
        plan_count(5_000, 1000, size)
    plan = plan_count(10 ** 7, 1000, size)
    assert plan.count == 1000 and "above the unpruned encode" in plan.note


@given(st.integers(1000, 20000), st.floats(4.0, 14.0), st.integers(100, 30000),
       st.floats(0.05, 0.98), st.floats(0.0, 0.05))
def test_fit_count_never_passes_the_target_and_leaves_little_under_it(fixed, per, upper, share,
                                                                        wobble):
    """The target is a budget: the fitted file is a measured size at or under it, and either
    every Gaussian fits, one more would not, or it is within FIT_SLACK under the target; sizes
    that wobble (compression noise, not monotone in the count) change none of that."""
    size = _size_model(fixed, per, wobble)
    target = int(fixed + per * upper * share) + 1
    if size(1) > target:
        return
    writes = []
    count, got = fit_count(target, upper, lambda n: writes.append(n) or size(n))
    assert got == size(count) and got <= target
    assert count == upper or size(count + 1) > target or got >= target * (1 - FIT_SLACK)
    assert len(writes) <= 3 + math.ceil(math.log2(upper))


def test_fit_count_lands_in_a_few_writes_when_sizes_are_nearly_linear():
    size = _size_model(40_000, 9.0, 0.01)
    writes = []
    count, got = fit_count(500_000, 60_000, lambda n: writes.append(n) or size(n))
    assert 500_000 * (1 - FIT_SLACK) <= got <= 500_000
    assert len(writes) <= 5, writes


@given(st.integers(500, 20000), st.floats(4.0, 14.0), st.floats(0.05, 0.95))
def test_plan_count_meets_a_tight_tolerance_when_asked(fixed, per, share):
    """Without retraining the planned file is the one written, so it is planned to FIT_SLACK."""
    n = 50_000
    size = _size_model(fixed, per, 0.02)
    target = int(fixed + share * (size(n) - fixed))
    if target < size(16):
        return
    plan = plan_count(target, n, size, FIT_SLACK)
    # a window narrower than two Gaussians may hold no count at all
    assert abs(size(plan.count) - target) <= max(FIT_SLACK * target, per * 2)


def test_close_up_crops_train_but_never_rank(cloud):
    """Distillation targets hold whole views and crops of nearer ones; blend weights rank
    Gaussians over the whole views only (a crop sees only some of them)."""
    from spcodec.imaging.render import RenderSettings
    from spcodec.imaging.training.targets import distillation_targets
    from spcodec.imaging.views import close_crops, sample_views

    whole = sample_views(cloud, 3, resolution=(48, 48), split="train")
    crops = close_crops(cloud, 2, resolution=96, crop=32)
    targets = distillation_targets(cloud, whole, RenderSettings(), torch.device("cpu"), crops)
    assert [v.crop for v in targets.views] == [False] * 3 + [True] * 2
    assert targets.whole_cameras == whole
    assert tuple(targets.views[-1].image.shape) == (32, 32, 3)
    assert float(targets.views[-1].image.max()) > 0  # the crop shows the scene
