"""Checkpoints of a long encode: written atomically beside the output, read back by ``--resume``.

A checkpoint holds what cannot be recomputed cheaply: the stage (``"retrain"`` or ``"finish"``),
the steps completed, the optimized tensors and the optimizer's moments, plus a fingerprint of the
input and of every setting that shapes the result. Everything before training (categorization,
sketch, targets, pruning) is deterministic for a seed and is simply run again on resume, so a
resumed encode writes the same bytes as an uninterrupted one.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spcodec.cloud import GaussianCloud
from spcodec.errors import UsageError
from spcodec.fileio import atomic_write

FORMAT = "spcodec-checkpoint-1"


def fingerprint(cloud: GaussianCloud, settings: dict[str, Any], extra: str = "") -> str:
    """sha256 over the input's arrays, the settings (as sorted JSON) and ``extra`` (targets)."""
    h = hashlib.sha256()
    for array in cloud.arrays().values():
        h.update(np.ascontiguousarray(array).tobytes())
    h.update(json.dumps(settings, sort_keys=True, default=str).encode())
    h.update(extra.encode())
    return h.hexdigest()


def checkpoint_path(output: str | Path) -> Path:
    """Where the checkpoint of an encode to ``output`` lives: ``OUTPUT.ckpt`` beside it."""
    output = Path(output)
    return output.with_name(output.name + ".ckpt")


@dataclass
class Checkpointer:
    """Reads and writes one checkpoint file for one encode (identified by ``fingerprint``)."""

    path: Path
    fingerprint: str

    def save(self, stage: str, step: int, state: dict[str, Any]) -> None:
        """Replace the checkpoint atomically (a crash mid-write leaves the previous one)."""
        buffer = io.BytesIO()
        torch.save({"format": FORMAT, "fingerprint": self.fingerprint, "stage": stage,
                    "step": step, "state": state}, buffer)
        atomic_write(self.path, buffer.getvalue())

    def load(self) -> dict[str, Any]:
        """The saved checkpoint; a one-line UsageError when it is missing, unreadable or made by
        another input or other settings."""
        if not self.path.exists():
            raise UsageError(f"--resume: no checkpoint at {self.path}")
        try:
            data = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - any unreadable file is the same user problem
            raise UsageError(f"checkpoint {self.path} cannot be read ({exc.__class__.__name__}); "
                             "delete it to start over") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise UsageError(f"{self.path} is not an spcodec checkpoint; delete it to start over")
        if data.get("fingerprint") != self.fingerprint:
            raise UsageError(f"checkpoint {self.path} was made from another input or other "
                             "settings; run with the same ones, or delete it to start over")
        return data

    def load_check(self, resume: bool) -> None:
        """The cheap part of :meth:`load` and :meth:`refuse_stale`: does a checkpoint exist as
        ``resume`` requires?"""
        if resume and not self.path.exists():
            raise UsageError(f"--resume: no checkpoint at {self.path}")
        if not resume:
            self.refuse_stale()

    def refuse_stale(self) -> None:
        """A fresh (non-resumed) encode must not silently overwrite a resumable checkpoint."""
        if self.path.exists():
            raise UsageError(f"a checkpoint of an interrupted encode exists at {self.path}: pass "
                             "--resume to continue it, or delete it to start over")

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)
