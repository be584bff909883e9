"""How long the training still takes: the steps timed as they run, and the progress callback that
shows it (with the one line that corrects the first estimate once the steps' rate is known).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from ..estimate import RunEstimate, duration

CORRECT_AFTER = 50
"""Retraining steps after which their measured rate corrects the first estimate (one line)."""


@dataclass
class TrainingClock:
    """Times the training steps as they run, to tell how long every stage still to come takes
    (the rest of this one, the later training stages, and ``after``: the seconds of work after
    the last step, the closing evaluation's and the checks', as the first estimate put them).
    ``after`` scales as the steps run faster or slower than the probe's ``probe_step`` (the
    machine's load moves both alike)."""

    after: float = 0.0
    probe_step: float | None = None
    first: float | None = None
    """When the first step of this run ended (the rate counts the steps after it)."""
    steps: int = 0

    def tick(self) -> None:
        """One more step done."""
        if self.first is None:
            self.first = time.perf_counter()
        else:
            self.steps += 1

    @property
    def per_step(self) -> float:
        """Seconds per step so far (NaN before two)."""
        if not self.steps:
            return float("nan")
        return (time.perf_counter() - self.first) / self.steps

    def eta_all(self, left: int) -> float:
        """Seconds for ``left`` more steps and the work after them at the rate so far."""
        pace = self.per_step / self.probe_step if self.probe_step and self.steps else 1.0
        return left * self.per_step + self.after * pace


def correction_line(clock: TrainingClock, estimate: RunEstimate, left: int) -> str:
    """The first estimate corrected with the training steps' measured rate."""
    return (f"estimate corrected: {clock.steps} steps measured at {clock.per_step:.2f} s each "
            f"(the probe said {estimate.step:.2f} s): the rest of the encode takes about "
            f"{duration(clock.eta_all(left))}")


def meter(stage, clock: TrainingClock, later: int = 0, estimate: RunEstimate | None = None):
    """A step callback that moves a progress stage, shows loss and PSNR and the ETA of all that
    is left (``later``: steps of the training stages after this one), starts a resumed run
    at its step, and after :data:`CORRECT_AFTER` steps says how ``estimate`` was off."""
    def on_step(report) -> None:
        if not on_step.seen and report.step > 1:
            stage.resumed(report.step - 1)
        on_step.seen = True
        clock.tick()
        left = report.total - report.step + later
        if estimate is not None and clock.steps == CORRECT_AFTER:
            stage.note(correction_line(clock, estimate, left))
        stage.update(1, loss=report.loss, psnr=report.psnr, eta_all=clock.eta_all(left))
    on_step.seen = False
    return on_step
