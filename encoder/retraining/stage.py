"""The encoder's last stage: prune the patch, retrain it with the decoded sketch frozen, quantize
with a quantization-aware finish (the paper's section "Patch Gaussian Pruning and Optimization").

Order of work, as :class:`RetrainStage` runs it:

1. **Targets**: dataset training images (``--dataset``) or renders of the original at sampled
   training views (distillation); see :mod:`spcodec.imaging.training.targets`.
2. **Prune** the patch Gaussians to ``round(n / patch_downsample)``: by blend weight over the
   training views (default) or uniformly at random (the paper's); see :mod:`spcodec.encoder.prune`.
3. **Retrain** the survivors (positions, scales, rotations, opacities, SH at the scene's degree)
   with Adam at the 3DGS rates, loss 0.8 L1 + 0.2 D-SSIM, the sketch as the file stores it
   rendered but never changed. From ``snap_start`` on, they train through their codebooks
   (quantization-aware; under rate control the count is fitted to the target at that step).
4. **Quantize** with the codebooks trained with (k-means when snapping was off), then the
   **finish**: fine-tune the codebook entries (and positions at their stored precision) through
   the renderer with indices fixed, re-assigning indices once midway; see :mod:`.quantaware`.
5. **Order** the patch by blend weight in the whole scene (sketch included, so what the sketch
   hides ranks low) for the layers.

Long runs report progress, write checkpoints and stop cleanly on request
(:class:`.control.RunControl`).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import numpy as np
import torch

from spcodec.attributes import PatchAttribute
from spcodec.cloud import GaussianCloud
from spcodec.errors import Interrupted
from spcodec.imaging.importance import blend_weights
from spcodec.imaging.render import GaussianParams, RenderSettings
from spcodec.imaging.training.checkpoint import Checkpointer
from spcodec.imaging.training.loop import FitLoop, StepReport
from spcodec.imaging.training.optim import FreeGaussians
from spcodec.imaging.training.targets import Targets
from spcodec.sections import Codebook

from ..config import RetrainConfig
from ..patch import PatchEncoder, Quantized, quantized_cloud
from ..prune import select
from ..statistics import RetrainStats, SnapDecision
from .control import RunControl
from .nested import NestedLayers
from .quantaware import CodebookGaussians, SnappedGaussians, with_positions

RowFit = Callable[[GaussianCloud, Quantized, np.ndarray], "np.ndarray | None"]
"""Rate control's choice when snapping starts: given the Gaussians, their k-means quantization and
importance, the rows to keep (sorted) or None to keep all."""


class RetrainStage:
    """Prune, retrain and quantize the patch of one scene against ``targets``.

    ``fit_rows`` is rate control's fit when snapping starts (None: keep every survivor);
    ``nested`` the layers nested retraining fixed, whose prefixes the steps render (None: every
    step renders all), with ``patch_encoder`` then the :class:`~.nested.NestedEncoder` of them.
    """

    def __init__(self, config: RetrainConfig, targets: Targets, sketch: GaussianCloud,
                 patch_encoder: PatchEncoder, seed: int, control: RunControl,
                 checkpointer: Checkpointer | None = None,
                 settings: RenderSettings | None = None, fit_rows: RowFit | None = None,
                 nested: NestedLayers | None = None) -> None:
        if nested is not None:  # snapping from the start: the rows must stay in their layers
            config = dataclasses.replace(config, snap_start=1.0)
        self.config, self.targets, self.seed, self.control = config, targets, seed, control
        self.checkpointer = checkpointer
        self.device = _device(control.device)
        self.settings = settings or RenderSettings(background=targets.background)
        self.frozen = GaussianParams.from_cloud(sketch, self.device) if len(sketch) else None
        self.patch_encoder = patch_encoder
        self.importance_cameras = spread(targets.whole_cameras, config.importance_views)
        self.saved: dict | None = None
        self.trained: GaussianCloud | None = None
        self.fit_rows = fit_rows
        self.nested = nested
        #: The codebooks snapping trained with (None: it never started) and the rows of the
        #: survivors still trained when retraining ended (None: all).
        self.snapped: list[Codebook] | None = None
        self.kept: np.ndarray | None = None
        #: What the quantization cost when snapping was to start, and whether it did.
        self.snap_decision: SnapDecision | None = None

    # ---------------------------------------------------------------------------- pruning
    def patch_weights(self, scene: GaussianCloud, patch_rows: np.ndarray) -> np.ndarray:
        """Blend weights of the Gaussians ``patch_rows`` of ``scene`` over the importance views."""
        weights = blend_weights(scene, self.importance_cameras, self.settings, self.device)
        return weights[patch_rows]

    def prune(self, patch_count: int, keep: int, weights: np.ndarray | None) -> np.ndarray:
        return select(self.config.prune, patch_count, keep, self.seed, weights)

    # --------------------------------------------------------------------------- training
    def retrain(self, survivors: GaussianCloud, stats: RetrainStats,
                on_step: Callable[[StepReport], None] | None = None) -> GaussianCloud:
        """Optimize the pruned patch against the targets (or take the result from a checkpoint
        of a later stage when resuming)."""
        checkpointer = self.checkpointer
        if self.control.resume:
            if checkpointer is None:
                raise ValueError("resume needs a checkpoint path")
            self.saved = checkpointer.load()
        elif checkpointer is not None:
            checkpointer.refuse_stale()
        model = self._model(survivors)
        loop = self._loop(model, self.config.iterations,
                          None if self.nested is None else self.nested.training())
        stats.psnr_before = loop.mean_psnr()
        start = time.perf_counter()
        saved = self.saved
        if saved is not None and saved["stage"] != "retrain":
            trained = _cloud_from_state(saved["state"]["trained"])
            self._restore_snap(saved["state"].get("snap"))
        else:
            if saved is not None:
                model.load_state_dict(saved["state"]["model"])
                loop.step = saved["step"]
            self._run_stage("retrain", loop, lambda: {"model": model.state_dict()}, on_step)
            trained = model.to_cloud()
            if isinstance(model, SnappedGaussians):
                self.kept = model.rows
                if model.snapping:
                    model.picked = None  # the nearest entries, as the file will store them
                    self.snapped = model.snap.codebooks()
                    stats.psnr_snapped = loop.mean_psnr()
            if self.snap_decision is not None:
                stats.snap = self.snap_decision
        self.trained = trained
        stats.retrain_seconds = time.perf_counter() - start
        stats.psnr_retrained = loop.mean_psnr(GaussianParams.from_cloud(trained, self.device))
        return trained

    def quantize(self, trained: GaussianCloud) -> tuple[Quantized, np.ndarray]:
        """The codebooks retraining snapped to (else k-means weighted by blend weight) with the
        indices of ``trained``, and its blend weights."""
        importance = self.rank(trained)
        if self.snapped is not None:
            return Quantized(self.snapped, self.patch_encoder.assign(trained, self.snapped)), \
                importance
        weights = self.patch_encoder.kmeans_weights(importance)
        return self.patch_encoder.quantize(trained, weights), importance

    def finish(self, trained: GaussianCloud, quantized: Quantized, stats: RetrainStats,
               on_step: Callable[[StepReport], None] | None = None,
               priority: np.ndarray | None = None) -> tuple[Quantized, GaussianCloud]:
        """The quantization-aware fine-tune of ``quantized`` (codebooks of ``trained``): returns
        the tuned codebooks with their indices, and ``trained`` with the tuned positions. Nested,
        ``priority`` is the layer priority of ``trained`` (:func:`~.nested.layer_priority`): the
        steps render prefixes of the layers rate or quality control left."""
        cfg, encoder = self.config, self.patch_encoder
        model = CodebookGaussians(
            trained.means, quantized.codebooks, quantized.indices, trained.sh_degree, self.device,
            position_rate=cfg.rates.position_final * self.targets.extent,
            position_bits=encoder.config.stored_position_bits)
        if self.nested is not None and priority is None:
            raise ValueError("a nested finish needs the layer priority of the Gaussians")
        loop = self._loop(model, cfg.finish_iterations, None if self.nested is None else
                          self.nested.finishing(priority, encoder.config.layers))
        stats.psnr_quantized = loop.mean_psnr()
        if cfg.finish_iterations == 0:
            return quantized, trained
        start = time.perf_counter()
        saved = self.saved
        if saved is not None and saved["stage"] == "finish":
            model.load_state_dict(saved["state"]["model"])
            loop.step = saved["step"]
        reassign_step = max(1, int(round(cfg.reassign_at * cfg.finish_iterations)))

        def reassign(report: StepReport) -> None:
            model.clamp_entries()
            if report.step == reassign_step:
                current = with_positions(trained, model.positions())
                model.set_indices(encoder.assign(current, model.codebooks()))
            if on_step is not None:
                on_step(report)

        trained_state = {"model": None, "trained": _cloud_state(self.trained),
                         "snap": self._snap_state()}
        self._run_stage("finish", loop, lambda: {**trained_state, "model": model.state_dict()},
                        reassign)
        stats.psnr_finished = loop.mean_psnr()
        stats.finish_seconds = time.perf_counter() - start
        return (Quantized(model.codebooks(), model.index_arrays()),
                with_positions(trained, model.positions()))

    def rank(self, patch: GaussianCloud) -> np.ndarray:
        """Blend weights of ``patch`` in the scene with the frozen sketch in front of it."""
        sketch = self.frozen.to_cloud() if self.frozen is not None else None
        scene = GaussianCloud.concat([sketch, patch]) if sketch is not None else patch
        offset = 0 if sketch is None else len(sketch)
        return self.patch_weights(scene, np.arange(offset, offset + len(patch)))

    # ---------------------------------------------------------------------------- helpers
    def _model(self, survivors: GaussianCloud) -> FreeGaussians | SnappedGaussians:
        """Free Gaussians, snapped to their codebooks from ``snap_step`` on when configured."""
        cfg = self.config
        if cfg.snap_step is None:
            return FreeGaussians(survivors, self.device, cfg.rates, self.targets.extent)
        return SnappedGaussians(survivors, self.device, cfg.rates, self.targets.extent,
                                cfg.snap_step, cfg.snap_refresh_every, self._snap_codebooks,
                                self.patch_encoder.config.stored_position_bits)

    def _snap_codebooks(self, cloud: GaussianCloud
                        ) -> tuple[np.ndarray | None, list[Codebook], np.ndarray]:
        """When snapping starts: the rows rate control keeps (None: all), k-means codebooks of
        those rows weighted by blend weight, and those weights."""
        encoder = self.patch_encoder
        importance = self.rank(cloud)
        rows = None
        if self.fit_rows is not None:
            rows = self.fit_rows(cloud, encoder.quantize(cloud, encoder.kmeans_weights(
                importance)), importance)
            if rows is not None:
                cloud, importance = cloud.subset(rows), importance[rows]
        weights = encoder.kmeans_weights(importance)
        if weights is None:
            weights = np.ones(len(cloud))
        quantized = encoder.quantize(cloud, weights)
        loss = self._quantization_loss(cloud, quantized)
        self.snap_decision = SnapDecision(round(loss, 3), loss >= self.config.snap_min_loss)
        return rows, quantized.codebooks if loss >= self.config.snap_min_loss else None, weights

    def psnr(self, patch: GaussianCloud) -> float:
        """Mean PSNR on the training views of the frozen sketch with ``patch`` in front."""
        return self._loop(None, 0).mean_psnr(GaussianParams.from_cloud(patch, self.device))

    def _quantization_loss(self, cloud: GaussianCloud, quantized: Quantized) -> float:
        """dB the training views lose when ``cloud`` is rendered through ``quantized``."""
        snapped = quantized_cloud(quantized, cloud.means, cloud.sh_degree)
        return self.psnr(cloud) - self.psnr(snapped)

    def _snap_state(self) -> dict | None:
        """What retraining decided that a later stage needs: the snapped codebooks (if it
        snapped) and the rows rate control kept (if it dropped any)."""
        if self.snapped is None and self.kept is None:
            return None
        entries = None if self.snapped is None else {
            cb.attribute.name: torch.from_numpy(cb.entries.astype(np.float32))
            for cb in self.snapped}
        return {"entries": entries,
                "kept": None if self.kept is None else torch.as_tensor(self.kept)}

    def _restore_snap(self, state: dict | None) -> None:
        """The snapped codebooks and kept rows of a checkpoint written after retraining."""
        if not state:
            return
        if state["entries"] is not None:
            self.snapped = [Codebook(PatchAttribute[name], entries.numpy().astype(np.float16))
                            for name, entries in state["entries"].items()]
        self.kept = None if state["kept"] is None else state["kept"].numpy()

    def _loop(self, model, total: int, visible: Callable[[int], int | None] | None = None
              ) -> FitLoop:
        """A fitting loop over the targets; ``visible``: which prefix of the model each step
        renders (step -> count of its first Gaussians, None: all; :mod:`.nested`)."""
        return FitLoop(model, self.targets, self.settings, total, seed=self.seed,
                       frozen=self.frozen, stop=self.control.stop, visible=visible)

    def _run_stage(self, name: str, loop: FitLoop, state: Callable[[], dict],
                   after_step: Callable[[StepReport], None] | None = None) -> None:
        """Run ``loop`` with ``after_step`` after each step (progress, the finish's
        re-assignment), periodic checkpoints and a checkpoint when stopped."""
        control = self.control

        def on_step(report: StepReport) -> None:
            if after_step is not None:
                after_step(report)
            if control.on_step is not None:
                control.on_step(name, report)
            every = control.checkpoint_every
            if checkpointer is not None and every and report.step % every == 0 \
                    and report.step < report.total:
                checkpointer.save(name, report.step, state())

        checkpointer = self.checkpointer
        with control.stoppable_section():
            completed = loop.run(on_step)
        if completed:
            return
        if checkpointer is None:
            raise Interrupted(f"stopped at {name} step {loop.step}/{loop.total} "
                                    "(no checkpoint was configured, nothing was saved)")
        checkpointer.save(name, loop.step, state())
        raise Interrupted(f"stopped at {name} step {loop.step}/{loop.total}; checkpoint "
                                f"saved to {checkpointer.path}; to resume: {control.resume_hint}")


def _device(spec: str) -> torch.device:
    from spcodec.imaging.render import resolve_device
    return resolve_device(spec)


def spread(items: list, count: int) -> list:
    """``count`` items evenly spread over ``items`` (all when there are fewer)."""
    if len(items) <= count:
        return list(items)
    picks = np.unique(np.linspace(0, len(items) - 1, count).round().astype(int))
    return [items[i] for i in picks]


def _cloud_state(cloud: GaussianCloud) -> dict[str, torch.Tensor]:
    return {name: torch.from_numpy(np.array(a)) for name, a in cloud.arrays().items()}


def _cloud_from_state(state: dict[str, torch.Tensor]) -> GaussianCloud:
    return GaussianCloud(**{name: t.numpy() for name, t in state.items()})
