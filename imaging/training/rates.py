"""The learning rates of every training loop: the 3DGS defaults and the position schedule.

Plain numbers, no torch: the encoder's configuration holds them without loading the trainer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class LearningRates:
    """Adam rates per attribute (the 3DGS defaults); ``position_*`` are multiplied by the extent."""

    #: Position rate at the first and the last iteration, per unit of scene extent.
    position_init: float = 1.6e-4
    position_final: float = 1.6e-6
    #: SH DC (base colour); the higher bands use ``sh_dc / sh_rest_divisor``.
    sh_dc: float = 2.5e-3
    sh_rest_divisor: float = 20.0
    opacity: float = 2.5e-2
    scale: float = 5e-3
    rotation: float = 1e-3

    def scaled(self, factor: float) -> "LearningRates":
        """Every rate times ``factor`` (a fine-tune of a converged model may want less)."""
        return LearningRates(**{f.name: getattr(self, f.name) * factor
                                if f.name != "sh_rest_divisor" else self.sh_rest_divisor
                                for f in fields(self)})


def position_rate(rates: LearningRates, extent: float, step: int, total: int) -> float:
    """Log-linear decay from ``position_init`` to ``position_final`` over ``total`` steps."""
    t = min(max(step / max(total, 1), 0.0), 1.0)
    log_rate = (1.0 - t) * math.log(rates.position_init) + t * math.log(rates.position_final)
    return math.exp(log_rate) * extent
