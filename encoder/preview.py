"""Encoding with a preview (spec 7.4): a small file made for its own size, shown first.

A prefix of a file is a part of a scene trained to be seen whole; on guitar, the first tenth of
an SPZ/4 file is 8-18 dB under a file trained for that tenth (docs/LOG.md 15.7). So
``--preview-size`` encodes the scene twice: a preview made for the preview's bytes, then the
scene for what is left of the target, and embeds the first in the second's layer 0, with the
first layer whose prefix beats it as the takeover layer.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from spcodec.cloud import GaussianCloud
from spcodec.container import PREVIEW_PREFIX_SIZE, SectionEntry
from spcodec.errors import UsageError
from spcodec.preview import attach_preview_file, choose_takeover

from .config import EncoderConfig
from .presets import sized
from .retraining.control import RunControl
from .stages import ProgressFactory, silent
from .statistics import EncodeStats, PreviewStats, RetrainStats

PREVIEW_OVERHEAD = SectionEntry.sizeof() + PREVIEW_PREFIX_SIZE
"""Bytes a preview adds besides its file: its table-of-contents entry and payload prefix."""


def encode_with_preview(cloud: GaussianCloud, config: EncoderConfig, preview_size: int,
                        progress: ProgressFactory = silent, source_name: str | None = None,
                        dataset: str | Path | None = None,
                        control: RunControl | None = None):
    """Encode ``cloud`` with a preview made for ``preview_size`` bytes embedded.

    With ``config.target_size`` the whole file, preview included, is aimed at it: the scene is
    made for what the preview leaves. The preview is encoded as ``--target-size`` would make it
    (:func:`.presets.sized`), without a checkpoint (a resumed encode makes it again,
    deterministically), and otherwise with the scene's settings, so both are trained on the same
    views and their PSNR on them can be compared.
    """
    from .pipeline import EncodeResult, encode

    if preview_size <= PREVIEW_OVERHEAD:
        raise UsageError(f"a preview of {preview_size} bytes holds nothing: give more than "
                         f"{PREVIEW_OVERHEAD}")
    rest = None
    if config.target_size is not None:
        rest = config.target_size - preview_size - PREVIEW_OVERHEAD
        if rest < preview_size:
            raise UsageError(f"--preview-size {preview_size} leaves the scene {max(rest, 0)} of "
                             f"the {config.target_size} bytes, less than the preview: a preview "
                             "is a small part of the file (a tenth, say)")
    preview_config = dataclasses.replace(sized(config, preview_size), target_psnr=None)
    if config.retrain is not None and config.retrain.nested:  # the preview is one plain file
        preview_config.retrain = dataclasses.replace(config.retrain, nested=False)
    preview_control = None if control is None else \
        dataclasses.replace(control, checkpoint=None, resume=False)
    try:
        preview = encode(cloud, preview_config, progress, source_name, dataset, preview_control)
    except UsageError as exc:  # rate control speaks of "the target": say which one
        raise UsageError(f"the preview (--preview-size): {exc}") from None
    # the preview usually comes in a little under its target: the scene gets what is left
    scene_config = config if rest is None else dataclasses.replace(
        config, target_size=config.target_size - len(preview.data) - PREVIEW_OVERHEAD)
    scene = encode(cloud, scene_config, progress, source_name, dataset, control)
    takeover = takeover_layer(scene.stats.retrain, len(scene.stats.layer_ends),
                              preview.stats.retrain)
    written = attach_preview_file(scene.data, preview.data, takeover)
    data = written.data
    stats = dataclasses.replace(scene.stats, bytes=len(data),
                                sections=written.layout.section_bytes(),
                                layer_ends=list(written.layout.stored_ends()),
                                preview=preview_stats(preview.stats, takeover))
    if "rate" in stats.sizing and config.target_size is not None:  # the target is the whole file's
        added = len(data) - len(scene.data)
        rate = stats.sizing["rate"]
        stats.sizing = {**stats.sizing, "rate": dict(
            rate, target_bytes=config.target_size, predicted_bytes=rate["predicted_bytes"] + added)}
    return EncodeResult(data, scene.scene, scene.source_index, stats)


def preview_stats(stats: EncodeStats, takeover: int) -> PreviewStats:
    """What the encode statistics say of the preview."""
    return PreviewStats(stats.bytes, takeover, whole_psnr(stats.retrain),
                        stats.sketch_gaussians + stats.patch_gaussians, stats.quality)


def whole_psnr(retrain: RetrainStats | None) -> float | None:
    """PSNR of a whole retrained file on its training views, as its encode measured it."""
    return None if retrain is None else retrain.whole_psnr


def takeover_layer(scene: RetrainStats | None, layers: int, preview: RetrainStats | None) -> int:
    """The first of the scene's ``layers`` whose prefix scores at least the preview on the
    training views, by what retraining measured of each (:func:`spcodec.preview.choose_takeover`)."""
    return choose_takeover(None if scene is None else scene.prefix_psnr, layers,
                           whole_psnr(preview))
