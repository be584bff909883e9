"""A faster eval with the same numbers: the reference's render cache, and SSIM computed only where
two images can differ (issue 40, "Progress that tells the truth")."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import spcodec
from spcodec.cli import main
from spcodec.imaging import metrics, views
from spcodec.imaging.cache import (
    CachedRenders,
    RenderCache,
    cache_key,
    cloud_digest,
    default_cache_dir,
)
from spcodec.imaging.cameras import Camera
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_reference, freed_memory_kept
from spcodec.synthetic import make_scene

SMALL = EvalConfig(views=3, resolution=48, device="cpu", closeup_resolution=64)


@pytest.fixture(scope="module")
def scene():
    return make_scene(11, curves=6, per_curve=150, blobs=800).cloud


@pytest.fixture(scope="module")
def model(scene):
    out = scene.subset(slice(None))
    rng = np.random.default_rng(0)
    out.sh_dc = (out.sh_dc + rng.normal(0, 0.05, out.sh_dc.shape)).astype(np.float32)
    return out


@pytest.fixture
def count_renders(monkeypatch):
    """Counts the renders an evaluation makes (every one goes through render_image)."""
    import spcodec.imaging.render as render

    calls = []
    real = render.render_image

    def counted(*args, **kwargs):
        calls.append(args[1])
        return real(*args, **kwargs)

    monkeypatch.setattr(render, "render_image", counted)
    return calls


def numbers(report) -> dict:
    """The report's JSON without its timings: what must not change."""
    doc = report.to_json()
    for framing in (doc, *doc["closeups"]):
        framing.pop("seconds")
        for view in framing["per_view"]:
            view.pop("render_seconds")
    return doc


def exact(report) -> list[tuple[float, float]]:
    """Every view's PSNR and SSIM unrounded."""
    return [(v.psnr, v.ssim) for r in (report, *report.closeups) for v in r.views]


# ------------------------------------------------------------------------------ the render cache
def test_a_cache_hit_gives_the_same_report_as_a_miss_and_as_no_cache(tmp_path, scene, model,
                                                                    count_renders):
    plain = evaluate_against_reference(model, scene, SMALL)
    assert len(count_renders) == 2 * 3 * 3  # both models, 3 views, 3 framings
    config = replace(SMALL, cache=tmp_path)
    count_renders.clear()
    miss = evaluate_against_reference(model, scene, config)
    assert len(count_renders) == 18 and len(list(tmp_path.glob("*.npz"))) == 3
    count_renders.clear()
    hit = evaluate_against_reference(model, scene, config)
    assert len(count_renders) == 9  # the model's renders only
    assert exact(hit) == exact(miss) == exact(plain)  # bit-identical, not merely close
    assert numbers(hit) == numbers(miss) == numbers(plain)
    assert not list(tmp_path.glob("*.tmp"))  # written atomically: no left-overs


def test_the_cache_serves_the_cameras_too(tmp_path, scene, model, monkeypatch):
    """A full hit samples no views (the cameras are stored with the renders)."""
    config = replace(SMALL, cache=tmp_path)
    first = evaluate_against_reference(model, scene, config)

    def refuse(*args, **kwargs):
        raise AssertionError("views were sampled again")

    monkeypatch.setattr(views, "sample_views", refuse)
    assert exact(evaluate_against_reference(model, scene, config)) == exact(first)


@pytest.mark.parametrize("change", [
    {"views": 2}, {"resolution": 40}, {"up": "+z"}, {"seed": 1}, {"blur_variance": 0.075},
    {"antialiased": True}, {"background": (1.0, 1.0, 1.0)}, {"closeup_resolution": 56},
])
def test_a_changed_setting_misses(tmp_path, scene, model, count_renders, change):
    config = replace(SMALL, cache=tmp_path, closeups=(0.5,))
    evaluate_against_reference(model, scene, config)
    count_renders.clear()
    changed = replace(config, **change)
    report = evaluate_against_reference(model, scene, changed)
    close_only = set(change) == {"closeup_resolution"}  # the sampled framing is the same
    views_ = changed.views
    assert len(count_renders) == (3 if close_only else 4) * views_
    assert exact(report) == exact(evaluate_against_reference(model, scene,
                                                             replace(changed, cache=None)))


def test_another_reference_misses_and_a_copy_hits(tmp_path, scene, model, count_renders):
    config = replace(SMALL, cache=tmp_path, closeups=())
    evaluate_against_reference(model, scene, config)
    count_renders.clear()
    evaluate_against_reference(model, scene.subset(slice(None)), config)  # same content
    assert len(count_renders) == 3
    count_renders.clear()
    evaluate_against_reference(scene, model, config)  # model and reference swapped
    assert len(count_renders) == 6


def test_framings_are_cached_one_by_one(tmp_path, scene, model, count_renders):
    """A later evaluation with fewer or other close-ups reuses every framing it shares, and a
    framing asked for twice is rendered once."""
    config = replace(SMALL, cache=tmp_path)
    full = evaluate_against_reference(model, scene, config)
    count_renders.clear()
    part = evaluate_against_reference(model, scene, replace(config, closeups=(0.25,)))
    assert len(count_renders) == 2 * 3 and exact(part.closeups[0]) == exact(full.closeups[1])
    count_renders.clear()
    twice = evaluate_against_reference(model, scene, replace(SMALL, closeups=(0.5, 0.5)))
    assert len(count_renders) == 2 * 3 + 2 * 3 + 3  # the second 0.5 renders the model only
    assert exact(twice.closeups[0]) == exact(twice.closeups[1]) == exact(full.closeups[0])
    count_renders.clear()
    near = evaluate_against_reference(model, scene, replace(config, closeups=(0.5, 0.3)))
    assert len(count_renders) == 3 + 3 + 2 * 3  # 0.3 is new, placed from the cached sampled views
    assert exact(near) == exact(evaluate_against_reference(
        model, scene, replace(SMALL, closeups=(0.5, 0.3))))


@pytest.mark.parametrize("damage", ["truncate", "garbage", "flip", "empty", "other_key"])
def test_a_corrupt_cache_file_is_ignored_and_rewritten(tmp_path, scene, model, count_renders,
                                                       damage):
    config = replace(SMALL, cache=tmp_path, closeups=())
    good = evaluate_against_reference(model, scene, config)
    (entry,) = tmp_path.glob("*.npz")
    data = entry.read_bytes()
    if damage == "truncate":
        entry.write_bytes(data[:len(data) // 2])
    elif damage == "garbage":
        entry.write_bytes(b"not a cache entry" * 100)
    elif damage == "flip":  # one byte in the middle of the images: the CRC-32 catches it
        middle = len(data) // 2
        entry.write_bytes(data[:middle] + bytes([data[middle] ^ 0xFF]) + data[middle + 1:])
    elif damage == "empty":
        entry.write_bytes(b"")
    else:  # a valid entry stored under the wrong name
        cache = RenderCache(tmp_path)
        cache.put("0" * 64, CachedRenders([], np.zeros((0, 8, 8, 3), np.float32)))
        (tmp_path / ("0" * 64 + ".npz")).replace(entry)
    count_renders.clear()
    again = evaluate_against_reference(model, scene, config)
    assert len(count_renders) == 6 and exact(again) == exact(good)  # rendered anew
    count_renders.clear()
    assert exact(evaluate_against_reference(model, scene, config)) == exact(good)
    assert len(count_renders) == 3  # rewritten: a hit again


def test_an_unwritable_cache_is_a_note_not_an_error(tmp_path, scene, model):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder should be")
    notes = []

    class Stage:
        def update(self, count=1, **figures):
            pass

        def note(self, message):
            notes.append(message)

        def done(self, summary=""):
            pass

    config = replace(SMALL, cache=blocker / "renders", closeups=(), progress=lambda n, t: Stage())
    report = evaluate_against_reference(model, scene, config)
    assert exact(report) == exact(evaluate_against_reference(model, scene,
                                                             replace(config, cache=None)))
    assert len(notes) == 1 and "was not written" in notes[0]


def test_view_sampling_warnings_are_repeated_from_the_cache(tmp_path, scene, model, monkeypatch):
    real = views.sample_views

    def warning(*args, **kwargs):
        warnings.warn("1 of 3 eval views reach less than 10% coverage", views.ViewSamplingWarning,
                      stacklevel=2)
        return real(*args, **kwargs)

    monkeypatch.setattr(views, "sample_views", warning)
    config = replace(SMALL, cache=tmp_path, closeups=())
    for _ in range(2):  # sampled, then served from the cache: the same warning both times
        with pytest.warns(views.ViewSamplingWarning, match="1 of 3 eval views"):
            evaluate_against_reference(model, scene, config)


def test_cache_trim_drops_the_least_recently_used(tmp_path):
    cache = RenderCache(tmp_path, max_bytes=1)
    camera = Camera.look_at([0, 0, -3.0], [0, 0, 0], [0, -1, 0], 8, 8, 0.9)
    entry = CachedRenders([camera], np.zeros((1, 8, 8, 3), np.float32))
    assert cache.put("a" * 64, entry) is None
    assert cache.put("b" * 64, entry) is None  # over the limit: "a" goes, the new one stays
    assert [p.stem for p in tmp_path.glob("*.npz")] == ["b" * 64]
    (got,) = cache.get("b" * 64).cameras
    assert (got.width, got.height, got.fx, got.fy, got.cx, got.cy) == \
        (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
    assert np.array_equal(got.world_to_camera, camera.world_to_camera)
    assert cache.get("c" * 64) is None


def test_cache_keys_and_digests(scene, monkeypatch, tmp_path):
    copy = scene.subset(slice(None))
    assert cloud_digest(copy) == cloud_digest(scene)
    copy.opacities = copy.opacities.copy()
    copy.opacities[0] += np.float32(1e-3)
    assert cloud_digest(copy) != cloud_digest(scene)
    assert cache_key({"a": 1, "b": [1, 2]}) == cache_key({"b": [1, 2], "a": 1})
    assert cache_key({"a": 1}) != cache_key({"a": 1.5})
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert default_cache_dir() == tmp_path / "spcodec" / "renders"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert default_cache_dir() == Path.home() / ".cache" / "spcodec" / "renders"


def test_eval_cli_caches_under_xdg_cache_home_unless_told_not_to(tmp_path, capsys, scene,
                                                                 monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    ply = tmp_path / "s.ply"
    spcodec.write_ply(ply, scene)
    argv = ["eval", str(ply), "--reference", str(ply), "--json", "--views", "2",
            "--resolution", "32", "--closeups", "0.5", "--closeup-resolution", "40",
            "--device", "cpu"]
    assert main(argv + ["--no-cache"]) == 0
    cold = json.loads(capsys.readouterr().out)
    assert not (tmp_path / "xdg").exists()
    docs = []
    for _ in range(2):
        assert main(argv) == 0
        docs.append(json.loads(capsys.readouterr().out))
    assert len(list((tmp_path / "xdg" / "spcodec" / "renders").glob("*.npz"))) == 2
    for doc in (cold, *docs):
        for framing in (doc, *doc["closeups"]):
            framing.pop("seconds")
            for view in framing["per_view"]:
                view.pop("render_seconds")
    assert cold == docs[0] == docs[1]


def test_freed_memory_kept_is_harmless():
    with freed_memory_kept() as applied:
        assert isinstance(applied, bool)
        np.ones((64, 1 << 20), np.uint8).sum()  # a 64 MB block, freed inside


# ----------------------------------------------------------------------------------------- SSIM
def _ssim_map_3dgs(reference: np.ndarray, ours: np.ndarray) -> np.ndarray:
    """The SSIM map as it was computed before (whole image, channel by channel): the oracle."""
    a, b = np.asarray(reference, np.float64), np.asarray(ours, np.float64)
    if a.ndim == 2:
        a, b = a[:, :, None], b[:, :, None]
    taps = metrics.gaussian_window()
    blur = metrics._blur_zero_padded
    out = np.empty(a.shape)
    for c in range(a.shape[2]):
        x, y = a[:, :, c], b[:, :, c]
        mu_x, mu_y = blur(x, taps), blur(y, taps)
        var_x = blur(x * x, taps) - mu_x * mu_x
        var_y = blur(y * y, taps) - mu_y * mu_y
        cov = blur(x * y, taps) - mu_x * mu_y
        out[:, :, c] = ((2.0 * mu_x * mu_y + metrics.SSIM_C1) * (2.0 * cov + metrics.SSIM_C2)) / \
            ((mu_x * mu_x + mu_y * mu_y + metrics.SSIM_C1) * (var_x + var_y + metrics.SSIM_C2))
    return out


def test_ssim_skips_only_windows_that_are_equal_and_keeps_every_bit():
    rng = np.random.default_rng(5)
    for trial in range(120):
        h, w = (int(v) for v in rng.integers(1, 140, 2))
        channels = int(rng.choice([1, 3]))
        a = rng.random((h, w, channels)).astype(np.float32)
        a[rng.random((h, w)) < 0.5] = 0.0  # background, as in renders
        b = a.copy()
        for _ in range(int(rng.integers(0, 4))):  # a few differing patches, maybe none
            y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
            b[y:y + int(rng.integers(1, 30)), x:x + int(rng.integers(1, 30))] += 0.05
        if trial % 10 == 0:
            b = rng.random(b.shape).astype(np.float32)  # differing everywhere
        if channels == 1 and trial % 2:
            a, b = a[:, :, 0], b[:, :, 0]
        expected = _ssim_map_3dgs(a, b)
        got = metrics.ssim_map(a, b)
        assert got.dtype == np.float64 and np.array_equal(got, expected), (h, w, channels)
        assert metrics.ssim(a, b) == float(expected.mean())


def test_image_metrics_are_unchanged_with_a_mask():
    rng = np.random.default_rng(1)
    a = rng.random((40, 50, 3))
    b = a.copy()
    b[10:20, 5:9] = 0.2
    mask = rng.random((40, 50)) < 0.7
    values = metrics.image_metrics(a, b, mask=mask, lpips_net=None)
    assert values["psnr"] == metrics.psnr(a, b, mask)
    assert values["ssim"] == float(_ssim_map_3dgs(a, b)[mask].mean())
