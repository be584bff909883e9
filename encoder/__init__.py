"""The spcodec reference encoder (extra ``encoder``).

``spcodec.encoder.encode(cloud, config)`` runs the no-retrain pipeline (categorize, refine, sketch,
patch, write) and returns the file with its :class:`EncodeStats`; :class:`EncoderConfig` holds every
parameter; :func:`preset_config` gives the named operating points (with ``retrain=True``, the
retrained layout the CLI writes); :func:`sized` aims one at a file size and :func:`aimed` at a
quality. The picture tools it trains and judges with (renderer, cameras, datasets, metrics,
evaluation) are a package of their own, :mod:`spcodec.imaging`. Names are resolved on first use, so
``import spcodec.encoder`` alone loads neither scikit-learn nor torch.
"""

from __future__ import annotations

from typing import Any

_EXPORTS = {
    "encode": "pipeline", "EncoderConfig": "pipeline", "EncodeResult": "pipeline",
    "EncodeStats": "statistics",
    "preset_config": "presets", "PRESETS": "presets", "sized": "presets", "aimed": "presets",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        from importlib import import_module
        return getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
