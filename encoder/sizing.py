"""How many patch Gaussians a file keeps: the one owner of rate and quality control.

The patch stage and the retraining stage ask a :class:`Sizing` where they used to branch on
``config.target_size`` and ``config.target_psnr`` themselves. There are four:

* :class:`FactorSizing`: no target; keep ``1 / patch_downsample`` of the patch (all of it
  without retraining);
* :class:`SizeTarget`: ``--target-size``, by :mod:`.ratecontrol` on real writes;
* :class:`QualityTarget`: ``--target-psnr``, by :mod:`.qualitycontrol` on real renders;
* :class:`PresetPoint`: no target and no retraining: the bytes the precision search predicts
  for the preset's codebooks, spent by it.

Each answers the same questions at the same points of an encode: how many to keep before any
training (:meth:`Sizing.plan`), which rows of a quantized patch to keep (:meth:`Sizing.fit`,
after retraining, and :meth:`Sizing.snap_fit` while snapping), and whether a written file must
lose more (:meth:`Sizing.overflows`). What each decided goes into the encode statistics under
its own key (:meth:`Sizing.stats`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable

import numpy as np

from spcodec.cloud import GaussianCloud
from spcodec.decoder import decode_layers
from spcodec.errors import UsageError
from spcodec.imaging.cache import default_cache_dir
from spcodec.imaging.sensitivity import Sensitivity

from .allocation import (
    Allocation,
    PrecisionSearch,
    framing_renders,
    patch_sensitivity,
    position_options,
    training_framings,
)
from .config import EncoderConfig, PatchConfig
from .patch import PatchEncoder, PatchEncoding, Quantized
from .prune import kept_count, prune_by_importance
from .qualitycontrol import (
    QualityPlan,
    TargetJudge,
    check_reachable,
    fewest_reaching,
    smallest_reaching,
)
from .ratecontrol import FIT_SLACK, SNAP_MARGIN, TOLERANCE, TRAIN_MARGIN, fit_count, plan_count
from .stages import SceneWriter, SketchOutcome

LANDING_TRIES = 3
"""Searches a quality target makes at most, each ending with one judgement at the evaluation's
resolution (:meth:`QualityTarget.landed`)."""

PRUNED_STEPS = 5
"""Below the preset's file, the steps from the preset's pruned count to every Gaussian: the
counts between, spaced geometrically, each at the precision that would fit it, are also tried
pruned to the target (:meth:`SizeTarget._best_below`). Two counts between left donut's curve a
kink of 2 dB for 2 % of bytes at 0.4x SPZ; four gained up to 1.9 dB there and 0.4-1.0 dB on
scenes held out, for a few CPU seconds more (docs/LOG.md)."""

ALLOCATION_TRIALS = 4
"""Real writes the precision search may make to land its allocation under the target."""

DECISIVE_DB = 1.0
"""How far (dB at the training views) every Gaussian at a coarser precision must have beaten the
preset's file pruned to the target, in an encode with the sketch, for the encode made again
without it to take that verdict instead of rendering both files again."""

RowFit = Callable[[GaussianCloud, Quantized, np.ndarray], "np.ndarray | None"]
"""``(cloud, quantized, importance) -> rows to keep`` (None: all of them)."""


class Sizing:
    """No target: the retrain config's downsample factor decides, and nothing is trimmed."""

    def __init__(self, config: EncoderConfig, original: GaussianCloud | None = None,
                 device: str = "auto") -> None:
        self.config = config
        self.original, self.device = original, device
        self.record: dict = {}
        self.sensitivity: dict[str, Sensitivity] | None = None
        self.sensitivity_of: GaussianCloud | None = None
        """The cloud :attr:`sensitivity` was taken of."""
        self.renders: tuple[GaussianCloud, dict[str, list[np.ndarray]]] | None = None
        """A cloud and its :func:`framing_renders`, the reference of rendered comparisons."""

    def plan(self, patch: GaussianCloud, weights: np.ndarray, writer: SceneWriter,
             encoder: PatchEncoder, rows: np.ndarray | None = None) -> int:
        """How many of ``patch`` (ranked by ``weights``; ``rows`` of the input scene) to keep
        before any training."""
        retrain = self.config.retrain
        return len(patch) if retrain is None else kept_count(len(patch), retrain.patch_downsample)

    def encoder_for(self, encoder: PatchEncoder) -> PatchEncoder:
        """The patch encoder to quantize with (a target fixes the codebooks' sizes)."""
        return encoder

    def snap_fit(self, writer: SceneWriter, encoder: PatchEncoder) -> RowFit | None:
        """Rate control while retraining snaps to codebooks (None: none)."""
        return None

    def fit(self, writer: SceneWriter, encoder: PatchEncoder, cloud: GaussianCloud,
            quantized: Quantized, importance: np.ndarray) -> np.ndarray | None:
        """Rows of a quantized ``cloud`` to keep (None: all), most important first."""
        return None

    def overflows(self, writer: SceneWriter, encoding: PatchEncoding) -> bool:
        """Whether the file ``writer`` makes of ``encoding`` is over the target."""
        return False

    def drops_sketch(self, cloud: GaussianCloud, sketch: SketchOutcome, writer: SceneWriter,
                     encoding: PatchEncoding) -> bool:
        """Whether the file is better without its sketch, every Gaussian patch (``encoding``:
        the patch encoded beside it)."""
        return False

    def trimmed(self) -> None:
        """Note that the written file had to lose Gaussians after its fit."""

    def inherit(self, earlier: "Sizing") -> None:
        """Take over what an earlier sizing of the same scene measured (an encode made again
        without its sketch): the sensitivity of the whole scene, the same renders."""
        if earlier.sensitivity is not None:
            self.sensitivity, self.sensitivity_of = earlier.sensitivity, earlier.sensitivity_of
        self.renders = earlier.renders

    def reference(self, scene: GaussianCloud) -> dict[str, list[np.ndarray]]:
        """``scene`` rendered at the search's framings, made once per scene (and shared with a
        later sizing, :meth:`inherit`)."""
        if self.renders is None or self.renders[0] is not scene:
            self.renders = (scene, framing_renders(scene, self.config, self.config.allocation,
                                                   self.device))
        return self.renders[1]

    def stats(self) -> dict:
        """What was decided, for the encode statistics."""
        return dict(self.record)

    def precision_search(self, patch: GaussianCloud, weights: np.ndarray, encoder: PatchEncoder,
                         rows: np.ndarray | None) -> PrecisionSearch:
        """Every precision option of ``patch`` measured (:mod:`.allocation`), against the
        sensitivity of the whole input scene when ``rows`` place the patch in it (the sketch
        occludes), taken once per sizing and shared with a later one (:meth:`inherit`)."""
        config = self.config.allocation
        scene = self.original if self.original is not None and rows is not None else patch
        if self.sensitivity is None or self.sensitivity_of is not scene:
            # its forward passes are the reference renders at the same framings (a drawing
            # pass differs from them by float rounding only, D-36)
            self.sensitivity, pictures = patch_sensitivity(scene, self.config, config,
                                                           self.device)
            self.sensitivity_of, self.renders = scene, (scene, pictures)
        framings = self.sensitivity if scene is patch else \
            {name: s.subset(rows) for name, s in self.sensitivity.items()}
        search = PrecisionSearch.measure(patch, framings, encoder.kmeans_weights(weights),
                                         encoder.config, self.config.seed, config, encoder.jobs)
        if not config.position_bits or encoder.config.position_mode not in ("draco", "quant16"):
            return search
        placed = rows if scene is not patch else np.arange(len(patch))
        return search.with_positions(position_options(
            scene, placed, dataclasses.replace(self.config, patch=encoder.config), config,
            self.device, self.reference(scene)))


class FactorSizing(Sizing):
    """The default: no size or quality asked (see :class:`Sizing`)."""


class PrecisionSizing(Sizing):
    """A sizing that may choose the patch's precision from the precision search: the chosen
    allocation (:attr:`chosen`, of :attr:`search`) sets the codebooks the patch is quantized
    with (:meth:`encoder_for`); none chosen, the preset's own."""

    def __init__(self, config: EncoderConfig, original: GaussianCloud | None = None,
                 device: str = "auto") -> None:
        super().__init__(config, original, device)
        self.allocated: PatchConfig | None = None
        self.search: PrecisionSearch | None = None
        self.chosen: Allocation | None = None

    def adopt(self, search: PrecisionSearch, chosen: Allocation, encoder: PatchEncoder) -> dict:
        """Quantize with ``chosen``; returns what the statistics record of the choice."""
        self.allocated = chosen.patch_config(encoder.config)
        self.search, self.chosen = search, chosen
        return {"options": chosen.describe(), "predicted_distortion": chosen.distortion,
                "predicted_distortions": {a: o.distortion for a, o in chosen.options.items()}}

    def encoder_for(self, encoder: PatchEncoder) -> PatchEncoder:
        if self.allocated is None:
            return encoder
        return PatchEncoder(self.allocated, seed=encoder.seed, jobs=encoder.jobs)

    def drops_sketch(self, cloud: GaussianCloud, sketch: SketchOutcome, writer: SceneWriter,
                     encoding: PatchEncoding) -> bool:
        """Whether the sketch costs more picture than its bytes buy as precision: its predicted
        error (the linearized renderer, as every option's) against the marginal rate of the
        precision curve at the chosen point times the bytes the sketch saves (its Gaussians as
        patch at the chosen precision and at the patch's bytes of position per Gaussian, less
        the sketch's own sections)."""
        if self.chosen is None or self.sensitivity is None or not sketch.sources:
            return False
        sources = np.concatenate(sketch.sources)
        decoded = writer.decoded_sketch()
        weight = self.config.allocation.linearized_weights()
        error = sum(weight.get(name, 1.0) * float(s.subset(sources).mse(
            cloud.subset(sources), decoded).sum()) for name, s in self.sensitivity.items())
        sections = writer.write_file(encoding).layout.section_bytes()
        sketch_bytes = sum(n for kind, n in sections.items() if kind.startswith("SKETCH"))
        patch_count = max(sum(len(layer) for layer in encoding.layers), 1)
        positions = 0 if "POSITION" in self.chosen.options else sections.get("PATCH_POSITIONS", 0)
        per_gaussian = (self.chosen.bytes + positions) / patch_count
        saved = len(sources) * per_gaussian - sketch_bytes
        slope = self.search.slope_at(self.chosen)
        decision = {"sketch_distortion": error, "bytes_saved": round(saved),
                    "marginal_distortion_per_byte": slope, "dropped": error > slope * saved}
        self.record["rate"]["sketch"] = decision
        return decision["dropped"]


class SizeTarget(PrecisionSizing):
    """``--target-size``: a file of at most ``config.target_size`` bytes.

    With retraining, and without ``config.allocation``, the least important patch Gaussians are
    dropped until the file fits. Without retraining and with ``config.allocation`` set, every
    Gaussian stays above the preset's file: the rate-distortion search (:mod:`.allocation`)
    picks each attribute's codebook for the bytes left, finer than the preset's. Below it,
    every Gaussian at a coarser precision competes on renders with fewer Gaussians at
    precisions between and with the preset's file pruned to the target. A target the preset's
    own file already fills (within the fit's slack) is left to it."""

    def __init__(self, config: EncoderConfig, original: GaussianCloud | None = None,
                 device: str = "auto") -> None:
        super().__init__(config, original, device)
        self.target = int(config.target_size or 0)
        self.predicted_count: int | None = None
        self.inherited: PrecisionSearch | None = None
        """The search an earlier size target of the same scene measured (:meth:`inherit`)."""
        self.verdict: tuple[float, float] | None = None
        """Training-view PSNR of the allocated file and of the pruned one, when compared."""
        self.inherited_verdict: tuple[float, float] | None = None
        """The verdict of an earlier size target of the same scene (:meth:`inherit`)."""
        self.allocated_count = 0
        """How many patch Gaussians the allocated precision keeps."""
        self.planned: tuple[int, bytes] | None = None
        """The planner's file at the count it chose (the pruned file a precision is compared
        with: writing it again repeats the planner's quantization)."""

    def inherit(self, earlier: Sizing) -> None:
        """Also the earlier target's precision search: re-encoding without the sketch, the
        patch gains the sketch's Gaussians, and its options are rescaled to them
        (:meth:`PrecisionSearch.rescaled`) rather than measured again."""
        super().inherit(earlier)
        if isinstance(earlier, SizeTarget) and earlier.search is not None:
            self.inherited = earlier.search
            self.inherited_verdict = earlier.verdict

    def plan(self, patch: GaussianCloud, weights: np.ndarray, writer: SceneWriter,
             encoder: PatchEncoder, rows: np.ndarray | None = None) -> int:
        retrain = self.config.retrain
        nearest: dict[int, bytes] = {}
        # without retraining the trial's file is the one written: plan it to the fit's slack
        plan = plan_count(self.target, len(patch),
                          _trial(writer, encoder, patch, weights, self.target, nearest),
                          TOLERANCE if retrain is not None else FIT_SLACK)
        self.planned = (plan.count, nearest[plan.count]) if plan.count in nearest else None
        self.record["rate"] = {"target_bytes": self.target, "predicted_bytes":
                               plan.predicted_bytes, "fixed_bytes": plan.fixed_bytes,
                               "unpruned_bytes": plan.full_bytes, "predicted_count": plan.count}
        if plan.note:
            self.record["rate"]["note"] = plan.note
        self.predicted_count = plan.count
        if self.config.keep_all and plan.count < len(patch):
            raise UsageError(
                f"target size {self.target:,} bytes is below this preset's file with every "
                f"Gaussian kept ({plan.full_bytes:,} bytes), and it never drops one: ask for at "
                f"least {plan.full_bytes:,} bytes, or use another preset, whose rate control "
                "prunes the least important")
        if retrain is None:
            if self.config.allocation is not None and not self.config.keep_all and \
                    not plan.full_bytes * (1 - FIT_SLACK) <= self.target <= plan.full_bytes:
                self.allocate(patch, weights, writer, encoder, plan.full_bytes, rows, plan.count)
                if self.allocated is not None:
                    return self.allocated_count
            return plan.count
        margin = TRAIN_MARGIN if retrain.snap_step is None else SNAP_MARGIN
        return min(len(patch), math.ceil(plan.count * (1 + margin)))

    def allocate(self, patch: GaussianCloud, weights: np.ndarray, writer: SceneWriter,
                 encoder: PatchEncoder, full_bytes: int, rows: np.ndarray | None,
                 pruned_count: int) -> None:
        """Choose the precision that fills the target: above the preset's file, every
        Gaussian at the precision predicted to beat the preset's; below it, every Gaussian at
        a coarser precision, fewer at one between, or the preset's file pruned to
        ``pruned_count``, whichever renders closest to the input (:meth:`_best_below`:
        pruning is no small change, which the model cannot predict)."""
        start = time.perf_counter()
        search = self.precision_search(patch, weights, encoder, rows) if self.inherited is None \
            else self.inherited.rescaled(len(patch))
        preset = search.matching(encoder.config.entry_dims, encoder.config.stored_position_bits)
        other = full_bytes - preset.bytes  # positions, headers, the sketch: what stays as it is
        aim = self.target * (1 - FIT_SLACK)
        chosen, written, ratio, tried, data = None, None, 1.0, None, None
        over: tuple[Allocation, int] | None = None  # the smallest trial over the target, its size
        measured: list[tuple[float, int]] = []  # (predicted option bytes, file bytes) per trial
        for _ in range(ALLOCATION_TRIALS):
            # entropy predicts the index bytes to within the coder's context gains, which the
            # real writes measure: each trial corrects the budget by the earlier ones' misses
            candidate = search.for_bytes((aim - other) / ratio)
            if candidate == tried and written is not None and \
                    written < self.target * (1 - 3 * FIT_SLACK):
                # a gap in the curve at the aim: the next allocation up may fit the target itself
                candidate = search.for_bytes((self.target - other) / ratio)
            if candidate is None or candidate == tried or \
                    (full_bytes <= self.target and candidate.distortion >= preset.distortion):
                break
            tried = candidate
            trial = pruned_file(writer, _coder(candidate, encoder), patch, weights, len(patch))
            size = trial.size
            if size <= self.target and (written is None or size > written):
                chosen, written, data = candidate, size, trial.data
            if size > self.target and (over is None or size < over[1]):
                over = (candidate, size)
            if self.target * (1 - 3 * FIT_SLACK) <= size <= self.target:
                break
            measured.append((candidate.bytes, size))
            other, ratio = _size_line(measured, other)
        record = {"preset_distortion": preset.distortion}
        count, size = len(patch), written
        if full_bytes > self.target:
            chosen, count, data = self._best_below(search, preset, chosen, data,
                                                   (aim - other) / ratio,
                                                   writer, encoder, patch, weights,
                                                   pruned_count, record)
            size = None if data is None else len(data)
        elif written is not None and written < self.target * (1 - 3 * FIT_SLACK):
            if over is None:  # the trials stopped short of the gap: the curve's next points
                chosen, written, data, over = self._up_the_curve(search, chosen, written, data,
                                                                 writer, encoder, patch, weights)
            if over is not None and written < self.target * (1 - 3 * FIT_SLACK):
                chosen, count, data = self._fill_gap(chosen, data, *over, writer, encoder,
                                                     patch, weights, record)
            size = len(data)
        record["seconds"] = round(time.perf_counter() - start, 2)
        if chosen is not None:
            record.update(self.adopt(search, chosen, encoder))
            self.allocated_count = count
            self.record["rate"].update(predicted_bytes=size, predicted_count=count)
            self.record["rate"].pop("note", None)
        self.record["rate"]["precision"] = record

    def _best_below(self, search: PrecisionSearch, preset: Allocation, every: Allocation | None,
                    data: bytes | None, budget: float, writer: SceneWriter, encoder: PatchEncoder,
                    patch: GaussianCloud, weights: np.ndarray, pruned_count: int, record: dict
                    ) -> tuple[Allocation | None, int, bytes | None]:
        """Below the preset's file, the file that renders closest to the input
        (:meth:`_render_psnr`) of: every Gaussian at the precision that fits (``every``, None
        when none does), the preset's precision pruned to ``pruned_count``, and between them
        the precisions that would fit counts between those two (:data:`PRUNED_STEPS`), each
        pruned to the target. Returns the allocation (None: the preset's), how many it keeps
        and its file.

        Pruning drops a Gaussian whole and a coarse codebook moves every one a little; the
        linearized model prices the latter only, and near the curve's coarse end its
        predictions fail by several dB, so the trade is judged on renders. An encode made
        again takes the first one's verdict where every Gaussian won by :data:`DECISIVE_DB`."""
        earlier = self.inherited_verdict
        if every is not None and earlier is not None and earlier[0] - earlier[1] >= DECISIVE_DB:
            # an encode made again without its sketch weighs the same precision against the
            # same pruning at the same target; the sketch's Gaussians, coded alike in both
            # files, shifted both scores, and rendering every file again is a sizeable part of
            # a size target's time
            self.verdict = earlier
            record["training_view_psnr"] = {"every_gaussian": round(earlier[0], 3),
                                            "pruned": round(earlier[1], 3),
                                            "from": "the encode with the sketch"}
            return every, len(patch), data
        candidates = [(every, len(patch), data)] if every is not None else []
        for step in range(1, PRUNED_STEPS):
            share = (max(pruned_count, 1) / len(patch)) ** (1 - step / PRUNED_STEPS)
            between = search.for_bytes(budget / share)
            if between is None or between == preset or any(between == c[0] for c in candidates):
                continue
            count, file = self._pruned_to_target(
                writer, _coder(between, encoder), patch, weights,
                keep=lambda n: pruned_count < n < len(patch))
            if file is not None:
                candidates.append((between, count, file))
        if not candidates:
            return None, pruned_count, None
        planned = self.planned
        candidates.append((None, pruned_count, planned[1] if planned is not None and
                           planned[0] == pruned_count else
                           pruned_file(writer, encoder, patch, weights, pruned_count).data))
        scores = self._render_psnr([file for _, _, file in candidates])
        record["candidates"] = [
            {"options": "preset" if allocation is None else allocation.describe(),
             "gaussians": count, "bytes": len(file), "training_view_psnr": round(score, 3)}
            for (allocation, count, file), score in zip(candidates, scores)]
        best = max(range(len(candidates)), key=lambda i: scores[i])
        # an encode made again may take this verdict only where it was every Gaussian or none
        self.verdict = (scores[0], scores[-1]) if every is not None and \
            best in (0, len(candidates) - 1) else None
        return candidates[best]

    def _up_the_curve(self, search: PrecisionSearch, chosen: Allocation, written: int, data: bytes,
                      writer: SceneWriter, encoder: PatchEncoder, patch: GaussianCloud,
                      weights: np.ndarray
                      ) -> tuple[Allocation, int, bytes, tuple[Allocation, int] | None]:
        """The curve's points above ``chosen`` (whose file of ``written`` bytes is ``data``),
        each written with every Gaussian while it fits and the file is more than 3 % under the
        target: ``(chosen, written, data, over)``, ``over`` the first point whose file did not
        fit and that file's size (None: none was written, or the target is reached)."""
        curve = search.curve()
        for _ in range(ALLOCATION_TRIALS):
            up = next((a for a in curve if a.bytes > chosen.bytes), None)
            if up is None or written >= self.target * (1 - 3 * FIT_SLACK):
                break
            trial = pruned_file(writer, _coder(up, encoder), patch, weights, len(patch))
            if trial.size > self.target:
                return chosen, written, data, (up, trial.size)
            chosen, written, data = up, trial.size, trial.data
        return chosen, written, data, None

    def _fill_gap(self, every: Allocation, data: bytes, over: Allocation, over_size: int,
                  writer: SceneWriter, encoder: PatchEncoder, patch: GaussianCloud,
                  weights: np.ndarray, record: dict) -> tuple[Allocation, int, bytes]:
        """Above the preset's file, a gap in the curve at the target: the allocation that fits,
        every Gaussian kept (``every``, its file ``data``), lands more than 3 % under it and the
        next one tried (``over``, whose file of every Gaussian took ``over_size`` bytes) over it.
        Also the latter pruned to the target, and whichever of the two renders closer to the
        input (:meth:`_render_psnr`) is kept: biker's colours step from a 256-entry vector
        codebook to their 136 exact values, 8 % more bytes and 6 dB, with nothing on the curve
        between (docs/LOG.md 28.4). Returns the allocation, how many it keeps and its file."""
        count, pruned = self._pruned_to_target(writer, _coder(over, encoder), patch, weights,
                                               keep=lambda n: n < len(patch),
                                               full_size=over_size)
        if pruned is None:
            return every, len(patch), data
        scores = self._render_psnr([data, pruned])
        record["gap"] = [
            {"options": allocation.describe(), "gaussians": kept, "bytes": len(file),
             "training_view_psnr": round(score, 3)}
            for allocation, kept, file, score in ((every, len(patch), data, scores[0]),
                                                  (over, count, pruned, scores[1]))]
        return (over, count, pruned) if scores[1] > scores[0] else (every, len(patch), data)

    def _pruned_to_target(self, writer: SceneWriter, coder: PatchEncoder, patch: GaussianCloud,
                          weights: np.ndarray, keep: Callable[[int], bool],
                          full_size: int | None = None) -> tuple[int, bytes | None]:
        """How many of the most important patch Gaussians ``coder`` fits in the target
        (:func:`plan_count` on real writes) and, where ``keep`` accepts that count, their file
        (None otherwise). ``full_size``: the file of every Gaussian, when already written."""
        nearest: dict[int, bytes] = {}
        sized = _trial(writer, coder, patch, weights, self.target, nearest)
        size = sized if full_size is None else \
            (lambda n: full_size if n == len(patch) else sized(n))
        count = plan_count(self.target, len(patch), size, FIT_SLACK).count
        if not keep(count):
            return count, None
        return count, nearest[count] if count in nearest else \
            pruned_file(writer, coder, patch, weights, count).data

    def _render_psnr(self, files: list[bytes]) -> list[float]:
        """Mean PSNR (dB) of each file against the input over the search's training views,
        the close framing weighted as in its distortion. The mean of per-view dB, as eval and
        the viewer report it: a mean of MSEs let one close view with a hole outweigh seven
        where the file was far better (donut at SPZ/2, docs/LOG.md 17.2)."""
        from spcodec.imaging.metrics import psnr
        from spcodec.imaging.render import render_image

        config, original = self.config.allocation, self.original
        weight = config.framing_weights()
        cameras = [(weight[name], camera) for name, group in
                   training_framings(original, self.config, config).items() for camera in group]
        settings = self.config.render_settings((0.0, 0.0, 0.0))
        reference = [image for images in self.reference(original).values() for image in images]
        total = sum(w for w, _ in cameras)
        scores = []
        for data in files:
            cloud = decode_layers(data).cloud
            scores.append(sum(w * psnr(r, render_image(cloud, c, settings))
                              for (w, c), r in zip(cameras, reference)) / total)
        return scores

    def encoder_for(self, encoder: PatchEncoder) -> PatchEncoder:
        if self.allocated is not None:
            return super().encoder_for(encoder)
        if encoder.config.groups_per_entry is None or self.predicted_count is None:
            return encoder
        # the codebooks the plan sized the file with, whatever count training ends with
        return PatchEncoder(dataclasses.replace(encoder.config,
                                                codebooks_sized_for=self.predicted_count),
                            seed=encoder.seed, jobs=encoder.jobs)

    def snap_fit(self, writer: SceneWriter, encoder: PatchEncoder) -> RowFit:
        def fit(cloud: GaussianCloud, quantized: Quantized, importance: np.ndarray):
            top = self.rows_that_fit(writer, encoder, cloud, quantized, importance)
            return None if len(top) >= len(cloud) else top
        return fit

    def fit(self, writer: SceneWriter, encoder: PatchEncoder, cloud: GaussianCloud,
            quantized: Quantized, importance: np.ndarray) -> np.ndarray | None:
        return self.rows_that_fit(writer, encoder, cloud, quantized, importance)

    def rows_that_fit(self, writer: SceneWriter, encoder: PatchEncoder, cloud: GaussianCloud,
                      quantized: Quantized, importance: np.ndarray) -> np.ndarray:
        """The most important rows of ``cloud``, as many as :func:`fit_count` finds room for
        on real writes."""
        count, _ = fit_count(self.target, len(cloud),
                             _sized(writer, encoder, cloud, quantized, importance))
        return prune_by_importance(importance, count)

    def overflows(self, writer: SceneWriter, encoding: PatchEncoding) -> bool:
        return writer.write_file(encoding).size > self.target

    def trimmed(self) -> None:
        self.record["rate"]["trimmed"] = True


class PresetPoint(PrecisionSizing):
    """No target, without retraining, with ``config.allocation``: the preset as a point of the
    rate-distortion curve (DECISIONS D-33, D-34). Its codebook shapes set the bytes: the
    precision search's prediction of their option bytes with every Gaussian, the rate model
    that makes every other choice. The search spends them on the allocation predicted to render
    closest, every Gaussian kept; where none beats the preset's own precision, the preset's
    file is written. No file is written to find the bytes: the point lands within the
    prediction's error of the shapes' own file, and under it where their large vector codebooks
    compress or index contexts pay, which the prediction does not see."""

    def plan(self, patch: GaussianCloud, weights: np.ndarray, writer: SceneWriter,
             encoder: PatchEncoder, rows: np.ndarray | None = None) -> int:
        start = time.perf_counter()
        search = self.precision_search(patch, weights, encoder, rows)
        preset = search.matching(encoder.config.entry_dims, encoder.config.stored_position_bits)
        chosen = search.for_bytes(preset.bytes)
        record = {"preset_bytes": round(preset.bytes), "preset_distortion": preset.distortion}
        if chosen is not None and chosen.distortion < preset.distortion:
            record.update(self.adopt(search, chosen, encoder))
        record["seconds"] = round(time.perf_counter() - start, 2)
        self.record["rate"] = {"preset_point": True, "predicted_count": len(patch),
                               "precision": record}
        return len(patch)


class QualityTarget(PrecisionSizing):
    """``--target-psnr``: the smallest file whose close-up reaches ``config.target_psnr``.

    With retraining, or without ``config.allocation``, the knob is how many patch Gaussians
    survive (:mod:`.qualitycontrol`). Without retraining and with ``config.allocation`` set, it
    is first the precision: the points of the rate-distortion curve (:mod:`.allocation`), every
    Gaussian kept, are judged on real files, bisected for the smallest that reaches the target;
    only a target the coarsest point already exceeds prunes, at that precision."""

    def __init__(self, config: EncoderConfig, original: GaussianCloud, device: str) -> None:
        super().__init__(config, original, device)
        self.target = float(config.target_psnr)
        self.judge = TargetJudge(original, up=config.up, antialiased=config.antialiased,
                                 device=device, cache=default_cache_dir())
        self.allocated_psnr = math.nan
        """The close-up PSNR of the allocated point's file, every patch Gaussian kept."""

    def plan(self, patch: GaussianCloud, weights: np.ndarray, writer: SceneWriter,
             encoder: PatchEncoder, rows: np.ndarray | None = None) -> int:
        known: dict[int, float] = {}
        if self.config.retrain is None and self.config.allocation is not None and len(patch):
            encoder = self.allocate(patch, weights, writer, encoder, rows)
            if self.config.keep_all:
                return len(patch)
            # the chosen point was judged with every patch Gaussian: the same file
            known[len(patch)] = self.allocated_psnr
        files = _pruned_files(writer, encoder, patch, weights)
        reach = self.landed(len(patch), files, known)
        check_reachable(self.target, reach, self.config.retrain is not None)
        short = [c for c, p in reach.judged.items() if p < self.target]
        self.record.setdefault("quality_target", {}).update({
            "target_psnr": self.target, "patch_gaussians": len(patch),
            "count_without_retraining": reach.count,
            "psnr_without_retraining": round(reach.psnr, 3),
            "largest_count_short": max(short, default=0), "judgements": len(reach.judged),
            "judged_at_full_resolution": self.judge.full_judgements})
        return reach.count

    def landed(self, upper: int, file_of: Callable[[int], bytes],
               known: dict[int, float]) -> QualityPlan:
        """:func:`fewest_reaching` with the judge's predictions, its answer then judged at the
        evaluation's resolution: when that falls short of the target, the judge's offset is
        taken from that file and the search goes on (at most :data:`LANDING_TRIES` times), so
        the count returned is judged on the evaluation's own scale."""
        judged = dict(known)
        made: dict[int, bytes] = {}  # the files judged, so the answer is not encoded again

        def decoded(count: int) -> GaussianCloud:
            if count not in made:
                made[count] = file_of(count)
            return decode_layers(made[count]).cloud

        for _ in range(LANDING_TRIES):
            reach = fewest_reaching(self.target, upper, lambda c: self.judge(decoded(c)), judged)
            if not reach.reached:
                return reach
            full = self.judge.verify(decoded(reach.count), predicted=reach.psnr)
            reach.judged[reach.count] = reach.psnr = full
            if full >= self.target:
                return reach
            # below the target: counts judged short stay short, the rest are judged again
            judged = {c: p for c, p in reach.judged.items() if c <= reach.count}
        return reach

    def allocate(self, patch: GaussianCloud, weights: np.ndarray, writer: SceneWriter,
                 encoder: PatchEncoder, rows: np.ndarray | None) -> PatchEncoder:
        """The smallest point of the precision curve whose file, every patch Gaussian kept,
        reaches the target (bisected on the judge's small views: the judged PSNR rises along
        the curve; then verified at the evaluation's resolution, stepping up while short), and
        its encoder. A target beyond the finest point is a UsageError that names what that
        point reaches."""
        start = time.perf_counter()
        curve = self.precision_search(patch, weights, encoder, rows).curve()
        encoders = [_coder(point, encoder) for point in curve]
        judged: dict[int, float] = {}
        files: dict[int, bytes] = {}

        def psnr_at(i: int) -> float:
            if i not in judged:
                files[i] = pruned_file(writer, encoders[i], patch, weights, len(patch)).data
                judged[i] = self.judge(decode_layers(files[i]).cloud)
            return judged[i]

        hi = len(curve) - 1
        if psnr_at(hi) < self.target:
            raise UsageError(
                f"--target-psnr {self.target:g} dB is out of reach without retraining: the finest "
                f"precision, every Gaussian kept, reaches {judged[hi]:.2f} dB at the close-up "
                "framing; ask for at most that, retrain (drop --no-retrain), or use --preset "
                "transparent, which also stores positions finer and keeps every Gaussian apart")
        # from -1, assumed short, guided by each point's predicted distortion
        hi = smallest_reaching(self.target, -1, hi, psnr_at, judged,
                               loss=lambda i: curve[i].distortion)
        # the search judged small views, and the target is promised at the evaluation's
        # own resolution: a point short there is followed up the curve, not pruned from
        verified = {hi: self.judge.verify(decode_layers(files[hi]).cloud, predicted=judged[hi])}
        while verified[hi] < self.target and hi < len(curve) - 1:
            hi += 1
            predicted = psnr_at(hi)  # writes the point's file
            verified[hi] = self.judge.verify(decode_layers(files[hi]).cloud, predicted=predicted)
        full = verified[hi]
        self.allocated = curve[hi].patch_config(encoder.config)
        self.allocated_psnr = full
        self.record["quality_target"] = {
            "target_psnr": self.target,
            "precision": {"options": curve[hi].describe(), "curve_points": len(curve),
                          "chosen_point": hi, "psnr": round(full, 3),
                          "judged": {str(i): round(v, 3) for i, v in sorted(judged.items())},
                          "verified": {str(i): round(v, 3) for i, v in sorted(verified.items())},
                          "seconds": round(time.perf_counter() - start, 2)}}
        return encoders[hi]

    def fit(self, writer: SceneWriter, encoder: PatchEncoder, cloud: GaussianCloud,
            quantized: Quantized, importance: np.ndarray) -> np.ndarray:
        """The fewest trained Gaussians that still reach the target."""
        found = self.landed(len(cloud), _quantized_files(writer, encoder, cloud, quantized,
                                                         importance), {})
        self.record["quality_target"].update(count_retrained=found.count,
                                             psnr_retrained=round(found.psnr, 3),
                                             reached=found.reached)
        return prune_by_importance(importance, found.count)


SLOPE_RANGE = (0.5, 2.0)
"""File bytes per predicted option byte that two trials may measure for :func:`_size_line` to
take their line (outside: the writes were too near each other to say)."""


def _size_line(measured: list[tuple[float, int]], other: float) -> tuple[float, float]:
    """``(intercept, slope)`` of file bytes against the search's predicted option bytes, for
    the next trial's budget ``(aim - intercept) / slope``. After one trial: through that trial
    and the preset's ``other`` bytes (its file less its options' prediction), the slope its
    miss gives. After two or more: through the last two trials, whose options are nearer the
    target than the preset's. Rescaling by the last miss alone crept up on the target a few
    percent a trial when the first landed far under it (tests/test_allocation.py's synthetic
    scene: 72 % of the aim, then 93, 96 and 98 %: out of trials, 3.1 % under the target)."""
    (b1, s1) = measured[-1]
    if len(measured) >= 2:
        b0, s0 = measured[-2]
        if b1 != b0 and SLOPE_RANGE[0] <= (s1 - s0) / (b1 - b0) <= SLOPE_RANGE[1]:
            slope = (s1 - s0) / (b1 - b0)
            return s1 - slope * b1, slope
    return other, max(s1 - other, 1.0) / max(b1, 1.0)


def sizing_for(config: EncoderConfig, original: GaussianCloud, device: str) -> Sizing:
    """The sizing ``config`` asks for (the pipeline refuses both targets at once)."""
    kind = _sizing_kind(config)
    return FactorSizing(config) if kind is FactorSizing else kind(config, original, device)


def sized_encode(config: EncoderConfig) -> bool:
    """Whether an encode of ``config`` asks its sizing how many Gaussians to keep and how finely
    (retraining, a target or a preset point); the others code every Gaussian as configured."""
    return config.retrain is not None or _sizing_kind(config) is not FactorSizing


def _sizing_kind(config: EncoderConfig) -> type[Sizing]:
    """Which :class:`Sizing` ``config`` asks for: a target, else a no-retrain preset's point
    of the curve (``config.allocation`` set by ``preset_config``), else the factor."""
    if config.target_psnr is not None:
        return QualityTarget
    if config.target_size is not None:
        return SizeTarget
    if config.retrain is None and config.allocation is not None and not config.keep_all:
        return PresetPoint
    return FactorSizing


def _trial(writer: SceneWriter, encoder: PatchEncoder, patch: GaussianCloud,
           weights: np.ndarray, target: int, nearest: dict[int, bytes]) -> Callable[[int], int]:
    """count -> bytes of the file with the ``count`` most important patch Gaussians, coded
    without retraining (rate control's size model). ``nearest`` keeps the one file nearest
    ``target`` so far, by its count: the planner's answer, which a size target may compare."""
    def size(count: int) -> int:
        data = pruned_file(writer, encoder, patch, weights, count).data
        if not nearest or abs(len(data) - target) < min(abs(len(d) - target)
                                                         for d in nearest.values()):
            nearest.clear()
            nearest[count] = data
        return len(data)
    return size


def _coder(allocation: Allocation, encoder: PatchEncoder) -> PatchEncoder:
    """The patch encoder of ``allocation``, with ``encoder``'s seed and jobs."""
    return PatchEncoder(allocation.patch_config(encoder.config), seed=encoder.seed,
                        jobs=encoder.jobs)


def pruned_file(writer: SceneWriter, encoder: PatchEncoder, patch: GaussianCloud,
                weights: np.ndarray, count: int):
    """The file (:class:`~spcodec.writer.WrittenFile`) with only the ``count`` most important
    patch Gaussians, coded as they are."""
    if count == 0:
        return writer.write_file(None)
    top = prune_by_importance(weights, count)
    return writer.write_file(encoder.encode(patch.subset(top), importance=weights[top]))


def _pruned_files(writer: SceneWriter, encoder: PatchEncoder, patch: GaussianCloud,
                  weights: np.ndarray) -> Callable[[int], bytes]:
    """count -> the file with the ``count`` most important patch Gaussians, coded without
    retraining (quality control's first search)."""
    return lambda count: pruned_file(writer, encoder, patch, weights, count).data


def _quantized_files(writer: SceneWriter, encoder: PatchEncoder, trained: GaussianCloud,
                     quantized: Quantized, importance: np.ndarray
                     ) -> Callable[[int], bytes]:
    """count -> the file with the ``count`` most important quantized Gaussians."""
    def file(count: int) -> bytes:
        top = prune_by_importance(importance, count)
        return writer.write(encoder.layer(trained.subset(top), quantized.subset(top),
                                          importance[top]))
    return file


def _sized(writer: SceneWriter, encoder: PatchEncoder, trained: GaussianCloud,
           quantized: Quantized, importance: np.ndarray) -> Callable[[int], int]:
    """count -> bytes of the file with the ``count`` most important quantized Gaussians."""
    def size(count: int) -> int:
        top = prune_by_importance(importance, count)
        return writer.write_file(encoder.layer(trained.subset(top), quantized.subset(top),
                                               importance[top])).size
    return size
