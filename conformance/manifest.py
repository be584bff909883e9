"""The manifest of the conformance suite: what each vector is and what a decoder must make of it.

``manifest.json`` is the contract between the generator, which writes it, and every runner (ours,
and any other implementation's); its format is described in ``conformance/README.md``. Paths in it
are relative to the folder that holds it.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

FORMAT = "spcodec-conformance/1"
SUITE_DIR = Path(__file__).resolve().parent
"""The suite shipped with spcodec: this package's folder (``conformance/`` in the repository)."""

MANIFEST_NAME = "manifest.json"
KINDS = ("valid", "invalid")
ROW_KINDS = ("sketch", "patch")
"""Rows of an output: the sketch layer's Gaussians first, then the patch layers' ([R-48])."""


@dataclass(frozen=True)
class Tolerance:
    """A value passes when ``|got - want| <= abs + ulps * spacing(want)`` (binary32 spacing)."""

    abs: float = 0.0
    ulps: int = 0

    def to_json(self) -> dict:
        return {"abs": self.abs, "ulps": self.ulps}


EXACT = Tolerance()


@dataclass(frozen=True)
class Expected:
    """The expected output of a vector's decodes: a whole decode's rows, in output order."""

    path: str
    sha256: str
    gaussians: int
    sketch_gaussians: int
    sh_degree: int
    tolerances: dict[str, dict[str, Tolerance]]
    """Per row kind ("sketch", "patch"), per property group (see ``outputs.PROPERTY_GROUPS``)."""

    def tolerance(self, row_kind: str, group: str) -> Tolerance:
        return self.tolerances.get(row_kind, {}).get(group, EXACT)

    def to_json(self) -> dict:
        return {"path": self.path, "sha256": self.sha256, "gaussians": self.gaussians,
                "sketch_gaussians": self.sketch_gaussians, "sh_degree": self.sh_degree,
                "tolerances": {kind: {g: t.to_json() for g, t in groups.items()}
                               for kind, groups in self.tolerances.items()}}


@dataclass(frozen=True)
class Outcome:
    """What a conforming decoder does with the input for one ``max_layer`` (None: not given)."""

    max_layer: int | None
    gaussians: int | None = None
    error: str | None = None
    also_accepted: tuple[str, ...] = ()
    """Further codes a decoder may report: the input fails several checks (spec section 12)."""
    needs: tuple[str, ...] = ()
    """Optional decoder features the decode uses: "zstd" ([R-23])."""

    @property
    def accepts(self) -> bool:
        return self.error is None

    @property
    def label(self) -> str:
        return "-" if self.max_layer is None else str(self.max_layer)

    def to_json(self) -> dict:
        out: dict = {"max_layer": self.max_layer}
        if self.error is None:
            out["gaussians"] = self.gaussians
        else:
            out["error"] = self.error
        if self.also_accepted:
            out["also_accepted"] = list(self.also_accepted)
        if self.needs:
            out["needs"] = list(self.needs)
        return out


@dataclass(frozen=True)
class Vector:
    """One conformance vector: an input file and the outcomes it must have."""

    id: str
    kind: str
    title: str
    requirements: tuple[str, ...]
    input_path: str
    input_sha256: str
    input_size: int
    outcomes: tuple[Outcome, ...]
    expected: Expected | None = None
    defect: str | None = None
    """For invalid vectors: what is wrong with the file, in one sentence."""

    @property
    def error(self) -> str | None:
        """The code of the decode without ``max_layer`` (None for valid vectors)."""
        return next(o.error for o in self.outcomes if o.max_layer is None)

    def to_json(self) -> dict:
        out: dict = {"id": self.id, "kind": self.kind, "title": self.title}
        if self.defect:
            out["defect"] = self.defect
        out["requirements"] = list(self.requirements)
        out["input"] = {"path": self.input_path, "sha256": self.input_sha256,
                        "size": self.input_size}
        if self.error:
            out["error"] = self.error
        if self.expected is not None:
            out["expected"] = self.expected.to_json()
        out["outcomes"] = [o.to_json() for o in self.outcomes]
        return out


@dataclass
class Manifest:
    """The whole suite: where it lives, how it was generated, and its vectors."""

    root: Path
    vectors: list[Vector]
    generator: dict = field(default_factory=dict)
    spec_version: str = "1.2.1"

    def path(self, relative: str) -> Path:
        return self.root / relative

    def to_json(self) -> dict:
        return {"format": FORMAT, "spec_version": self.spec_version, "generator": self.generator,
                "vectors": [v.to_json() for v in self.vectors]}

    def dumps(self) -> str:
        """The manifest's text: one line per field of a vector, so that diffs of a regeneration
        read well; stable key order, so that regenerating gives the same bytes."""
        doc = self.to_json()
        head = {k: v for k, v in doc.items() if k != "vectors"}
        lines = ["{" + ", ".join(f"{json.dumps(k)}: {json.dumps(v)}" for k, v in head.items())
                 + ', "vectors": [']
        for i, vector in enumerate(doc["vectors"]):
            fields = [f" {json.dumps(k)}: {json.dumps(v)}" for k, v in vector.items()]
            end = "}" if i == len(doc["vectors"]) - 1 else "},"
            lines.append("{" + ",\n".join(fields)[1:] + end)
        return "\n".join(lines) + "\n]}\n"


class ManifestError(ValueError):
    """The manifest is missing or does not follow the format this runner reads."""


def sha256_file(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def load_manifest(root: Path | str = SUITE_DIR) -> Manifest:
    """Read ``root/manifest.json``."""
    root = Path(root)
    path = root / MANIFEST_NAME
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ManifestError(f"{path}: no conformance manifest here") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ManifestError(f"{path}: not JSON ({exc})") from None
    if doc.get("format") != FORMAT:
        raise ManifestError(f"{path}: format {doc.get('format')!r}, this runner reads {FORMAT!r}")
    try:
        vectors = [_vector(v) for v in doc["vectors"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise ManifestError(f"{path}: malformed vector entry ({exc!r})") from None
    return Manifest(root, vectors, doc.get("generator", {}), doc.get("spec_version", "1.0"))


def _vector(doc: dict) -> Vector:
    expected = doc.get("expected")
    if expected is not None:
        expected = Expected(
            expected["path"], expected["sha256"], int(expected["gaussians"]),
            int(expected["sketch_gaussians"]), int(expected["sh_degree"]),
            {kind: {g: Tolerance(float(t["abs"]), int(t["ulps"])) for g, t in groups.items()}
             for kind, groups in expected["tolerances"].items()})
    outcomes = tuple(
        Outcome(o["max_layer"], o.get("gaussians"), o.get("error"),
                tuple(o.get("also_accepted", ())), tuple(o.get("needs", ())))
        for o in doc["outcomes"])
    if doc["kind"] not in KINDS:
        raise ValueError(f"kind {doc['kind']!r}")
    if any((o.gaussians is None) == (o.error is None) for o in outcomes):
        raise ValueError(f"{doc['id']}: an outcome needs exactly one of gaussians and error")
    if expected is None and any(o.accepts for o in outcomes):
        raise ValueError(f"{doc['id']}: decodes succeed but no expected output is given")
    return Vector(doc["id"], doc["kind"], doc["title"], tuple(doc["requirements"]),
                  doc["input"]["path"], doc["input"]["sha256"], int(doc["input"]["size"]),
                  outcomes, expected, doc.get("defect"))
