"""The encode's typed record (encoder/statistics.py) and the ``--stats`` document it writes.

The bench scripts and the tests read the ``--stats`` JSON by key, so ``EncodeStats.to_json()`` has
to give the document the dicts gave before the record was typed: the same keys, in the same
order, with the same meaning. The key lists below are those of the dict-built document (checked
against encodes made before and after the change); a field a run leaves unset is left out.
"""

from __future__ import annotations

import dataclasses
import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

import spcodec
from spcodec.cli import main
from spcodec.encoder.config import EncoderConfig, PatchConfig, RetrainConfig
from spcodec.encoder.pipeline import encode
from spcodec.encoder.statistics import RetrainStats, SketchStats, SnapDecision
from spcodec.synthetic import make_scene

FAST = EncoderConfig(seed=3, patch=PatchConfig(kmeans_iterations=10, kmeans_samples=20_000))
QUICK = RetrainConfig(iterations=20, finish_iterations=6, views=6, resolution=48,
                      importance_views=6, patch_downsample=3.0, close_views=2,
                      close_resolution=96, close_crop=32)

HEAD = ["gaussians", "sketch_gaussians", "patch_gaussians", "patch_layers", "sketch", "bytes",
        "sections", "layer_ends", "seconds"]
"""The document's first keys, in every encode."""
SKETCH = ["clusters_found", "clusters_accepted", "clusters_encoded", "draco_step", "scene_diameter",
          "duplicates", "rejected_clusters", "rejected_gaussians", "refine",
          "moved_to_patch_for_share"]
RETRAIN = ["prune", "psnr_before", "retrain_seconds", "psnr_retrained", "psnr_quantized",
           "psnr_finished", "finish_seconds", "prefix_psnr", "estimate"]


@pytest.fixture(scope="module")
def scene():
    return make_scene(5, curves=4, per_curve=150, blobs=900, sh_degree=1).cloud


def _check_counts(doc: dict, data: bytes) -> None:
    """The figures mean what they meant: they add up to the file that was written."""
    decoded = spcodec.decode_layers(data)
    assert doc["bytes"] == len(data) == doc["layer_ends"][-1]
    assert doc["sketch_gaussians"] + doc["patch_gaussians"] == len(decoded.cloud)
    assert doc["patch_layers"] == len(decoded.layers) - 1
    assert sum(doc["sections"].values()) <= len(data)
    assert json.loads(json.dumps(doc)) == doc  # plain JSON all through


def test_a_plain_encode_writes_the_document_it_always_wrote(scene):
    result = encode(scene, FAST)
    doc = result.stats.to_json()
    assert list(doc) == HEAD + ["sketch_error"]
    assert list(doc["sketch"]) == SKETCH and doc["sketch"]["clusters_encoded"] > 0
    assert list(doc["sketch"]["refine"]) == ["patch_by_reason", "splits", "fits"]
    assert list(doc["sketch_error"]) == ["position_rel_diameter", "log_scale_abs", "rotation_deg",
                                         "opacity_abs", "color_dc_abs"]
    _check_counts(doc, result.data)
    assert doc["sketch"]["moved_to_patch_for_share"] == result.stats.sketch.moved_to_patch_for_share


def test_a_sized_encode_adds_rate_controls_record_after_the_seconds(scene):
    result = encode(scene, dataclasses.replace(FAST, target_size=12_000))
    doc = result.stats.to_json()
    assert list(doc) == HEAD + ["rate", "sketch_error"]
    assert doc["rate"] is result.stats.rate and doc["rate"]["target_bytes"] == 12_000
    _check_counts(doc, result.data)


def test_without_sketch_the_sketch_record_is_the_short_one(scene):
    result = encode(scene, dataclasses.replace(FAST, use_sketch=False))
    doc = result.stats.to_json()
    assert doc["sketch"] == {"clusters_found": 0, "clusters_accepted": 0,
                             "moved_to_patch_for_share": 0}
    assert doc["sketch_error"] == {} and doc["sketch_gaussians"] == 0


def test_the_stats_file_is_the_document_with_the_command_lines_additions(tmp_path, scene):
    ply, out, stats = tmp_path / "in.ply", tmp_path / "out.spc", tmp_path / "stats.json"
    spcodec.write_ply(ply, scene)
    assert main(["encode", str(ply), "-o", str(out), "--no-retrain", "--quiet",
                 "--stats", str(stats)]) == 0
    doc = json.loads(stats.read_text())
    # a no-retrain preset is a point of the curve (DECISIONS D-33): its sizing's record is "rate"
    assert list(doc) == HEAD + ["rate", "sketch_error", "input_bytes", "output"]
    assert doc["rate"]["preset_point"] and doc["rate"]["precision"]["preset_bytes"] > 0
    assert doc["input_bytes"] == ply.stat().st_size and doc["output"] == str(out)
    _check_counts(doc, out.read_bytes())


@pytest.mark.training
def test_a_retrained_encode_keeps_its_retraining_and_evaluation_keys(scene):
    result = encode(scene, EncoderConfig(seed=3, retrain=QUICK, evaluate=False))
    doc = result.stats.to_json()
    assert list(doc) == HEAD + ["psnr_input", "retrain", "sketch_error", "evaluation"]
    retrain = doc["retrain"]
    assert [key for key in retrain if key not in ("psnr_snapped", "snap")] == RETRAIN
    assert retrain["psnr_finished"] == result.stats.retrain.psnr_finished
    assert list(retrain["estimate"]) == ["targets", "training", "evaluation", "total"]
    assert retrain["estimate"]["evaluation"] is None  # evaluate=False: no evaluation estimated
    assert doc["evaluation"] == {"skipped": True, "eval_options": []}
    _check_counts(doc, result.data)


_OPTIONAL = {
    "nested_layers": st.lists(st.integers(0, 10**6), min_size=1, max_size=4),
    "psnr_before": st.floats(0, 60), "psnr_snapped": st.floats(0, 60),
    "snap": st.builds(SnapDecision, st.floats(-5, 5), st.booleans()),
    "retrain_seconds": st.floats(0, 1e4), "psnr_retrained": st.floats(0, 60),
    "fitted_when_snapping": st.tuples(st.integers(0, 10**6), st.integers(0, 10**6)),
    "psnr_quantized": st.floats(0, 60), "psnr_finished": st.floats(0, 60),
    "finish_seconds": st.floats(0, 1e4),
    "prefix_psnr": st.lists(st.fixed_dictionaries({"layer": st.integers(1, 8),
                                                    "psnr": st.floats(0, 60)}), min_size=1),
    "estimate": st.fixed_dictionaries({"targets": st.floats(0, 1e4), "training": st.floats(0, 1e4),
                                       "evaluation": st.none() | st.floats(0, 1e4),
                                       "total": st.floats(0, 1e4)}),
}


@given(st.fixed_dictionaries({}, optional=_OPTIONAL))
def test_retraining_writes_exactly_the_figures_it_measured_in_field_order(figures):
    stats = RetrainStats("importance", **figures)
    doc = stats.to_json()
    order = [f.name for f in dataclasses.fields(RetrainStats)]
    assert list(doc) == [name for name in order if name == "prune" or name in figures]
    assert json.loads(json.dumps(doc)) == doc
    if "fitted_when_snapping" in figures:
        before, after = figures["fitted_when_snapping"]
        assert doc["fitted_when_snapping"] == {"from": before, "to": after}
    if "snap" in figures:
        assert doc["snap"] == {"loss_db": figures["snap"].loss_db,
                               "snapped": figures["snap"].snapped}


@given(st.integers(0, 10**6), st.booleans())
def test_the_sketch_record_names_a_drop_only_when_there_was_one(moved, dropped):
    doc = SketchStats(3, 2, moved_to_patch_for_share=moved,
                      dropped_for_precision=dropped).to_json()
    assert doc["moved_to_patch_for_share"] == moved
    assert doc.get("dropped_for_precision", False) is dropped
    assert list(doc)[:2] == ["clusters_found", "clusters_accepted"]


def test_jobs_bounds_every_thread_pool_of_the_patch_encoder(scene, monkeypatch):
    """``n_jobs`` (``--jobs``) is the encoder's thread count all through: the patch encoder's
    codebooks, importance and index contexts ran on the cores available whatever it said, so a
    tileset's single-job node encodes took a second core each. The file does not depend on it."""
    from spcodec.encoder import contexts, patch

    seen = []
    choose = contexts.choose_index_contexts

    def spy(*args, jobs=None, **kwargs):
        seen.append(jobs)
        return choose(*args, jobs=jobs, **kwargs)

    monkeypatch.setattr(patch, "choose_index_contexts", spy)
    monkeypatch.setattr(contexts, "RECENT", contexts.RecentChoices(4096))
    one = encode(scene, dataclasses.replace(FAST, n_jobs=1))
    assert seen and set(seen) == {1}
    jobs = []
    monkeypatch.setattr(patch.PatchEncoder, "_map", lambda self, fn, items: (
        jobs.append(self.jobs), [fn(item) for item in items])[1])
    assert encode(scene, dataclasses.replace(FAST, n_jobs=1)).data == one.data
    assert jobs and set(jobs) == {1}
    assert encode(scene, dataclasses.replace(FAST, n_jobs=2)).data == one.data
    assert set(jobs) == {1, 2}
