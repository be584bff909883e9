"""The conformance suite of the spcodec bitstream (``spcodec.conformance``).

Test vectors under ``vectors/{valid,invalid}/<id>/``, described by ``manifest.json`` (the outcome
each decode must have, the expected output and its tolerances); a runner that judges a decoder
against them, in-process or through any command line (:mod:`.runner`); and the generator that
rebuilds every byte from seeded scenes (:mod:`.generate`, with the cases in :mod:`.valid_cases`
and :mod:`.invalid_cases`). ``conformance/README.md`` states the contract for other decoders.

Importing this package, or running the suite, needs only the decoder side of spcodec: never
torch, scikit-learn or scipy. Generating needs zstandard too.
"""

from .manifest import SUITE_DIR, Expected, Manifest, Outcome, Tolerance, Vector, load_manifest
from .runner import Decode, ExternalDecoder, InProcessDecoder, Report, run_suite

__all__ = [
    "SUITE_DIR", "Decode", "Expected", "ExternalDecoder", "InProcessDecoder", "Manifest", "Outcome",
    "Report", "Tolerance", "Vector", "load_manifest", "run_suite",
]
