"""The generator: every vector, expected output and the manifest, byte for byte from the cases.

``spcodec conformance --generate DIR`` builds each case (``valid_cases.py``, ``invalid_cases.py``),
decodes it with the reference decoder to record its outcomes (without ``max_layer`` and for the
case's ``max_layer`` values), refuses a case whose outcome is not the declared one, writes the
expected output of the decodes that succeed, and emits a prefix vector for each layer boundary of
the cases that ask for them. The output depends on nothing but the cases and the zlib, zstd and
Draco encoders, whose versions the manifest records.
"""

from __future__ import annotations

import shutil
import tempfile
import zlib
from importlib import metadata as package_metadata
from pathlib import Path

import spcodec
from spcodec.codecs import gunzip, is_gzip, read_gzip_layer_ends
from spcodec.container import Codec
from spcodec.decoder.header import KNOWN_SECTIONS
from spcodec.errors import FormatError, UsageError
from spcodec.fileio import atomic_write
from spcodec.limits import DEFAULT_LIMITS
from spcodec.writer import layer_end_offsets

from .cases import Case, all_cases
from .manifest import MANIFEST_NAME, Expected, Manifest, Outcome, Vector, sha256_file
from .outputs import cloud_properties, write_npz
from .tolerances import tolerances

COMMAND = "spcodec conformance --generate DIR"


class GenerationError(AssertionError):
    """A case does not build the vector it declares (the reference decoder disagrees)."""


def generator_versions() -> dict:
    """What the bytes depend on besides the cases: the encoders' library versions."""
    import zstandard

    return {"command": COMMAND, "zlib": zlib.ZLIB_RUNTIME_VERSION,
            "zstd": ".".join(map(str, zstandard.ZSTD_VERSION)),
            "dracopy": package_metadata.version("DracoPy")}


def generate(out: Path | str, only: list[Case] | None = None) -> Manifest:
    """Write the suite into ``out`` (``out/vectors/`` replaced, ``out/manifest.json`` written)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    target = out / "vectors"
    if target.exists() and not (out / MANIFEST_NAME).exists():
        raise UsageError(f"{target} exists but {out} holds no {MANIFEST_NAME}: not replacing it")
    staging = Path(tempfile.mkdtemp(prefix=".vectors-", dir=out))
    try:
        vectors = []
        for case in only if only is not None else all_cases():
            vectors += emit(case, case.build(), staging)
        write_tables(staging, vectors)
        if target.exists():
            shutil.rmtree(target)
        staging.rename(target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    manifest = Manifest(out, vectors, generator_versions())
    atomic_write(out / MANIFEST_NAME, manifest.dumps().encode("utf-8"))
    return manifest


def emit(case: Case, data: bytes, staging: Path) -> list[Vector]:
    """The vector of ``case`` (and its prefix vectors), written under ``staging``."""
    folder = staging / case.kind / case.id
    folder.mkdir(parents=True)
    (folder / "input.spc").write_bytes(data)
    outcomes, decoded = record_outcomes(case, data, _max_layers(case, data))
    _check_declared(case, outcomes)
    expected = write_expected(case, data, outcomes, decoded, folder,
                              f"vectors/{case.kind}/{case.id}")
    relative = f"vectors/{case.kind}/{case.id}/input.spc"
    vectors = [Vector(case.id, case.kind, case.title, case.requirements, relative,
                      sha256_file(folder / "input.spc"), len(data), outcomes, expected,
                      case.defect)]
    if case.prefixes:
        vectors += prefix_vectors(case, data, expected, staging)
    return vectors


def _max_layers(case: Case, data: bytes) -> tuple[int, ...]:
    """The case's ``max_layer`` values; for valid cases every layer and one past the last."""
    if case.max_layers is not None:
        return case.max_layers
    if case.kind == "invalid":
        return ()
    return tuple(range(len(spcodec.inspect(data).header.layers) + 1))


Decoded = dict[int | None, spcodec.GaussianCloud]
"""The reference decoder's output for each ``max_layer`` that decodes."""


def record_outcomes(case: Case, data: bytes, max_layers: tuple[int, ...]
                    ) -> tuple[tuple[Outcome, ...], Decoded]:
    """What the reference decoder does with ``data`` for each ``max_layer``."""
    outcomes, decoded = [], {}
    for k in (None, *max_layers):
        needs = ("zstd",) if _needs_zstd(data, k) else ()
        try:
            decoded[k] = spcodec.decode(data, max_layer=k)
        except FormatError as exc:
            also = case.also_accepted if exc.code == case.error else ()
            outcomes.append(Outcome(k, error=exc.code, also_accepted=also, needs=needs))
        else:
            outcomes.append(Outcome(k, gaussians=len(decoded[k]), needs=needs))
    return tuple(outcomes), decoded


def _needs_zstd(data: bytes, max_layer: int | None) -> bool:
    """Whether decoding layers 0..max_layer of ``data`` inflates a zstd section ([R-23])."""
    try:
        header = spcodec.inspect(data).header
        inner = gunzip(data, DEFAULT_LIMITS.max_file_bytes).inner if is_gzip(data) else data
    except FormatError:
        return False
    if max_layer is None:
        layers = [layer for layer in header.layers if layer.end_offset <= len(inner)]
    else:
        layers = header.layers[:max_layer + 1]
    return any(sec.codec == Codec.ZSTD and sec.type in KNOWN_SECTIONS
               for layer in layers for sec in layer.sections)


def _check_declared(case: Case, outcomes: tuple[Outcome, ...]) -> None:
    full = outcomes[0]
    if case.kind == "valid" and not full.accepts:
        raise GenerationError(f"{case.id}: declared valid, but the reference decoder rejects it "
                              f"with [{full.error}]")
    if case.kind == "invalid" and full.error != case.error:
        got = "accepts it" if full.accepts else f"reports [{full.error}]"
        raise GenerationError(f"{case.id}: declared to be rejected with [{case.error}], but the "
                              f"reference decoder {got}")


def write_expected(case: Case, data: bytes, outcomes: tuple[Outcome, ...], decoded: Decoded,
                   folder: Path, relative: str) -> Expected | None:
    """The expected output of the largest successful decode, checked against the others."""
    accepted = [o for o in outcomes if o.accepts]
    if not accepted:
        return None
    widest = max(accepted, key=lambda o: o.gaussians)
    result = spcodec.decode_layers(data, max_layer=widest.max_layer)
    properties = cloud_properties(result.cloud)
    for outcome in accepted:
        part = cloud_properties(decoded[outcome.max_layer])
        if any(part[n].tobytes() != properties[n][:outcome.gaussians].tobytes() for n in part):
            raise GenerationError(f"{case.id}: the max_layer={outcome.max_layer} decode is not a "
                                  f"prefix of the widest decode")
    name = "expected.npz" if case.npz else "expected.ply"
    if case.npz:
        write_npz(folder / name, properties)
    else:
        spcodec.write_ply(folder / name, result.cloud)
    sketch_rows = len(result.layers[0].cloud)
    return Expected(f"{relative}/{name}", sha256_file(folder / name), len(result.cloud),
                    sketch_rows, result.header.sh_degree, tolerances(data, sketch_rows))


def prefix_vectors(case: Case, data: bytes, expected: Expected, staging: Path) -> list[Vector]:
    """A vector for each prefix of ``data`` that ends at a layer boundary but the last ([R-11]);
    they share the whole file's expected output."""
    wrapped = is_gzip(data)
    ends = read_gzip_layer_ends(data) if wrapped else layer_end_offsets(data)
    layers = len(ends)
    vectors = []
    for k, end in enumerate(ends[:-1]):
        prefix = data[:end]
        sub = Case(f"{case.id}-prefix-{k}", "valid",
                   f"{case.title}: the prefix that ends with layer {k}",
                   tuple(sorted(set(case.requirements) | {"R-11"} | ({"R-81"} if wrapped else set()),
                                key=lambda r: int(r[2:]))), lambda p=prefix: p)
        folder = staging / "valid" / sub.id
        folder.mkdir(parents=True)
        (folder / "input.spc").write_bytes(prefix)
        outcomes, _ = record_outcomes(sub, prefix, tuple(range(layers + 1)))
        _check_declared(sub, outcomes)
        whole = len(spcodec.decode(data, max_layer=k))
        if outcomes[0].gaussians != whole:
            raise GenerationError(f"{sub.id}: decodes {outcomes[0].gaussians} Gaussians, layers "
                                  f"0..{k} of the whole file hold {whole}")
        vectors.append(Vector(sub.id, "valid", sub.title, sub.requirements,
                              f"vectors/valid/{sub.id}/input.spc", sha256_file(folder / "input.spc"),
                              len(prefix), outcomes, expected))
    return vectors


def write_tables(staging: Path, vectors: list[Vector]) -> None:
    """``valid/README.md`` and ``invalid/README.md``: one line per vector."""
    valid = [v for v in vectors if v.kind == "valid"]
    lines = ["# Valid vectors", "",
             "Generated by `spcodec conformance --generate DIR`; `manifest.json` holds the outcomes "
             "and tolerances. Every conforming decoder decodes these files (a prefix decodes to the "
             "layers it holds; a `--max-layer` beyond them is `truncated`).", "",
             "| vector | what it holds | Gaussians | requirements |", "|---|---|---:|---|"]
    for v in valid:
        lines.append(f"| `{v.id}` | {v.title} | {v.outcomes[0].gaussians} | "
                     f"{', '.join(v.requirements)} |")
    (staging / "valid" / "README.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    invalid = [v for v in vectors if v.kind == "invalid"]
    lines = ["# Invalid vectors", "",
             "Generated by `spcodec conformance --generate DIR`: each file is a valid file with the "
             "defect below put in by the generator (`invalid_cases.py`), checksums repaired unless "
             "the defect is the checksum; nothing is edited by hand. A conforming decoder rejects "
             "each with the code given (or, where listed, another code of a check the file also "
             "fails: spec section 12). Some decode with `--max-layer`: see `manifest.json`.", "",
             "| vector | defect | error | requirements |", "|---|---|---|---|"]
    for v in invalid:
        also = v.outcomes[0].also_accepted
        code = f"`{v.error}`" + (f" (or {', '.join(f'`{c}`' for c in also)})" if also else "")
        lines.append(f"| `{v.id}` | {v.defect} | {code} | {', '.join(v.requirements)} |")
    (staging / "invalid" / "README.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
