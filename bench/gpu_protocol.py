"""The paper's protocol on a dense model, in one run a lent GPU finishes (issue 38).

Trains a vanilla 3DGS model on a dataset (``bench/train_vanilla.py``, gsplat on CUDA), then,
for each compression ratio asked (vanilla PLY bytes over file bytes), encodes it three ways at
the same size and judges every file against the dataset's held-out test images:

* **S&P++**: the default encode, retrained against the training images (``--dataset``);
* **Prune&Retrain**: every Gaussian patch (``--no-sketch``), pruned uniformly (``--prune
  uniform``), the same retraining budget: the paper's baseline;
* **no-retrain**: ``--no-retrain --target-size`` (and the ``balanced`` preset once).

S&P++ and Prune&Retrain of one ratio run at the same time on the one GPU. Every encode runs in
a child process (``measure`` below) that records its wall time, peak RSS and peak GPU memory
beside spcodec's own ``--stats`` (seconds per stage, sketch and patch counts, test PSNR/SSIM).
``summary.json`` is rewritten after each step, so a run cut short by its deadline still reports
what it finished. A 15-minute device session runs it through ``bench/gpu_protocol.sh``; on the
CPU a small smoke run checks the wiring::

    python bench/gpu_protocol.py DATASET --work /tmp/gp --out /tmp/gp-out --device cpu \\
        --downscale 16 --iterations 60 --init-points 3000 --ratios 20 --retrain-iterations 20 \\
        --finish-iterations 5 --max-views 8
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
WITHIN_DB = 0.3
"""The paper's "comparable quality": test PSNR within this much of the vanilla model's."""


@dataclass
class Protocol:
    """What one run does (recorded in summary.json)."""

    dataset: str
    work: Path
    out: Path
    device: str = "cuda"
    downscale: int = 1
    iterations: int = 3000
    init_points: int = 100_000
    max_views: int | None = None
    ratios: list[float] = field(default_factory=lambda: [100.0])
    retrain_iterations: int = 1000
    finish_iterations: int = 200
    threads: int = 2
    jobs: int = 4
    deadline_s: float = 540.0
    started: float = field(default_factory=time.monotonic)

    def left(self) -> float:
        """Seconds left before the deadline (never below one, so a child can start and stop)."""
        return max(1.0, self.deadline_s - (time.monotonic() - self.started))


class Summary:
    """summary.json in the output folder, rewritten whole after every step."""

    def __init__(self, protocol: Protocol) -> None:
        self.path = protocol.out / "summary.json"
        # folders by name only: the summary is committed to docs/results, machine paths are not
        named = {"dataset": Path(protocol.dataset).name, "work": protocol.work.name,
                 "out": protocol.out.name}
        self.doc: dict = {"protocol": {k: named.get(k, v) for k, v in vars(protocol).items()
                                       if k != "started"},
                          "steps": []}

    def add(self, step: dict) -> None:
        self.doc["steps"].append(step)
        self.write()

    def write(self) -> None:
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.doc, indent=1) + "\n")
        os.replace(tmp, self.path)


def spawn(argv: list[str], log: Path) -> subprocess.Popen:
    """A child process whose output goes to ``log``."""
    handle = open(log, "w")  # noqa: SIM115 - closed by finish()
    proc = subprocess.Popen(argv, stdout=handle, stderr=subprocess.STDOUT, text=True)
    proc.log_handle = handle  # type: ignore[attr-defined]
    return proc


def finish(proc: subprocess.Popen, timeout: float) -> dict:
    """Wait for ``proc`` until ``timeout`` seconds, killing it after; its exit and wall time."""
    start = time.monotonic()
    try:
        code = proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        code = "timed out"
    proc.log_handle.close()  # type: ignore[attr-defined]
    return {"exit": code, "waited_s": round(time.monotonic() - start, 1)}


def train_step(p: Protocol, summary: Summary) -> Path | None:
    """The vanilla model (MODEL.ply and MODEL.json), or None when training failed."""
    model = p.work / "vanilla.ply"
    argv = [sys.executable, str(HERE / "train_vanilla.py"), p.dataset, "-o", str(model),
            "--downscale", str(p.downscale), "--iterations", str(p.iterations),
            "--init-points", str(p.init_points), "--device", p.device, "--threads",
            str(p.threads), "--quiet"]
    if p.max_views:
        argv += ["--max-views", str(p.max_views)]
    result = finish(spawn(argv, p.out / "train.log"), p.left())
    step = {"step": "vanilla", **result}
    if result["exit"] == 0:
        record = json.loads(model.with_suffix(".json").read_text())
        step.update({key: record.get(key) for key in (
            "gaussians", "training_seconds", "seconds_per_step", "peak_rss_mib", "peak_gpu_mib",
            "test", "resolution", "training_views", "machine")})
        step["ply_bytes"] = model.stat().st_size
    summary.add(step)
    return model if result["exit"] == 0 else None


def encode_argv(p: Protocol, model: Path, name: str, extra: list[str]) -> list[str]:
    """A measured ``spcodec encode`` of ``model`` into ``work/NAME.spc``."""
    out = p.work / f"{name}.spc"
    return [sys.executable, str(Path(__file__).resolve()), "measure",
            str(p.work / f"{name}.measure.json"), "--", "encode", str(model), "-o", str(out),
            "--device", p.device, "--threads", str(p.threads), "--jobs", str(p.jobs), "--quiet",
            "--stats", str(p.work / f"{name}.stats.json"), *extra]


def retrained_args(p: Protocol, target: int) -> list[str]:
    argv = ["--dataset", p.dataset, "--downscale", str(p.downscale), "--target-size",
            str(target), "--iterations", str(p.retrain_iterations), "--finish-iterations",
            str(p.finish_iterations)]
    return argv


def read_result(p: Protocol, name: str, method: str, ratio: float | None,
                waited: dict) -> dict:
    """One encode's row: size, ratio, test quality, sketch share, time and memory per stage."""
    row: dict = {"step": name, "method": method, "ratio_asked": ratio, **waited}
    stats_path, measure_path = (p.work / f"{name}.stats.json", p.work / f"{name}.measure.json")
    if measure_path.exists():
        row.update(json.loads(measure_path.read_text()))
    if stats_path.exists():
        stats = json.loads(stats_path.read_text())
        row.update({"bytes": stats["bytes"], "gaussians_in": stats["gaussians"],
                    "sketch_gaussians": stats["sketch_gaussians"],
                    "patch_gaussians": stats["patch_gaussians"],
                    "seconds": {k: round(v, 1) for k, v in stats["seconds"].items()},
                    "quality": _named(stats.get("quality"), p.dataset)})
    return row


def _named(quality: dict | None, dataset: str) -> dict | None:
    """``quality`` with the dataset named by its folder's name, not its path on this machine."""
    if quality is None or "against" not in quality:
        return quality
    return {**quality, "against": quality["against"].replace(dataset, Path(dataset).name)}


def evaluate(p: Protocol, name: str) -> dict | None:
    """Test PSNR/SSIM of ``work/NAME.spc`` against the dataset (as ``spcodec eval`` reports)."""
    # through measure, not ``-m spcodec.cli``: run from a checkout, -m would import the source
    # folders (whose subpackages only an install maps) instead of the installed spcodec
    argv = [sys.executable, str(Path(__file__).resolve()), "measure",
            str(p.work / f"{name}.eval.measure.json"), "--", "eval", str(p.work / f"{name}.spc"),
            "--dataset", p.dataset, "--downscale", str(p.downscale), "--device", p.device,
            "--json"]
    log = p.out / f"{name}.eval.log"
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=p.left())
    log.write_text(proc.stderr)
    if proc.returncode != 0:
        return None
    doc = json.loads(proc.stdout)
    return {"psnr": doc["psnr"], "ssim": doc["ssim"], "lpips": doc.get("lpips")}


def ratio_step(p: Protocol, summary: Summary, model: Path, ply_bytes: int, ratio: float) -> None:
    """S&P++ and Prune&Retrain (at once) and no-retrain, all aimed at ``ply_bytes / ratio``."""
    target = int(ply_bytes / ratio)
    tag = f"{ratio:g}x"
    runs = {f"sp_{tag}": ("S&P++", []),
            f"pr_{tag}": ("Prune&Retrain", ["--no-sketch", "--prune", "uniform"])}
    procs = {name: spawn(encode_argv(p, model, name, retrained_args(p, target) + extra),
                         p.out / f"{name}.log") for name, (_, extra) in runs.items()}
    for name, proc in procs.items():
        summary.add(read_result(p, name, runs[name][0], ratio, finish(proc, p.left())))
    name = f"nr_{tag}"
    waited = finish(spawn(encode_argv(p, model, name, ["--no-retrain", "--target-size",
                                                        str(target)]), p.out / f"{name}.log"),
                    p.left())
    row = read_result(p, name, "no-retrain", ratio, waited)
    if waited["exit"] == 0:
        row["quality"] = evaluate(p, name)
    summary.add(row)


def run(p: Protocol) -> dict:
    p.work.mkdir(parents=True, exist_ok=True)
    p.out.mkdir(parents=True, exist_ok=True)
    summary = Summary(p)
    model = train_step(p, summary)
    if model is None:
        return summary.doc
    ply_bytes = model.stat().st_size
    for ratio in p.ratios:
        if p.left() <= 1.0:
            break
        ratio_step(p, summary, model, ply_bytes, ratio)
    if p.left() > 1.0:
        waited = finish(spawn(encode_argv(p, model, "nr_balanced", ["--no-retrain"]),
                              p.out / "nr_balanced.log"), p.left())
        row = read_result(p, "nr_balanced", "no-retrain balanced", None, waited)
        if waited["exit"] == 0:
            row["quality"] = evaluate(p, "nr_balanced")
        summary.add(row)
    summary.doc["findings"] = findings(summary.doc)
    summary.write()
    return summary.doc


def findings(doc: dict) -> dict:
    """The issue's figures from the rows: ratio within 0.3 dB of vanilla, S&P++ minus P&R."""
    vanilla = next((s for s in doc["steps"] if s["step"] == "vanilla"), {})
    base = (vanilla.get("test") or {}).get("psnr")
    rows = [s for s in doc["steps"] if s.get("bytes") and s.get("quality")]
    out: dict = {"vanilla_test_psnr": base}
    for row in rows:
        row["ratio"] = round(vanilla["ply_bytes"] / row["bytes"], 1)
    if base is not None:
        within = [r["ratio"] for r in rows if r["quality"]["psnr"] >= base - WITHIN_DB]
        out["largest_ratio_within_0.3_dB"] = max(within, default=None)
    by_ratio: dict = {}
    for row in rows:
        by_ratio.setdefault(row["ratio_asked"], {})[row["method"]] = row["quality"]["psnr"]
    out["sp_minus_pr_db"] = {str(r): round(m["S&P++"] - m["Prune&Retrain"], 3)
                             for r, m in by_ratio.items() if {"S&P++", "Prune&Retrain"} <= set(m)}
    return out


def measure(stats_path: str, argv: list[str]) -> int:
    """Run ``spcodec ARGV`` in this process; write its exit, wall time and peak memory."""
    from spcodec.cli import main as spcodec_main

    start = time.perf_counter()
    try:
        code = spcodec_main(argv)
    except SystemExit as exc:  # argparse and the CLI's own exits
        code = exc.code if isinstance(exc.code, int) else 1
    doc = {"exit": code, "wall_s": round(time.perf_counter() - start, 1),
           "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
           "peak_gpu_mib": None}
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_available() and torch.cuda.is_initialized():
        doc["peak_gpu_mib"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
    Path(stats_path).write_text(json.dumps(doc) + "\n")
    return int(code or 0)


def parse_args(argv: list[str]) -> Protocol:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("dataset")
    p.add_argument("--work", type=Path, required=True, help="models and .spc files (large)")
    p.add_argument("--out", type=Path, required=True, help="summary.json and the logs (small)")
    p.add_argument("--device", default="cuda", choices=["cpu", "cuda"])
    p.add_argument("--downscale", type=int, default=1)
    p.add_argument("--iterations", type=int, default=3000, help="vanilla training steps")
    p.add_argument("--init-points", type=int, default=100_000)
    p.add_argument("--max-views", type=int, default=None)
    p.add_argument("--ratios", type=float, nargs="+", default=[100.0],
                   help="vanilla PLY bytes over file bytes, one encode trio each")
    p.add_argument("--retrain-iterations", type=int, default=1000)
    p.add_argument("--finish-iterations", type=int, default=200)
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads per process")
    p.add_argument("--jobs", type=int, default=4, help="encoder worker processes per encode")
    p.add_argument("--deadline", type=float, default=540.0, dest="deadline_s",
                   help="seconds the whole run may take; a step past it is stopped")
    args = p.parse_args(argv)
    return Protocol(**vars(args))


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["measure"]:
        split = argv.index("--")
        return measure(argv[1], argv[split + 1:])
    doc = run(parse_args(argv))
    print(json.dumps(doc.get("findings", {}), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
