"""What the encoder's stages hand each other, and how a stage reports progress.

The pipeline (:mod:`.pipeline`), the pruned patch stage (:mod:`.prune_retrain`) and retraining
(:mod:`.retraining`) all work with the sketch stage's outcome, with a writer that turns any patch
encoding into the file and with the patch they choose; these types live here, below them all, so
none imports another for them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from spcodec.cloud import GaussianCloud
from spcodec.decoder import decode_layers
from spcodec.writer import EncodedScene, WriteOptions, WrittenFile, write_file

from . import compressions
from .config import EncoderConfig
from .patch import PatchEncoding
from .statistics import RetrainStats, SketchStats

if TYPE_CHECKING:  # torch: only a pruned encode holds a run control
    from .retraining.control import RunControl

ProgressFactory = Callable[[str, int | None], "Stage"]


class Stage:
    """Progress of one stage; the default prints nothing. ``update`` may carry figures to show
    (training steps pass ``loss`` and ``psnr``, and ``eta_all``: seconds left for every stage
    still to come, not only this one)."""

    def resumed(self, count: int) -> None:  # pragma: no cover - trivial
        """``count`` steps were done by an earlier run (a resumed checkpoint): start there."""

    def update(self, count: int = 1, **figures: float) -> None:  # pragma: no cover - trivial
        pass

    def note(self, message: str) -> None:  # pragma: no cover - trivial
        """A line for the user that is no stage of its own (an estimate, a choice made)."""

    def done(self, summary: str = "") -> None:  # pragma: no cover - trivial
        pass


def silent(name: str, total: int | None) -> Stage:
    return Stage()


@dataclass
class SketchOutcome:
    """The sketch stage's result: encoded clusters and where every input Gaussian went."""

    clusters: list
    sources: list[np.ndarray]
    """Per encoded cluster, the indices of its input Gaussians in stored order."""
    patch_idx: np.ndarray
    """Sorted indices of the input Gaussians left to the patch."""
    stats: SketchStats


@dataclass
class EncodeRun:
    """What every stage of one encode reads: the input scene, its settled settings, where
    progress and stage times go, and the dataset and run control of a pruned encode."""

    cloud: GaussianCloud
    config: EncoderConfig
    progress: ProgressFactory
    times: dict[str, float] = field(default_factory=dict)
    dataset: str | Path | None = None
    control: RunControl | None = None


@dataclass
class PatchChoice:
    """The pruned patch handed back to the pipeline."""

    encoding: PatchEncoding
    rows: np.ndarray
    """Indices into the patch cloud of the encoded Gaussians (``encoding.order`` indexes these)."""
    psnr_input: float | None = None
    """PSNR of the input against the retraining targets (retraining only)."""
    sizing: dict = field(default_factory=dict)
    """What the sizing decided (:meth:`.sizing.Sizing.stats`)."""
    retrain: RetrainStats | None = None


@dataclass
class SceneWriter:
    """Writes the file of one scene for any patch encoding (the sketch and metadata are fixed),
    so rate control can size trial files exactly as the final one."""

    sh_degree: int
    sketch: list
    metadata: dict
    options: WriteOptions

    def scene(self, patch: PatchEncoding | None) -> EncodedScene:
        if patch is None:
            return EncodedScene(self.sh_degree, self.sketch, [], [], self.metadata)
        layers = patch.layers if sum(map(len, patch.layers)) else []
        return EncodedScene(self.sh_degree, self.sketch, patch.codebooks, layers, self.metadata,
                            index_contexts=patch.contexts_for(self.options.codec,
                                                              self.options.level))

    def write(self, patch: PatchEncoding | None) -> bytes:
        return self.write_file(patch).data

    def write_file(self, patch: PatchEncoding | None) -> WrittenFile:
        """The file and its layout (section and layer extents), which trial files are judged
        by without reading them back."""
        return write_file(self.scene(patch), self.options, compressor=compressions.RECENT)

    def with_prefix_psnr(self, prefix_psnr: list[dict] | None) -> SceneWriter:
        """This writer with the file's per-prefix PSNR on the training views in its metadata
        (``stats.prefix_psnr``: what a viewer reads to choose where to stop, [R-71], and what
        picks a preview's takeover layer); itself when there is no table. Rate control sizes the
        final file with the writer this returns, so the table's bytes are inside the target."""
        if not prefix_psnr:
            return self
        return replace(self, metadata={**self.metadata, "stats": {
            "prefix_psnr": prefix_psnr, "prefix_psnr_against": "training views"}})

    def decoded_sketch(self) -> GaussianCloud:
        """The sketch exactly as a decoder will see it (layer 0 of a sketch-only file)."""
        return decode_layers(self.write(None), max_layer=0).cloud
