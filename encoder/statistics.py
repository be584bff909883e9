"""The record of an encode, typed: what :func:`.pipeline.encode` returns beside the file and what
``spcodec encode --stats`` writes.

Each stage fills its own part (the sketch stage :class:`SketchStats`, retraining
:class:`RetrainStats`, the closing evaluation :class:`Quality`), so a reader finds a figure by
attribute instead of by a key that some other module spelled. ``to_json()`` gives the ``--stats``
document: the bench scripts and the tests read its keys, so a field that is unset (None) is left
out rather than written as null, as the dicts before these types did.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


def _present(**items: Any) -> dict:
    """``items`` without those that are None, in their order."""
    return {key: value for key, value in items.items() if value is not None}


@dataclass
class SketchStats:
    """What the sketch stage did: clusters found by categorization and accepted by refinement,
    and (with clusters to encode) the sketch encoder's outcome."""

    clusters_found: int
    clusters_accepted: int
    clusters_encoded: int | None = None
    draco_step: float | None = None
    scene_diameter: float | None = None
    counts: dict[str, int] = field(default_factory=dict)
    """The sketch encoder's counts (duplicates and rejected clusters sent back to the patch)."""
    refine: dict | None = None
    """Refinement's record: Gaussians sent to the patch by reason, splits, fits."""
    moved_to_patch_for_share: int | None = None
    """Gaussians of clusters moved to the patch for the cap on the sketch layer's share."""
    dropped_for_precision: bool = False
    """The sketch was dropped: its models cost more picture than their bytes buy as precision."""

    def to_json(self) -> dict:
        return {**_present(clusters_found=self.clusters_found,
                           clusters_accepted=self.clusters_accepted,
                           clusters_encoded=self.clusters_encoded, draco_step=self.draco_step,
                           scene_diameter=self.scene_diameter),
                **self.counts,
                **_present(refine=self.refine,
                           moved_to_patch_for_share=self.moved_to_patch_for_share,
                           dropped_for_precision=self.dropped_for_precision or None)}


@dataclass
class SnapDecision:
    """What quantizing cost the training views when snapping was to start, and whether it did."""

    loss_db: float
    snapped: bool

    def to_json(self) -> dict:
        return {"loss_db": self.loss_db, "snapped": self.snapped}


@dataclass
class RetrainStats:
    """What retraining measured, stage by stage (PSNR on the training views, seconds); a figure
    of a stage that did not run (a resumed run past it, a finish of no steps) stays None."""

    prune: str
    nested_layers: list[int] | None = None
    """Nested retraining: where each layer fixed before training ends among the survivors."""
    psnr_before: float | None = None
    psnr_snapped: float | None = None
    snap: SnapDecision | None = None
    retrain_seconds: float | None = None
    psnr_retrained: float | None = None
    fitted_when_snapping: tuple[int, int] | None = None
    """Rate control's fit when snapping started: survivors before and after."""
    psnr_quantized: float | None = None
    psnr_finished: float | None = None
    finish_seconds: float | None = None
    prefix_psnr: list[dict] | None = None
    """``{"layer": K, "psnr": dB}`` per file prefix that ends at a non-empty layer."""
    estimate: dict | None = None
    """The run's first estimate in seconds (``targets``, ``training``, ``evaluation``,
    ``total``), kept so that a benchmark can compare it with the stages' measured seconds."""

    @property
    def finish_gain(self) -> float:
        """dB the quantization-aware finish won back over the quantized patch."""
        finished = self.psnr_finished if self.psnr_finished is not None else self.psnr_quantized
        return finished - self.psnr_quantized

    @property
    def whole_psnr(self) -> float | None:
        """PSNR of the whole file on the training views, as the run last measured it."""
        if self.prefix_psnr:
            return self.prefix_psnr[-1]["psnr"]
        return self.psnr_finished if self.psnr_finished is not None else self.psnr_quantized

    def to_json(self) -> dict:
        fitted = None if self.fitted_when_snapping is None else \
            dict(zip(("from", "to"), self.fitted_when_snapping))
        return _present(
            prune=self.prune, nested_layers=self.nested_layers, psnr_before=self.psnr_before,
            psnr_snapped=self.psnr_snapped,
            snap=None if self.snap is None else self.snap.to_json(),
            retrain_seconds=self.retrain_seconds, psnr_retrained=self.psnr_retrained,
            fitted_when_snapping=fitted, psnr_quantized=self.psnr_quantized,
            psnr_finished=self.psnr_finished, finish_seconds=self.finish_seconds,
            prefix_psnr=self.prefix_psnr or None, estimate=self.estimate)


@dataclass
class Closeup:
    """The closing evaluation at one close-up framing."""

    distance: float
    psnr: float
    ssim: float
    width: int
    height: int

    def to_json(self) -> dict:
        return {"distance": self.distance, "psnr": self.psnr, "ssim": self.ssim,
                "width": self.width, "height": self.height}


@dataclass
class Quality:
    """The written file's quality as ``spcodec eval`` measures it (:func:`.pipeline.judge`)."""

    psnr: float
    ssim: float
    lpips: float | None
    views: int
    width: int
    height: int
    closeups: list[Closeup]
    against: str
    """What the file was judged against, in words."""

    def to_json(self) -> dict:
        return {"psnr": self.psnr, "ssim": self.ssim, "lpips": self.lpips, "views": self.views,
                "width": self.width, "height": self.height,
                "closeups": [c.to_json() for c in self.closeups], "against": self.against}


@dataclass
class SkippedEvaluation:
    """The closing evaluation was turned off: the ``spcodec eval`` options that measure it."""

    eval_options: list[str]

    def to_json(self) -> dict:
        return {"skipped": True, "eval_options": self.eval_options}


@dataclass
class PreviewStats:
    """The preview stored before the scene (spec 1.1)."""

    bytes: int
    takeover_layer: int
    psnr: float | None
    gaussians: int
    quality: Quality | None

    def to_json(self) -> dict:
        return {"bytes": self.bytes, "takeover_layer": self.takeover_layer, "psnr": self.psnr,
                "gaussians": self.gaussians,
                "quality": None if self.quality is None else self.quality.to_json()}


@dataclass
class EncodeStats:
    """Everything a report needs of one encode."""

    gaussians: int
    sketch_gaussians: int
    patch_gaussians: int
    patch_layers: int
    sketch: SketchStats
    bytes: int
    sections: dict[str, int]
    """Stored bytes per section type."""
    layer_ends: list[int]
    """Where each layer of the file ends, in stored bytes."""
    seconds: dict[str, float]
    """Seconds per stage."""
    psnr_input: float | None = None
    """PSNR of the input against the retraining targets (the mismatch check's figure)."""
    sizing: dict = field(default_factory=dict)
    """What rate control (``rate``) or quality control (``quality_target``) decided, as
    :meth:`.sizing.Sizing.stats` records it."""
    retrain: RetrainStats | None = None
    sketch_error: dict[str, dict[str, float]] = field(default_factory=dict)
    """Errors of the decoded sketch Gaussians against their originals, per attribute."""
    evaluation: SkippedEvaluation | None = None
    quality: Quality | None = None
    preview: PreviewStats | None = None

    @property
    def rate(self) -> dict | None:
        """Rate control's record (None without a target size)."""
        return self.sizing.get("rate")

    @property
    def quality_target(self) -> dict | None:
        """Quality control's record (None without a target PSNR)."""
        return self.sizing.get("quality_target")

    def to_json(self) -> dict:
        """The ``--stats`` document."""
        return {
            "gaussians": self.gaussians, "sketch_gaussians": self.sketch_gaussians,
            "patch_gaussians": self.patch_gaussians, "patch_layers": self.patch_layers,
            "sketch": self.sketch.to_json(), "bytes": self.bytes, "sections": self.sections,
            "layer_ends": self.layer_ends, "seconds": self.seconds,
            **_present(psnr_input=self.psnr_input), **self.sizing,
            **_present(retrain=None if self.retrain is None else self.retrain.to_json()),
            "sketch_error": self.sketch_error,
            **_present(evaluation=None if self.evaluation is None else self.evaluation.to_json(),
                       quality=None if self.quality is None else self.quality.to_json(),
                       preview=None if self.preview is None else self.preview.to_json()),
        }
