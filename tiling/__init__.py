"""Scenes bigger than one machine: a scene cut into a 3D Tiles 1.1 tileset of ``.spc`` nodes.

:func:`build_tileset` reads the input in chunks (:mod:`.source`), partitions it in two passes
into a median k-d tree (:mod:`.partition`; through blocks on disk when larger than one,
:mod:`.blocks`), merges children into coarser levels of detail
(:mod:`.grouping` picks the groups, :mod:`.merge` merges them), encodes every node on its own
with the no-retrain encoder (:mod:`.build`), as tasks on Dask (:mod:`.jobs`), and writes the
index (:mod:`.tileset`; ``spec/tileset.md``).
``python -m spcodec.tiling IN.ply -o OUT/`` runs it from a shell.
"""

from __future__ import annotations

from .config import TilingConfig
from .tileset_build import TilingSummary, build_tileset

__all__ = ["TilingConfig", "TilingSummary", "build_tileset"]
