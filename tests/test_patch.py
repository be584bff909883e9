"""The patch encoder's steps (encoder/patch.py): quantize, assign, layer, and their round trips."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import spcodec
from spcodec.attributes import PatchAttribute
from spcodec.cloud import GaussianCloud
from spcodec.encoder.config import PatchConfig, codebook_entries
from spcodec.encoder.morton import morton_codes
from spcodec.encoder.patch import PatchEncoder, coded_attributes, dequantize, quantized_cloud
from spcodec.synthetic import make_scene
from spcodec.writer import EncodedScene, build_bitstream

from conftest import real_file

CONFIG = PatchConfig(kmeans_iterations=10, kmeans_samples=20_000)


@pytest.fixture(scope="module")
def cloud():
    return make_scene(11, curves=0, blobs=2500, sh_degree=2).cloud


@pytest.fixture(scope="module")
def quantized(cloud):
    return PatchEncoder(CONFIG, seed=3).quantize(cloud)


def test_quantize_gives_a_codebook_and_indices_per_attribute(cloud, quantized):
    attrs = PatchAttribute.for_sh_degree(cloud.sh_degree)
    assert [cb.attribute for cb in quantized.codebooks] == attrs
    for cb in quantized.codebooks:
        idx = quantized.indices[cb.attribute]
        assert cb.entries.dtype == np.float16 and len(cb.entries) <= CONFIG.codebook_size
        assert cb.entry_dim == CONFIG.entry_dims[cb.attribute.name]
        assert idx.dtype == np.uint8 and idx.shape == (len(cloud), cb.groups)
        assert idx.max() < len(cb.entries)
    assert len(quantized) == len(cloud)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10**6), st.integers(0, 10**6), st.floats(0.5, 500),
       st.integers(1, 256), st.integers(1, 256))
def test_codebook_entries_grow_with_the_groups_and_stay_in_range(a, b, per_entry, floor, cap):
    config = PatchConfig(codebook_size=cap, groups_per_entry=per_entry, min_codebook_entries=floor)
    small, large = sorted((a, b))
    assert 1 <= codebook_entries(config, small, 1) <= codebook_entries(config, large, 1) <= cap
    entries = codebook_entries(config, large, 1)
    assert min(cap, floor) <= entries <= max(floor, large / per_entry)  # one entry per per_entry groups
    assert entries == cap or entries == floor or entries > large / per_entry - 1
    assert codebook_entries(dataclasses.replace(config, groups_per_entry=None), small, 1) == cap
    assert codebook_entries(config, large, 3) == codebook_entries(config, 3 * large, 1)
    fixed = dataclasses.replace(config, codebooks_sized_for=large)
    assert codebook_entries(fixed, small, 1) == entries  # the planned count, not the cloud's


def test_few_gaussians_get_small_codebooks_and_still_decode_exactly(cloud):
    few = cloud.subset(np.arange(300))
    config = dataclasses.replace(CONFIG, groups_per_entry=32, min_codebook_entries=4)
    quantized = PatchEncoder(config, seed=3).quantize(few)
    for cb in quantized.codebooks:
        expected = codebook_entries(config, len(few), cb.groups)
        assert len(cb.entries) <= expected < CONFIG.codebook_size
        assert quantized.indices[cb.attribute].max() < len(cb.entries)
    sizes = {cb.attribute.name: len(cb.entries) for cb in quantized.codebooks}
    assert sizes["SH_BAND_2"] <= 300 // 32 and sizes["SCALE"] <= 900 // 32
    full = PatchEncoder(CONFIG, seed=3).quantize(few)
    assert sum(cb.entries.size for cb in quantized.codebooks) < sum(
        cb.entries.size for cb in full.codebooks) / 4


def test_dequantize_returns_the_selected_entries_close_to_the_input(cloud, quantized):
    values, original = dequantize(quantized), coded_attributes(cloud)
    for cb in quantized.codebooks:
        got = values[cb.attribute]
        assert got.shape == original[cb.attribute].shape
        # every group is one of the codebook's entries ...
        groups = got.reshape(-1, cb.entry_dim)
        want = cb.entries.astype(np.float32)[quantized.indices[cb.attribute].ravel()]
        np.testing.assert_array_equal(groups, want)
        # ... and the squared error is well below the attribute's variance (random SH bands of 9
        # and 15 dimensions keep the most: 27 % and 43 %; the other attributes < 3 %)
        orig = original[cb.attribute]
        error = ((got - orig) ** 2).sum(axis=1).mean()
        assert error < 0.6 * ((orig - orig.mean(axis=0)) ** 2).sum(axis=1).mean(), cb.attribute.name


def test_assign_reproduces_quantize_and_picks_the_nearest_entry(cloud, quantized):
    enc = PatchEncoder(CONFIG, seed=3)
    again = enc.assign(cloud, quantized.codebooks)
    values = coded_attributes(cloud)
    for cb in quantized.codebooks:
        np.testing.assert_array_equal(again[cb.attribute], quantized.indices[cb.attribute])
        groups = values[cb.attribute].reshape(-1, cb.entry_dim)
        dist = ((groups[:, None, :] - cb.entries.astype(np.float64)[None]) ** 2).sum(axis=2)
        chosen = dist[np.arange(len(groups)), again[cb.attribute].ravel()]
        np.testing.assert_allclose(chosen, dist.min(axis=1), rtol=1e-5, atol=1e-9)


def test_assign_refuses_codebooks_of_another_sh_degree(cloud, quantized):
    with pytest.raises(ValueError, match="codebooks for"):
        PatchEncoder(CONFIG).assign(cloud, quantized.codebooks[:4])
    with pytest.raises(ValueError, match="weights"):
        PatchEncoder(CONFIG).quantize(cloud, weights=np.ones(3))


@pytest.mark.parametrize("as_set", [False, True])
def test_layers_follow_importance_and_pair_each_position_with_its_gaussian(cloud, quantized, as_set):
    """Layers by decreasing importance; within a layer, Morton order when positions are coded in
    sequence, Draco's order when coded as a set (where that is smaller), and each stored position
    is its own Gaussian's."""
    importance = np.random.default_rng(0).exponential(size=len(cloud))
    config = dataclasses.replace(CONFIG, set_coding_saving=0.0 if as_set else None)
    out = PatchEncoder(config).layer(cloud, quantized, importance)
    assert len(out.layers) == config.layers
    joined = np.concatenate(out.order)
    assert np.array_equal(np.sort(joined), np.arange(len(cloud)))
    for earlier, later in zip(out.order, out.order[1:]):
        assert importance[earlier].min() >= importance[later].max()
    in_morton_order = []
    for members, layer in zip(out.order, out.layers):
        xyz = cloud.means[members].astype(np.float64)
        step = np.ptp(xyz, axis=0).max() / ((1 << config.stored_position_bits) - 1)
        assert np.abs(layer.positions.decode() - xyz).max() <= 0.51 * step
        in_morton_order.append(bool(np.all(np.diff(morton_codes(xyz).astype(np.int64)) >= 0)))
        for attr, idx in layer.indices.items():
            np.testing.assert_array_equal(idx, quantized.indices[attr][members])
    # coded as a set where that is smaller: the larger layers here, not the smallest
    assert all(in_morton_order) != as_set


def test_the_decoded_file_equals_the_quantized_cloud(cloud):
    """quantized_cloud is what a decoder makes of the layers (positions aside)."""
    enc = PatchEncoder(CONFIG, seed=1)
    out = enc.encode(cloud)
    data = build_bitstream(EncodedScene(cloud.sh_degree, [], out.codebooks, out.layers))
    decoded = spcodec.decode(data)
    order = np.concatenate(out.order)
    q = enc.quantize(cloud, None)
    q.codebooks = out.codebooks
    q.indices = enc.assign(cloud, out.codebooks)
    expect = quantized_cloud(q.subset(order), decoded.means, cloud.sh_degree)
    assert expect.equals(decoded)


def test_encode_is_deterministic_for_a_seed(cloud):
    a = PatchEncoder(CONFIG, seed=5).encode(cloud)
    b = PatchEncoder(CONFIG, seed=5).encode(cloud)
    for x, y in zip(a.codebooks, b.codebooks):
        np.testing.assert_array_equal(x.entries, y.entries)
    for x, y in zip(a.order, b.order):
        np.testing.assert_array_equal(x, y)


def test_blend_importance_sends_a_hidden_gaussian_last_where_footprint_sent_it_first():
    """A large opaque Gaussian inside a closed shell: the footprint proxy ranks it first, the blend
    weight over sampled views (which never see it) ranks it last."""
    rng = np.random.default_rng(0)
    shell = rng.normal(size=(3000, 3))
    shell /= np.linalg.norm(shell, axis=1, keepdims=True)
    cloud = GaussianCloud.zeros(len(shell) + 1, 0)
    cloud.means[:-1] = shell
    cloud.scales[:] = np.log(0.08)
    cloud.scales[-1] = np.log(0.2)  # 3 sigma stays inside the shell
    cloud.opacities[:] = 6.0
    config = PatchConfig(kmeans_iterations=10, kmeans_samples=20_000, importance_views=4,
                         importance_resolution=(64, 48))
    hidden = len(cloud) - 1
    blend = PatchEncoder(config).measure_importance(cloud)
    assert blend[hidden] < 1e-3 * np.median(blend[:-1]) and (blend[:-1] > 0).mean() > 0.5
    footprint = PatchEncoder(dataclasses.replace(config, importance="footprint"))
    assert hidden in footprint.encode(cloud).order[0]
    assert hidden in PatchEncoder(config).encode(cloud).order[-1]


# ------------------------------------------------------- scalar rotation codebooks, input grids
@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 256))
def test_scaled_rotation_indices_are_never_farther_than_the_nearest_entries(seed, entries):
    from spcodec.encoder.patch import assign, assign_rotation

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(300, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    book = np.sort(rng.uniform(-1, 1, (entries, 1))).astype(np.float16)

    def angle(idx: np.ndarray) -> np.ndarray:
        coded = book.astype(np.float64)[idx][..., 0]
        norm = np.linalg.norm(coded, axis=1)
        cosine = np.abs((coded * q).sum(axis=1)) / np.where(norm > 0, norm, np.inf)
        return np.arccos(np.clip(cosine, 0, 1))

    scaled, plain = assign_rotation(q, book), assign(q, book)
    assert scaled.dtype == np.uint8 and scaled.shape == (300, 4) and scaled.max() < entries
    assert np.all(angle(scaled) <= angle(plain) + 1e-12)


def plain_scaled_rotation_search(q: np.ndarray, book: np.ndarray) -> np.ndarray:
    """The search assign_rotation makes, written plainly: every component rounded afresh at
    every multiple and every Gaussian judged at each."""
    from spcodec.encoder.patch import ROTATION_SCALES

    flat = book.astype(np.float64)[:, 0]
    order = np.argsort(flat, kind="stable")
    sorted_entries = flat[order]
    midpoints = (sorted_entries[1:] + sorted_entries[:-1]) / 2.0
    best, out = np.full(len(q), -1.0), np.zeros(q.shape, np.uint8)
    for scale in ROTATION_SCALES:
        idx = np.searchsorted(midpoints, q * scale)
        coded = sorted_entries[idx]
        norm = np.linalg.norm(coded, axis=1)
        cosine = np.abs((coded * q).sum(axis=1)) / np.where(norm > 0, norm, np.inf)
        better = cosine > best
        best[better], out[better] = cosine[better], order[idx[better]]
    return out


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 256), st.booleans())
def test_scaled_rotation_indices_equal_the_plain_search(seed, entries, odd):
    """Rounding again only the components that crossed a midpoint changes no index: repeated
    entries, zeros, signs, and (``odd``) zero, infinite and NaN components included."""
    from spcodec.encoder.patch import assign_rotation

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(400, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    book = rng.uniform(-1, 1, (entries, 1)).astype(np.float16)
    book[rng.random(entries) < 0.1] = 0
    if entries > 1:
        book[-1] = book[0]  # a repeated entry
    if odd:
        q[rng.random(400) < 0.1] = 0
        q[rng.integers(400), rng.integers(4)] = np.nan
        q[rng.integers(400), rng.integers(4)] = np.inf
    with np.errstate(invalid="ignore"):  # the infinite component times a zero entry, on purpose
        assert np.array_equal(assign_rotation(q, book), plain_scaled_rotation_search(q, book))


def test_scaled_rotation_indices_halve_the_angle_error_on_a_real_scene():
    from spcodec.attributes import canonical_rotation, decode_rotation
    from spcodec.encoder.patch import assign, assign_rotation, train_codebook

    q = canonical_rotation(spcodec.read_ply(real_file("playcanvas_biker_guitar/guitar_inria.ply")).quats)
    book = train_codebook(q, 1, 256, None, PatchConfig(), 0)

    def rms_degrees(idx: np.ndarray) -> float:
        coded = decode_rotation(book.astype(np.float64)[idx][..., 0]).astype(np.float64)
        cosine = np.clip(np.abs((coded * q).sum(axis=1)), 0, 1)
        return float(np.sqrt(np.mean(np.degrees(2 * np.arccos(cosine)) ** 2)))

    assert rms_degrees(assign_rotation(q, book)) < 0.5 * rms_degrees(assign(q, book))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 14), st.integers(1, 4000))
def test_positions_on_a_coarse_power_of_two_grid_are_stored_on_it(seed, exponent, levels):
    """quant16 mode stores grid positions bit for bit; draco mode keeps the smaller of that and
    Draco on the same grid, which must decode within a sixteenth of the grid's step."""
    import zlib

    from spcodec.encoder.patch import encode_positions
    from spcodec.sections import PositionMode, pack_positions

    rng = np.random.default_rng(seed)
    offset = rng.integers(-2000, 2000, 3)
    xyz = ((rng.integers(0, levels + 1, (200, 3)) + offset) * 2.0 ** -exponent).astype(np.float32)
    exact = encode_positions(xyz, "quant16", 16).positions
    assert exact.mode == PositionMode.QUANT16
    assert np.array_equal(exact.decode(), xyz)
    stored = encode_positions(xyz, "draco", 16)
    size = len(zlib.compress(pack_positions(stored.positions)))
    assert size <= len(zlib.compress(pack_positions(exact)))
    off = np.abs(stored.positions.decode().astype(np.float64) - xyz[stored.order]).max()
    assert off <= 2.0 ** -exponent / 16
    if stored.positions.mode == PositionMode.QUANT16:
        assert np.array_equal(stored.positions.decode(), xyz)


def test_positions_decoded_from_spz_take_dracos_grid_coder_at_three_quarters_the_bytes():
    """fourth_st's positions lie on SPZ's 2^-12 grid: Draco on that grid stores them in
    under 80 % of QUANT16's bytes, and every one decodes within a hundredth of the step."""
    import zlib

    from spcodec.encoder.patch import encode_positions
    from spcodec.sections import PositionMode, pack_positions

    xyz = spcodec.read_ply(real_file("pdal_fourth_st_spz/fourth_st_inria.ply")).means
    xyz = xyz[np.argsort(morton_codes(xyz.astype(np.float64)), kind="stable")]
    exact, stored = (encode_positions(xyz, mode, 16) for mode in ("quant16", "draco"))
    assert stored.positions.mode == PositionMode.DRACO
    sizes = [len(zlib.compress(pack_positions(p.positions))) for p in (stored, exact)]
    assert sizes[0] < 0.8 * sizes[1]
    off = np.abs(stored.positions.decode().astype(np.float64) - xyz[stored.order]).max()
    assert off < 1e-2 * 2.0 ** -12


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 600), st.integers(4, 16), st.integers(0, 5))
def test_positions_as_a_set_are_a_permutation_within_half_a_step(seed, n, bits, twins):
    """[R-58], [R-100]: a layer coded as a set is stored in Draco's order; ``order`` names the
    input row of every stored point, each decodes within half a grid step of its own row, and the
    file never grows for it; exact twins (which Draco's kd-tree mode would merge) included."""
    import zlib

    from spcodec.encoder.patch import encode_positions
    from spcodec.sections import pack_positions

    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(n, 3)).astype(np.float32) * rng.uniform(0.01, 100)
    twins = min(twins, n - 1)
    xyz[:twins] = xyz[n - twins:]
    unordered = encode_positions(xyz, "draco", bits)
    ordered = encode_positions(xyz, "draco", bits, set_saving=None)
    assert np.array_equal(ordered.order, np.arange(n))
    assert np.array_equal(np.sort(unordered.order), np.arange(n))
    step = float(np.ptp(xyz.astype(np.float64), axis=0).max()) / ((1 << bits) - 1)
    off = np.abs(unordered.positions.decode().astype(np.float64) - xyz[unordered.order]).max()
    assert off <= 0.5 * step * 1.001 + 1e-6 * float(np.abs(xyz).max())
    sizes = [len(zlib.compress(pack_positions(p.positions))) for p in (unordered, ordered)]
    assert sizes[0] <= sizes[1]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 300), st.integers(1, 6))
def test_apart_separates_twins_by_units_in_the_last_place(seed, n, copies):
    from spcodec.encoder.draco import apart

    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(n, 3)).astype(np.float32)
    twins = np.concatenate([xyz] + [xyz[: n // 2]] * (copies - 1))
    moved = apart(twins)
    assert len(np.unique(moved, axis=0)) == len(moved)
    assert np.array_equal(moved[:, 1:], twins[:, 1:])
    assert np.array_equal(moved[:n], xyz)  # first copies stay where they are
    assert np.abs(moved[:, 0] - twins[:, 0]).max() <= copies * np.spacing(np.abs(twins[:, 0])).max()


def test_a_layer_with_twins_is_coded_as_a_set_too():
    """biker (decoded from SPZ) repeats 341 positions exactly: at 14 bits its layer is
    still coded as a set, and every Gaussian comes back."""
    from spcodec.encoder.patch import encode_positions
    from spcodec.sections import PositionMode

    xyz = spcodec.read_ply(real_file("playcanvas_biker_guitar/biker_from_spz_inria.ply")).means
    assert len(np.unique(xyz, axis=0)) < len(xyz) - 300
    xyz = xyz[np.argsort(morton_codes(xyz.astype(np.float64)), kind="stable")]
    unordered, ordered = (encode_positions(xyz, "draco", 14, set_saving=s) for s in (2.0, None))
    assert unordered.positions.mode == PositionMode.DRACO
    assert np.array_equal(np.sort(unordered.order), np.arange(len(xyz)))
    assert len(unordered.positions.blob) < 0.9 * len(ordered.positions.blob)


def test_a_trained_scenes_positions_as_a_set_take_a_tenth_fewer_bytes():
    """guitar's trained positions at 14 bits: Draco's kd-tree coding of the Morton-ordered layer
    is at least 10 % smaller than its sequential coding of the same grid (14 % measured)."""
    from spcodec.encoder.patch import encode_positions
    from spcodec.sections import PositionMode

    xyz = spcodec.read_ply(real_file("playcanvas_biker_guitar/guitar_inria.ply")).means
    xyz = xyz[np.argsort(morton_codes(xyz.astype(np.float64)), kind="stable")]
    unordered, ordered = (encode_positions(xyz, "draco", 14, set_saving=s) for s in (2.0, None))
    assert unordered.positions.mode == ordered.positions.mode == PositionMode.DRACO
    assert not np.array_equal(unordered.order, ordered.order)
    assert len(unordered.positions.blob) < 0.9 * len(ordered.positions.blob)


def test_positions_off_any_grid_or_on_a_finer_one_keep_the_configured_coding():
    from spcodec.encoder.patch import encode_positions, input_grid
    from spcodec.sections import PositionMode

    rng = np.random.default_rng(4)
    trained = rng.normal(size=(500, 3)).astype(np.float32)
    assert input_grid(trained, 16) is None
    assert encode_positions(trained, "draco", 16).positions.mode == PositionMode.DRACO
    fine = (rng.integers(0, 60_000, (500, 3)) * 2.0 ** -12).astype(np.float32)
    assert input_grid(fine, 12) is None  # 60,000 levels: finer than 12 bits asks for
    assert input_grid(fine, 16) is not None
    wide = (rng.integers(0, 70_000, (500, 3)) * 2.0 ** -12).astype(np.float32)
    assert input_grid(wide, 18) is None  # more levels than QUANT16 holds


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(1.0, 1e4), st.integers(0, 3))
def test_retrained_position_bits_keep_the_robust_grid_fine_whatever_the_outliers(seed, reach,
                                                                                outliers):
    """12 bits over a scene without outliers; outliers ``reach`` times as far as the scene's
    extent add bits, so the step stays near 1/4096 of the robust extent (the box views frame),
    until 16 bits."""
    from spcodec.encoder.config import DEFAULT_POSITION_BITS, RETRAINED_POSITION_BITS
    from spcodec.encoder.patch import retrained_position_bits

    rng = np.random.default_rng(seed)
    scene = rng.uniform(-1, 1, (1000, 3)) * rng.uniform(0.1, 10, 3)
    far = rng.normal(size=(outliers, 3))
    far *= reach * np.ptp(scene, axis=0).max() / np.linalg.norm(far, axis=1, keepdims=True)

    def cloud(xyz: np.ndarray) -> GaussianCloud:
        n = len(xyz)
        return GaussianCloud(means=xyz, scales=np.full((n, 3), -4.0),
                             quats=np.tile([1, 0, 0, 0], (n, 1)), opacities=np.full(n, 2.0),
                             sh_dc=np.zeros((n, 3)), sh_rest=np.zeros((n, 0, 3)))

    points = cloud(np.concatenate([scene, far]))
    bits = retrained_position_bits(points)
    assert RETRAINED_POSITION_BITS <= bits <= DEFAULT_POSITION_BITS
    if outliers == 0:
        assert bits == RETRAINED_POSITION_BITS
    box = float(np.ptp(points.means.astype(np.float64), axis=0).max())
    robust = float(np.ptp(scene, axis=0).max())  # the scene without its outliers, known here
    if bits < DEFAULT_POSITION_BITS:
        assert box / (2 ** bits - 1) <= 1.5 * robust / (2 ** RETRAINED_POSITION_BITS - 1)
    assert retrained_position_bits(cloud(np.concatenate([scene, 2 * far]))) >= bits


def test_importance_views_orbit_the_encodes_up_axis():
    """The encode's ``--up`` places the importance views, as it places the search's and eval's:
    a z-up scene measured with the default -y orbit was circled about the wrong axis, and its
    size targets pruned by that (docs/LOG.md 33.7)."""
    from spcodec.encoder.config import EncoderConfig
    from spcodec.encoder.pipeline import measure_importance
    from spcodec.encoder.stages import EncodeRun, silent
    from spcodec.imaging.importance import training_view_weights

    rng = np.random.default_rng(3)
    cloud = GaussianCloud.zeros(400, 0)
    cloud.means[:] = rng.normal(size=(400, 3)) * (1.0, 0.3, 0.6)
    cloud.scales[:] = np.log(0.05)
    cloud.opacities[:] = 4.0
    patch = PatchConfig(importance_views=3, importance_resolution=(48, 36))
    for up in ("+z", "-y"):
        config = EncoderConfig(patch=patch, up=up)
        got = measure_importance(EncodeRun(cloud, config, silent))
        np.testing.assert_array_equal(
            got, training_view_weights(cloud, 3, (48, 36), seed=config.seed, up=up))
    other = training_view_weights(cloud, 3, (48, 36), seed=config.seed, up="+z")
    assert not np.array_equal(got, other)
