"""How a long encode runs: the device, checkpoints and a clean stop on request.

None of it changes the bytes written, so it is not in the file's settings; it sits apart from the
retraining stage so that the pipeline and the command line can hold one without building a stage.
"""

from __future__ import annotations

import contextlib
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from spcodec.errors import UsageError
from spcodec.imaging.training.checkpoint import Checkpointer
from spcodec.imaging.training.loop import StepReport


@dataclass
class RunControl:
    """How a long encode runs; none of it changes the bytes written (so it is not in the
    file's settings)."""

    #: "auto" (CUDA when torch sees a GPU), "cpu" or "cuda[:N]".
    device: str = "auto"
    #: Checkpoint file (None: none is written) and how often it is rewritten, in optimizer steps.
    #: It is removed when the encode completes.
    checkpoint: Path | None = None
    checkpoint_every: int = 500
    #: Continue from the checkpoint instead of starting over.
    resume: bool = False
    #: Set to stop after the step in progress (a checkpoint is written first).
    stop: threading.Event = field(default_factory=threading.Event)
    #: Called after every optimizer step with the stage name ("retrain", "finish").
    on_step: Callable[[str, StepReport], None] | None = None
    #: How to resume, for the interruption message (the CLI fills in its command line).
    resume_hint: str = "run the same encode again with resume enabled"
    #: True while an optimization loop runs (it then stops cleanly on ``stop``); a Ctrl-C handler
    #: aborts at once otherwise, since there is nothing to save.
    stoppable: bool = False

    def check_checkpoint(self) -> None:
        """Fail before any work when resuming without a checkpoint, or when a fresh run would
        overwrite one (the stage checks the fingerprint itself when it loads it)."""
        if self.checkpoint is None:
            if self.resume:
                raise UsageError("resuming needs a checkpoint path")
            return
        Checkpointer(Path(self.checkpoint), "").load_check(self.resume)

    @contextlib.contextmanager
    def stoppable_section(self) -> Iterator[None]:
        self.stoppable = True
        try:
            yield
        finally:
            self.stoppable = False
