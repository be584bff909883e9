"""Experiment (issue 18, docs/LOG.md 15.7): a standalone preview file frozen in front of the
main encode. Patches the encoder's SceneWriter; kept to make 15.7 reproducible, not a feature.

    PREVIEW=small.spc python bench/experiments/preview_frozen.py encode IN.ply -o MAIN.spc \
        --target-size N --threads 1
    python bench/experiments/judge_preview.py rows.json LABEL small.spc MAIN.spc

PREVIEW=path.spc: its decoded Gaussians are rendered in front of the patch during retraining and
ranking, like the sketch (so the main file learns to add to them); the main file is written as
usual. The judge shows preview + main prefix.
"""
import os
import sys

import spcodec
from spcodec.cloud import GaussianCloud
from spcodec.encoder import stages

preview = spcodec.decode(open(os.environ["PREVIEW"], "rb").read())
_decoded = stages.SceneWriter.decoded_sketch


def decoded_sketch(self):
    sketch = _decoded(self)
    return GaussianCloud.concat([c for c in (preview, sketch) if len(c)])


stages.SceneWriter.decoded_sketch = decoded_sketch
from spcodec.cli import main  # noqa: E402

sys.exit(main(sys.argv[1:]))
