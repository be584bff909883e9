"""Named operating points of the encoder: ``--preset lowrate|balanced|highrate``.

The presets differ in how finely the patch codebooks split each attribute (entry dimensions) and in
how readily clusters become sketch (``tau_max``). Without retraining, ``lowrate``, ``balanced``
and ``highrate`` are points of the rate-distortion curve: their shapes set the bytes, which the
precision search spends (:func:`preset_config`, DECISIONS D-33); the table below is of the shapes
themselves. Measured against renders of the original at
8 held-out views of 400x400 (``spcodec eval --reference``), sizes in bytes, on 2026-11-22:

============  ====================  ====================  ====================  ===============
scene         lowrate               balanced              highrate              SPZ (splat-tr.)
============  ====================  ====================  ====================  ===============
fourth_st     1.18 MB, 35.9 dB      1.47 MB, 37.4 dB      2.24 MB, 53.1 dB      3.14 MB, 85 dB
biker         0.87 MB, 36.8 dB      1.27 MB, 46.6 dB      1.46 MB, 47.0 dB      2.24 MB, 100 dB
donut         0.35 MB, 28.5 dB      0.48 MB, 40.7 dB      0.56 MB, 42.1 dB      0.65 MB, 48.5 dB
============  ====================  ====================  ====================  ===============

(fourth_st and biker were decoded from SPZ, so SPZ re-encodes them almost exactly; since their
positions are stored exactly on SPZ's grid, their files are 2-3 % larger than above, docs/LOG.md 14.4.)
``docs/LOG.md`` 13.18 has the full, current table (every preset on every shared scene, judged in
PlayCanvas); this one records why the defaults are what they are (``docs/DECISIONS.md`` D-8).
"""

from __future__ import annotations

import dataclasses

from .config import (
    RETRAINED_MAX_SKETCH_SHARE,
    RETRAINED_PATCH_LAYERS,
    TARGET_GROUPS_PER_ENTRY,
    AllocationConfig,
    EncoderConfig,
    PatchConfig,
    RetrainConfig,
    geometric_fractions,
)

_SH_BANDS = {"SH_BAND_1": 9, "SH_BAND_2": 15, "SH_BAND_3": 21}
_SH_TRIPLETS = {"SH_BAND_1": 3, "SH_BAND_2": 3, "SH_BAND_3": 3}
_SH_SCALARS = {"SH_BAND_1": 1, "SH_BAND_2": 1, "SH_BAND_3": 1}

PRESETS: dict[str, dict] = {
    # Smallest files: whole-vector codebooks everywhere and more sketch. Quality depends on the
    # scene: fine on large Gaussians, poor on many small ones (donut 28.5 dB).
    "lowrate": dict(entry_dims={"SCALE": 3, "ROTATION": 4, "OPACITY": 1, "COLOR_DC": 3,
                                **_SH_BANDS}, tau_max=0.3,
                    retrain=dict(patch_downsample=8.0, iterations=3000)),
    # The default: >= 37 dB on every shared scene at about half of SPZ's size.
    "balanced": dict(entry_dims={"SCALE": 1, "ROTATION": 2, "OPACITY": 1, "COLOR_DC": 3,
                                 **_SH_BANDS}, tau_max=0.1,
                     retrain=dict(patch_downsample=4.0, iterations=3000)),
    # Near-transparent: per-channel colour and one index per RGB SH coefficient (>= 42 dB).
    "highrate": dict(entry_dims={"SCALE": 1, "ROTATION": 2, "OPACITY": 1, "COLOR_DC": 1,
                                 **_SH_TRIPLETS}, tau_max=0.1,
                     retrain=dict(patch_downsample=2.0, iterations=3000)),
    # Looks like the original in a viewer, smaller than SPZ: every Gaussian kept, as patch (the
    # sketch's models cost more than they save here), one scalar codebook of 256 levels per
    # attribute (the budget of docs/LOG.md 14.1: the rotation pairs' codebooks and the sketch
    # were most of highrate's loss; scalar rotations are assigned at the best of 64 multiples,
    # encoder/patch.py), 14-bit positions over each layer's box (guitar loses 0.9 dB against 18
    # bits and stays above SPZ; donut needs <= 14 to be smaller than SPZ), and inputs already on
    # a coarser grid (decoded from SPZ) stored exactly on it. Never retrained: pruning would
    # defeat the point. Measured against SPZ in docs/LOG.md 14.4.
    "transparent": dict(entry_dims={"SCALE": 1, "ROTATION": 1, "OPACITY": 1, "COLOR_DC": 1,
                                    **_SH_SCALARS}, tau_max=0.1, use_sketch=False,
                        position_bits=14, retrain=None),
}


def retrains(name: str) -> bool:
    """Whether preset ``name`` can retrain (``transparent`` keeps every Gaussian, so it never
    does)."""
    return PRESETS[name]["retrain"] is not None


def preset_config(name: str, base: EncoderConfig | None = None,
                  retrain: bool = False, point: bool = True) -> EncoderConfig:
    """``base`` (default: a fresh EncoderConfig) with the preset's settings applied. With
    ``retrain``, also its retraining settings (on ``base.retrain`` or a default RetrainConfig) and
    the layout a retrained file is best with: :data:`RETRAINED_PATCH_LAYERS` geometric layers and
    the sketch within :data:`RETRAINED_MAX_SKETCH_SHARE` of the file. The CLI builds every encode
    here, so a library caller gets the file ``spcodec encode`` writes. A preset that never
    retrains refuses ``retrain`` with ValueError.

    Without retraining, a preset that may prune is a *point* of the rate-distortion curve: its
    codebook shapes only set the bytes (the search's prediction of them with every Gaussian),
    which the precision search (:class:`AllocationConfig`, encoder/sizing.py ``PresetPoint``)
    spends, without a sketch (DECISIONS D-33, D-34). ``point=False`` keeps the preset's own
    shapes and sketch: a tileset's nodes, and the start of :func:`sized` and :func:`aimed`,
    whose targets choose the point themselves (a quality target keeps the preset's sketch: on
    kacytran without it its file was 8 % larger, docs/LOG.md 26.1)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}: use one of {', '.join(PRESETS)}")
    base = base or EncoderConfig()
    values = PRESETS[name]
    patch = dataclasses.replace(base.patch, entry_dims=dict(values["entry_dims"]),
                                position_bits=values.get("position_bits",
                                                         base.patch.position_bits))
    retrain_config, sketch_share = base.retrain, base.max_sketch_share
    if retrain:
        if not retrains(name):
            raise ValueError(f"preset {name!r} keeps every Gaussian and never retrains")
        retrain_config = dataclasses.replace(base.retrain or RetrainConfig(), **values["retrain"])
        patch = with_layers(patch, RETRAINED_PATCH_LAYERS)
        sketch_share = RETRAINED_MAX_SKETCH_SHARE
    on_curve = point and not retrain and retrains(name)
    return dataclasses.replace(
        base,
        patch=patch,
        refine=dataclasses.replace(base.refine, tau_max=values["tau_max"]),
        use_sketch=base.use_sketch and values.get("use_sketch", True) and not on_curve,
        retrain=retrain_config,
        max_sketch_share=sketch_share,
        keep_all=values["retrain"] is None,
        allocation=(base.allocation or AllocationConfig()) if on_curve else base.allocation,
    )


def with_layers(patch: PatchConfig, layers: int) -> PatchConfig:
    """``patch`` cut into ``layers`` layers: the default three keep their measured shares, any
    other count takes :func:`geometric_fractions`."""
    if layers == patch.layers:
        return patch
    default = PatchConfig()
    fractions = (default.layer_fractions if layers == default.layers
                 else geometric_fractions(layers))
    return dataclasses.replace(patch, layers=layers, layer_fractions=fractions)


def sized(config: EncoderConfig, target_size: int) -> EncoderConfig:
    """``config`` aimed at ``target_size`` bytes by rate control, with the smaller codebooks
    (:data:`TARGET_GROUPS_PER_ENTRY`) that leave the bytes to Gaussians, as ``--target-size``
    does; without retraining, with the precision search (:class:`AllocationConfig`), which
    keeps every Gaussian wherever some precision fits them all, and without a sketch, which the
    search's files never kept (DECISIONS D-30)."""
    searched = config.retrain is None
    return dataclasses.replace(
        config, target_size=target_size, use_sketch=config.use_sketch and not searched,
        allocation=AllocationConfig() if searched else config.allocation,
        patch=dataclasses.replace(config.patch, groups_per_entry=TARGET_GROUPS_PER_ENTRY))


def aimed(config: EncoderConfig, target_psnr: float) -> EncoderConfig:
    """``config`` aimed at ``target_psnr`` dB at the close-up framing by quality control, as
    ``--target-psnr`` does; without retraining, with the precision search
    (:class:`AllocationConfig`), which bisects the rate-distortion curve for the smallest
    precision that reaches it before it prunes (encoder/sizing.py)."""
    return dataclasses.replace(
        config, target_psnr=target_psnr,
        allocation=AllocationConfig() if config.retrain is None else config.allocation)


RETRAINING_OPTIONS = ("dataset", "iterations", "finish_iterations", "views", "close_views",
                      "resolution", "resume", "checkpoint_every", "downscale", "nested",
                      "nested_full_share")
"""Encode options (by their ``spcodec encode`` names, ``-`` as ``_``) that set up retraining."""
SURVIVOR_OPTIONS = ("target_size", "target_psnr", "patch_downsample")
"""Encode options that each choose how many patch Gaussians survive: one at most."""
ENCODE_OPTIONS = (*RETRAINING_OPTIONS, *SURVIVOR_OPTIONS, "prune", "no_retrain")
"""Every option :func:`check_options` judges."""


def check_options(preset: str, **options: object) -> bool:
    """Refuse encode options that contradict each other or ``preset``, with ValueError and the
    one-line message ``spcodec encode`` prints; return whether the encode retrains.

    ``options`` are named as on the command line (``no_retrain=True``, ``target_size="150k"``);
    None or False means not given. The rules live here, beside the presets they depend on, so a
    library caller building a configuration from such options is refused as the command is.
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}: use one of {', '.join(PRESETS)}")
    unknown = sorted(set(options) - set(ENCODE_OPTIONS))
    if unknown:
        raise ValueError(f"unknown encode options {', '.join(unknown)}: check_options judges "
                         f"{', '.join(ENCODE_OPTIONS)}")
    given = {name for name, value in options.items() if value is not None and value is not False}
    no_retrain = "no_retrain" in given
    retrain = not no_retrain and retrains(preset)
    without = "--no-retrain" if no_retrain else f"--preset {preset} (it never retrains)"
    if not retrain:
        named = [_flag(n) for n in RETRAINING_OPTIONS if n in given]
        if named:
            raise ValueError(f"{', '.join(named)} only apply to retraining: drop {without} or "
                             "them")
    targets = [_flag(n) for n in SURVIVOR_OPTIONS if n in given]
    if len(targets) > 1:
        raise ValueError(f"{' and '.join(targets)} each choose how many patch Gaussians survive: "
                         "give one of them")
    if "nested_full_share" in given and "nested" not in given:
        raise ValueError("--nested-full-share sets how --nested trains: give --nested too, or "
                         "drop it")
    if not retrain and ({"patch_downsample", "prune"} & given):
        raise ValueError(f"--patch-downsample and --prune need retraining, which {without} "
                         "leaves out (give --target-size to prune by importance without it)")
    return retrain


def _flag(name: str) -> str:
    """An option's name as the command line spells it."""
    return f"--{name.replace('_', '-')}"
