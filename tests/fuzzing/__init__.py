"""Structure-aware fuzzing of the spcodec decoder, with checksum repair.

Every byte of a valid file is covered by the header CRC or a section CRC, so random byte flips die
at the CRC checks and never reach the parsers behind them. The mutators here change *structure*
and then repair the checksums, so the mutant reaches the layer they aim at:

* ``payload`` / ``stored`` (:mod:`.payloads`): a section's raw payload edited field by field where
  the layout is known (cluster records, codebooks, positions, Draco headers, metadata JSON) and
  recompressed, or its stored bytes damaged; CRCs derived again;
* ``header``, ``sections``, ``truncate``, ``append``, ``flip``, ``splice`` (:mod:`.structure`):
  header, layer-table and TOC fields (header CRC recomputed), section lists reshuffled, cuts,
  trailing bytes, unrepaired flips, one file's header on another's sections;
* ``claim`` (:mod:`.claims`): a count or length claiming far more than the file holds;
* ``gzip`` (:mod:`.wrapper`): the (mutated) inner file re-wrapped, or the wrapper itself edited.

:mod:`.oracle` holds the contract every decoding entry point is held to (:func:`check_input`).
The mutators take their decisions from a :class:`~.choosers.Chooser`: hypothesis in
``tests/test_fuzz.py`` and ``tests/test_web_decoder.py``, ``random.Random`` or atheris in the
by-hand driver ``bench/fuzz_decoder.py``, which runs them for as long as you like.
"""

from .choosers import AtherisChooser, Chooser, RandomChooser, chance, choice
from .mutants import INNER_MUTATORS, KIND_WEIGHTS, make_mutant
from .oracle import Finding, Outcome, check_input
from .seeds import SeedFile, build_seeds

__all__ = ["AtherisChooser", "Chooser", "Finding", "INNER_MUTATORS", "KIND_WEIGHTS", "Outcome",
           "RandomChooser", "SeedFile", "build_seeds", "chance", "check_input", "choice",
           "make_mutant"]
