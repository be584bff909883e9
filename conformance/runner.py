"""Running the conformance suite against a decoder: in-process, or any command line.

A *decoder* here is anything that turns an input file and an optional ``max_layer`` into a
:class:`Decode`: properties (accepted), an error code (rejected), or a *failure* when it broke the
contract (crashed, timed out, left output behind, wrote a PLY outside the contract). Each outcome
of each vector in the manifest is one decode; :func:`judge` says whether it passed. The runner
imports the decoder side of spcodec only (never torch, scikit-learn or scipy).
"""

from __future__ import annotations

import fnmatch
import re
import shlex
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from spcodec.errors import ERROR_CODES, FormatError, UsageError

from .manifest import Manifest, Outcome, Vector, load_manifest, sha256_file
from .outputs import (
    OutputError,
    Properties,
    check_property_set,
    cloud_properties,
    compare,
    read_expected,
    read_output_ply,
)

FORMAT_CODES = frozenset(ERROR_CODES) - {"ply-invalid", "dataset-invalid"}
"""The spec's error codes (section 12); the other two concern PLY and dataset input."""
_CODE = re.compile(r"\[([a-z][a-z-]*)\]")


@dataclass
class Decode:
    """What a decoder did with one input."""

    properties: Properties | None = None
    error: str | None = None
    failure: str | None = None
    """The decoder broke the contract (this fails the decode whatever was expected)."""

    @property
    def gaussians(self) -> int | None:
        return None if self.properties is None else len(self.properties["x"])

    def describe(self) -> str:
        if self.failure is not None:
            return "contract broken"
        if self.error is not None:
            return self.error
        return f"{self.gaussians} Gaussians"


class Decoder(Protocol):
    """A decoder under test."""

    name: str
    supports_max_layer: bool

    def decode(self, path: Path, max_layer: int | None, sh_degree: int | None) -> Decode:
        """Decode ``path`` (layers 0..max_layer when given); ``sh_degree`` is the file's, when
        the suite knows it, for checking the output's property set."""


class InProcessDecoder:
    """The reference decoder, called as a library (``spcodec.decode``)."""

    name = "spcodec (in-process)"
    supports_max_layer = True

    @property
    def lacks_zstd(self) -> bool:
        """The optional zstd codec is not installed here (``pip install spcodec`` without the
        ``zstd`` extra): vectors that need it must then fail with codec-unavailable."""
        from importlib.util import find_spec
        return find_spec("zstandard") is None

    def decode(self, path: Path, max_layer: int | None, sh_degree: int | None) -> Decode:
        import spcodec

        try:
            cloud = spcodec.decode(path.read_bytes(), max_layer=max_layer)
        except FormatError as exc:
            return Decode(error=exc.code)
        except Exception as exc:  # noqa: BLE001 - any other exception breaks [R-1]
            return Decode(failure=f"raised {type(exc).__name__}: {exc}")
        properties = cloud_properties(cloud)
        if sh_degree is not None:
            try:
                check_property_set(set(properties), sh_degree)
            except OutputError as exc:
                return Decode(properties=properties, failure=str(exc))
        return Decode(properties=properties)


class ExternalDecoder:
    """Another decoder's command line, run per decode under the contract of the README."""

    def __init__(self, template: str, max_layer_template: str | None = None,
                 timeout: float = 60.0) -> None:
        self.argv = shlex.split(template)
        if not any("{input}" in a for a in self.argv) or not any("{output}" in a for a in self.argv):
            raise UsageError(f"--decoder must contain {{input}} and {{output}}, got {template!r}")
        self.max_layer_argv = shlex.split(max_layer_template) if max_layer_template else None
        if self.max_layer_argv is not None and not any("{k}" in a for a in self.max_layer_argv):
            raise UsageError(f"--max-layer-arg must contain {{k}}, got {max_layer_template!r}")
        self.timeout = timeout
        self.name = template

    @property
    def supports_max_layer(self) -> bool:
        return self.max_layer_argv is not None

    def command(self, path: Path, output: Path, max_layer: int | None) -> list[str]:
        args = [a.replace("{input}", str(path)).replace("{output}", str(output)) for a in self.argv]
        if max_layer is not None:
            args += [a.replace("{k}", str(max_layer)) for a in self.max_layer_argv or []]
        return args

    def decode(self, path: Path, max_layer: int | None, sh_degree: int | None) -> Decode:
        with tempfile.TemporaryDirectory(prefix="spc-conformance-") as folder:
            output = Path(folder) / "output.ply"
            args = self.command(path, output, max_layer)
            try:
                done = subprocess.run(args, stdin=subprocess.DEVNULL, capture_output=True,
                                      timeout=self.timeout)
            except OSError as exc:  # not found, not executable: the command line is wrong
                raise UsageError(f"cannot run the decoder {args[0]}: "
                                 f"{exc.strerror or exc}") from None
            except subprocess.TimeoutExpired:
                return Decode(failure=f"ran past the {self.timeout:g} s timeout")
            stderr = done.stderr.decode("utf-8", "replace")
            if done.returncode < 0:
                return Decode(failure=f"killed by signal {-done.returncode}: {_last_line(stderr)}")
            if done.returncode == 0:
                return _accepted(output, sh_degree)
            left = sorted(p.name for p in Path(folder).iterdir())
            if left:
                return Decode(failure=f"rejected the input but left {', '.join(left)} behind")
            code = error_code(stderr)
            if code is None:
                return Decode(failure=f"exited {done.returncode} without an [error-code] on "
                                      f"stderr: {_last_line(stderr)!r}")
            return Decode(error=code)


def _accepted(output: Path, sh_degree: int | None) -> Decode:
    if not output.exists():
        return Decode(failure="exited 0 without writing the output")
    try:
        return Decode(properties=read_output_ply(output, sh_degree))
    except OutputError as exc:
        return Decode(failure=str(exc))


def error_code(stderr: str) -> str | None:
    """The first ``[code]`` on stderr that is one of the spec's codes."""
    return next((m for m in _CODE.findall(stderr) if m in FORMAT_CODES), None)


def _last_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1][:200] if lines else ""


# ------------------------------------------------------------------------------- judging
@dataclass
class Result:
    """One decode of one vector, judged."""

    vector: str
    kind: str
    max_layer: int | None
    expected: str
    got: str
    status: str
    """"pass", "fail" or "not run"."""
    reason: str = ""

    def to_json(self) -> dict:
        return {"vector": self.vector, "kind": self.kind, "max_layer": self.max_layer,
                "expected": self.expected, "got": self.got, "status": self.status,
                "reason": self.reason}


def allowed_errors(outcome: Outcome, without_zstd: bool) -> set[str]:
    """Codes a decoder may report for ``outcome`` (ID-1 and ID-4 of the spec's section 1.1)."""
    codes = set() if outcome.error is None else {outcome.error, *outcome.also_accepted}
    if without_zstd and "zstd" in outcome.needs:
        codes.add("codec-unavailable")
    return codes


def judge(outcome: Outcome, decode: Decode, want: Properties | None, vector: Vector,
          without_zstd: bool = False) -> tuple[bool, str]:
    """Whether ``decode`` is the outcome the manifest requires, and if not, why not."""
    if decode.failure is not None:
        return False, decode.failure
    allowed = allowed_errors(outcome, without_zstd)
    if decode.error is not None:
        if decode.error in allowed:
            return True, ""
        if outcome.accepts:
            return False, f"rejected a valid input with [{decode.error}]"
        return False, f"rejected with [{decode.error}], expected [{outcome.error}]" + (
            f" (or {', '.join(sorted(allowed - {outcome.error}))})" if len(allowed) > 1 else "")
    if not outcome.accepts:
        return False, f"accepted an input it must reject with [{outcome.error}]"
    problem = compare(decode.properties, want, vector.expected)
    return (problem is None), (problem or "")


# -------------------------------------------------------------------------------- the run
@dataclass
class Report:
    """Every judged decode of a run."""

    decoder: str
    suite: str
    results: list[Result] = field(default_factory=list)
    seconds: float = 0.0
    vectors: int = 0
    without_zstd: str = ""
    """Why decodes that need zstd expected codec-unavailable ("": they did not)."""

    def count(self, status: str) -> int:
        return sum(r.status == status for r in self.results)

    @property
    def failed_vectors(self) -> list[str]:
        return list(dict.fromkeys(r.vector for r in self.results if r.status == "fail"))

    @property
    def ok(self) -> bool:
        """Every selected decode ran and passed: a decode left unrun (no --max-layer-arg for an
        external decoder) is not a pass, or a decoder that cannot stop at a layer would conform."""
        return self.count("fail") == 0 and self.count("not run") == 0

    def to_json(self) -> dict:
        return {"decoder": self.decoder, "suite": self.suite, "vectors": self.vectors,
                "decodes": len(self.results), "passed": self.count("pass"),
                "failed": self.count("fail"), "not_run": self.count("not run"),
                "without_zstd": self.without_zstd or None,
                "seconds": round(self.seconds, 3), "failed_vectors": self.failed_vectors,
                "results": [r.to_json() for r in self.results]}

    def table(self) -> str:
        """The pass/fail table and the summary, as printed by ``spcodec conformance``."""
        width = max([len(r.vector) for r in self.results] + [6])
        lines = [f"{'vector':<{width}}  {'max_layer':<9}  {'expected':<24}  {'got':<24}  result"]
        for r in self.results:
            status = {"pass": "PASS", "fail": "FAIL", "not run": "not run"}[r.status]
            lines.append(f"{r.vector:<{width}}  {_layer(r.max_layer):<9}  {r.expected:<24}  "
                         f"{r.got:<24}  {status}{' ' + r.reason if r.reason else ''}")
        lines.append(self.summary())
        return "\n".join(lines)

    def summary(self) -> str:
        text = (f"{self.vectors} vectors, {len(self.results)} decodes: {self.count('pass')} "
                f"passed, {self.count('fail')} failed, {self.count('not run')} not run "
                f"({self.seconds:.1f} s, decoder: {self.decoder})")
        if self.failed_vectors:
            text += "\nfailed: " + ", ".join(self.failed_vectors)
        if self.count("not run"):
            text += ("\nnot conforming until every decode runs: give --max-layer-arg (how the "
                     "decoder is told to stop after layer k, e.g. '--max-layer {k}')")
        if self.without_zstd:
            text += f"\nwithout zstd: {self.without_zstd}; vectors needing it expect codec-unavailable"
        return text


def _layer(max_layer: int | None) -> str:
    return "-" if max_layer is None else str(max_layer)


def _describe(outcome: Outcome) -> str:
    return f"{outcome.gaussians} Gaussians" if outcome.accepts else outcome.error


def run_suite(decoder: Decoder, manifest: Manifest | None = None, only: list[str] | None = None,
              without_zstd: bool = False) -> Report:
    """Every outcome of every selected vector, decoded by ``decoder`` and judged."""
    manifest = manifest or load_manifest()
    vectors = [v for v in manifest.vectors
               if not only or any(fnmatch.fnmatchcase(v.id, pattern) for pattern in only)]
    report = Report(decoder.name, str(manifest.root), vectors=len(vectors))
    if without_zstd:
        report.without_zstd = "as asked (--without-zstd)"
    elif getattr(decoder, "lacks_zstd", False):
        without_zstd = True
        report.without_zstd = "the zstandard package is not installed (pip install 'spcodec[zstd]')"
    start = time.perf_counter()
    for vector in vectors:
        report.results += run_vector(decoder, manifest, vector, without_zstd)
    report.seconds = time.perf_counter() - start
    return report


def run_vector(decoder: Decoder, manifest: Manifest, vector: Vector,
               without_zstd: bool = False) -> list[Result]:
    """The judged decodes of one vector (its files' checksums checked first)."""
    path = manifest.path(vector.input_path)
    damaged = _damaged(manifest, vector)
    want_all = None
    if damaged is None and vector.expected is not None:
        want_all = read_expected(manifest.path(vector.expected.path), vector.expected)
    sh_degree = vector.expected.sh_degree if vector.expected is not None else None
    results = []
    for outcome in vector.outcomes:
        row = Result(vector.id, vector.kind, outcome.max_layer, _describe(outcome), "", "fail")
        if damaged is not None:
            row.reason = damaged
        elif outcome.max_layer is not None and not decoder.supports_max_layer:
            row.status, row.reason = "not run", "the decoder takes no --max-layer-arg"
        else:
            decode = decoder.decode(path, outcome.max_layer, sh_degree)
            want = None if want_all is None or not outcome.accepts else \
                {name: column[:outcome.gaussians] for name, column in want_all.items()}
            passed, row.reason = judge(outcome, decode, want, vector, without_zstd)
            row.got, row.status = decode.describe(), ("pass" if passed else "fail")
        results.append(row)
    return results


def _damaged(manifest: Manifest, vector: Vector) -> str | None:
    """A reason when the suite's own files are not those the manifest describes."""
    files = [(vector.input_path, vector.input_sha256)]
    if vector.expected is not None:
        files.append((vector.expected.path, vector.expected.sha256))
    for relative, digest in files:
        path = manifest.path(relative)
        if not path.exists():
            return f"suite damaged: {relative} is missing"
        if sha256_file(path) != digest:
            return f"suite damaged: the sha256 of {relative} differs from the manifest's"
    return None

