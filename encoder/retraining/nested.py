"""Nested retraining: every layer prefix of the file is a trained scene (``RetrainConfig.nested``).

Plain retraining optimizes all patch survivors together for the full file and then orders them
by importance into layers, so a prefix is the full scene with holes in it (guitar: the prefix
at 30 % of the bytes 20 dB under the full file, docs/LOG.md section 12). Here the layers are
fixed *before* training, by the same importance split the file would store, and every training
step renders one layer prefix (the sketch and patch layers 1..k) against the target: the whole
file at a share of the steps (``nested_full_share``), otherwise a shorter prefix drawn at
random. Gradients reach only the Gaussians the prefix holds, so layer 1 learns to stand on its
own, layer 2 to add to it, and so on, while the full file keeps most of its quality. The
quantization-aware finish draws prefixes the same way. The file keeps the trained layers: a
Gaussian never moves to another layer, and rate control drops from the last layer first.

Training the layers one after the other instead (each with the layers before it frozen) lost
3 dB on guitar's full file at 1000 steps: the later layers, trained a third of the steps each
against earlier layers that had moved, never caught up (docs/LOG.md 15).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from spcodec.cloud import GaussianCloud

from ..patch import PatchEncoder, PatchEncoding, Quantized, split_layers


def nested_groups(weights: np.ndarray, encoder: PatchEncoder) -> list[np.ndarray]:
    """The layers (indices into the survivors, first layer first) fixed before training: the
    encoder's importance split of ``weights``."""
    cfg = encoder.config
    return split_layers(np.asarray(weights, np.float64), cfg.layer_fractions, cfg.layers)


def layer_priority(importance: np.ndarray, layer_of: np.ndarray, layers: int) -> np.ndarray:
    """A score that orders Gaussians by layer first (layer 0 highest) and by ``importance``
    within a layer: its integer part is ``layers - layer``, so :class:`NestedEncoder` and
    :func:`layers_of` read the layer back, and every "keep the most important" choice (rate and
    quality control) keeps earlier layers whole."""
    importance = np.maximum(np.asarray(importance, np.float64), 0.0)
    top = importance.max() if len(importance) else 0.0
    scaled = importance / (2.0 * top) if top > 0 else np.zeros_like(importance)
    return (layers - np.asarray(layer_of, np.float64)) + scaled


def layers_of(priority: np.ndarray, layers: int) -> np.ndarray:
    """The layer (0 first) of each Gaussian of a :func:`layer_priority` score."""
    return layers - np.floor(np.asarray(priority, np.float64)).astype(np.int64)


class NestedEncoder(PatchEncoder):
    """A patch encoder whose layers are the ones training fixed: ``importance`` is a
    :func:`layer_priority` score, and each distinct integer part is one layer (the layer count
    stays the configured one; a layer emptied by rate control is stored empty)."""

    def layer(self, cloud: GaussianCloud, quantized: Quantized, importance: np.ndarray
              ) -> PatchEncoding:
        if np.shape(importance) != (len(cloud),) or len(quantized) != len(cloud):
            raise ValueError("cloud, quantized and importance must describe the same Gaussians")
        layers = self.config.layers
        layer_of = layers_of(importance, layers)
        if len(layer_of) and (layer_of.min() < 0 or layer_of.max() >= layers):
            raise ValueError("a nested priority names a layer the configuration does not have")
        groups = []
        for k in range(layers):
            members = np.flatnonzero(layer_of == k)
            groups.append(members[np.argsort(-importance[members], kind="stable")])
        return self.layer_groups(cloud, quantized, groups)


def prefix_ends(priority: np.ndarray, layers: int) -> list[int]:
    """Where each layer ends among Gaussians in layer order (the ends of the prefixes to train)
    for a :func:`layer_priority` score."""
    return np.cumsum(np.bincount(layers_of(priority, layers), minlength=layers)).tolist()


def prefix_schedule(ends: list[int], seed: int, full_share: float) -> Callable[[int], int | None]:
    """step -> how many of the model's first Gaussians the step trains: all of them (None) at
    ``full_share`` of the steps, otherwise the end of a shorter non-empty prefix drawn
    uniformly; seeded per step, so a resumed run draws the same prefixes."""
    shorter = sorted({end for end in ends[:-1] if 0 < end < ends[-1]}) if ends else []

    def visible(step: int) -> int | None:
        if not shorter:
            return None
        rng = np.random.default_rng([seed, 0x5E57ED, step])
        if rng.random() < full_share:
            return None
        return int(shorter[rng.integers(len(shorter))])
    return visible


@dataclass(frozen=True)
class NestedLayers:
    """Nested retraining's layers, fixed before training, and how training draws their prefixes:
    what :class:`~.stage.RetrainStage` is built with instead of having a schedule set on it.

    ``ends`` are where the layers end among the survivors put in layer order (:meth:`plan`)."""

    ends: list[int]
    seed: int
    full_share: float

    @classmethod
    def plan(cls, weights: np.ndarray, encoder: PatchEncoder, seed: int, full_share: float
             ) -> tuple[NestedLayers, np.ndarray]:
        """The layers of the survivors ranked by ``weights`` and the order (indices into the
        survivors) that puts them first layer first, as training and the file keep them."""
        groups = nested_groups(weights, encoder)
        order = np.concatenate(groups)
        return cls(np.cumsum([len(g) for g in groups]).tolist(), seed, full_share), order

    @property
    def layer_of(self) -> np.ndarray:
        """The layer of each survivor in layer order."""
        return np.repeat(np.arange(len(self.ends)), np.diff([0, *self.ends]))

    def encoder(self, encoder: PatchEncoder) -> NestedEncoder:
        """``encoder``'s settings, layering by the trained layers (:class:`NestedEncoder`)."""
        return NestedEncoder(encoder.config, seed=self.seed, jobs=encoder.jobs)

    def training(self) -> Callable[[int], int | None]:
        """The prefix each retraining step renders."""
        return prefix_schedule(self.ends, self.seed, self.full_share)

    def finishing(self, priority: np.ndarray, layers: int) -> Callable[[int], int | None]:
        """The prefix each finish step renders: of the layers rate or quality control left
        (``priority`` a :func:`layer_priority` score), drawn apart from training's."""
        return prefix_schedule(prefix_ends(priority, layers), self.seed + 1, self.full_share)
