"""By-hand structure-aware fuzzing of the spcodec decoder, for as long as you like.

The mutators (payloads, stored bytes, header and section lists, claims, the gzip wrapper; each
repairs the checksums so the damage reaches the parsers behind the CRCs) and the oracle (every
decoding entry point either succeeds with finite arrays of consistent length or raises a
``FormatError`` with a code of the spec's list, nothing else, no warning; the stream decoder
accepts what ``decode_layers`` accepts) live in the test tree, ``tests/fuzzing/``, where
``tests/test_fuzz.py`` drives them through hypothesis. This script adds what only a long run
needs: a time bound per input (an interval timer interrupts a hang), tracemalloc on every n-th
input against a memory bound, an address-space limit with DracoPy's MemoryErrors counted (the
decoder turns them into ``draco-failed``, which would hide a blob that asked Draco for
gigabytes), reproducers for each finding, and ``current.bin`` in the output folder, the input
being tried, should the process die. ``--atheris`` runs a coverage-guided search instead (a
chooser backed by atheris' ``FuzzedDataProvider``).

    python bench/fuzz_decoder.py --iterations 200000 [--seconds 1200] [--seed 1] [--out DIR]
    python bench/fuzz_decoder.py --replay DIR/finding-0001.bin
    python bench/fuzz_decoder.py --atheris -- -max_total_time=600
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import random
import resource
import signal
import sys
import tempfile
import time
import traceback
import tracemalloc
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from fuzzing import (  # noqa: E402  tests/ is on sys.path
    KIND_WEIGHTS,
    AtherisChooser,
    Chooser,
    Finding,
    RandomChooser,
    build_seeds,
    check_input,
    choice,
    make_mutant,
)


class DracoWatch:
    """Counts DracoPy MemoryErrors: decode_points turns them into draco-failed, which hides a
    blob that made Draco ask for gigabytes (the bench runs under an address-space limit)."""

    def __init__(self) -> None:
        import DracoPy

        self.module, self.original, self.hits = DracoPy, DracoPy.decode, 0

        def watched(blob, *args, **kwargs):
            try:
                return self.original(blob, *args, **kwargs)
            except MemoryError:
                self.hits += 1
                raise

        DracoPy.decode = watched

    def close(self) -> None:
        self.module.decode = self.original


# ============================================================================ the runner
@dataclass
class Stats:
    """Counters of a fuzz run."""

    executions: int = 0
    by_kind: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    by_code: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    findings: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    slowest: float = 0.0
    peak_ratio: float = 0.0


class _Timeout(TimeoutError):
    pass


def _alarm(signum, frame):  # pragma: no cover - only fires on a hang
    raise _Timeout("execution exceeded the time bound")


def save_reproducer(out: Path, index: int, kind: str, data: bytes, problem: str) -> Path:
    """Write the input and a note on what went wrong; return the input's path."""
    path = out / f"finding-{index:04d}-{kind}.bin"
    path.write_bytes(data)
    path.with_suffix(".txt").write_text(problem + "\n")
    return path


def fuzz(iterations: int, seconds: float, rng_seed: int, out: Path, time_bound: float,
         memory_every: int, report_every: float = 30.0) -> Stats:
    """Run mutants until ``iterations`` or ``seconds`` run out; save findings under ``out``."""
    seeds = build_seeds()
    for seed in seeds:  # the corpus itself must decode
        check_input(seed.data, RandomChooser(random.Random(0)))
    rng = random.Random(rng_seed)
    ch = RandomChooser(rng)
    stats, watch = Stats(), DracoWatch()
    signal.signal(signal.SIGALRM, _alarm)
    current = out / "current.bin"  # survives a crash of the process: the last input tried
    start = last_report = time.perf_counter()
    seen_problems: dict[str, int] = {}
    try:
        while stats.executions < iterations and time.perf_counter() - start < seconds:
            kind, data = make_mutant(seeds, ch)
            current.write_bytes(data)
            problem = _execute(data, ch, stats, watch, time_bound,
                               stats.executions % memory_every == 0)
            stats.executions += 1
            stats.by_kind[kind] += 1
            if problem:
                key = problem.split(":")[0] + ":" + problem.split(":")[1][:60] \
                    if ":" in problem else problem
                stats.findings[key] += 1
                if seen_problems.setdefault(key, 0) < 3:
                    seen_problems[key] += 1
                    path = save_reproducer(out, sum(seen_problems.values()), kind, data, problem)
                    print(f"FINDING [{kind}] {problem}\n  reproducer: {path}", flush=True)
            if time.perf_counter() - last_report > report_every:
                last_report = time.perf_counter()
                _report(stats, last_report - start)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        watch.close()
    _report(stats, time.perf_counter() - start, final=True)
    return stats


def _execute(data: bytes, ch: Chooser, stats: Stats, watch: DracoWatch, time_bound: float,
             measure: bool) -> str | None:
    """Check one input; return a description of a finding, or None."""
    before = watch.hits
    if measure:
        tracemalloc.start()
    signal.setitimer(signal.ITIMER_REAL, time_bound * 4)
    t0 = time.perf_counter()
    try:
        outcome = check_input(data, ch)
    except Finding as exc:
        return f"{exc.target}: {exc.problem}"
    except _Timeout:
        return "hang: no answer within the time bound"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        elapsed = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1] if measure else 0
        if measure:
            tracemalloc.stop()
    stats.slowest = max(stats.slowest, elapsed)
    for code in outcome.results.values():
        stats.by_code[code] += 1
    if watch.hits != before:
        return "draco-memory: DracoPy raised MemoryError (asked for more than the address space)"
    if elapsed > time_bound:
        return f"slow: {elapsed:.2f} s for a {len(data)}-byte input"
    if measure:
        ratio = peak / (len(data) + 1)
        stats.peak_ratio = max(stats.peak_ratio, ratio)
        if peak > memory_bound(len(data)):
            return f"memory: traced peak {peak / 2**20:.1f} MiB for a {len(data)}-byte input"
    return None


def memory_bound(size: int) -> int:
    """Peak traced memory allowed for decoding every target on an input of ``size`` bytes.

    Generous on purpose: an honest decode expands a small file by its compression ratio and the
    output's 236 bytes per Gaussian; what this catches is allocation sized by a claimed count.
    """
    return 512 * size + 32 * 2**20


def _report(stats: Stats, elapsed: float, final: bool = False) -> None:
    rate = stats.executions / max(elapsed, 1e-9)
    print(f"{'FINAL ' if final else ''}{stats.executions} executions in {elapsed:.0f} s "
          f"({rate:.0f}/s); slowest {stats.slowest * 1000:.0f} ms; peak/input "
          f"{stats.peak_ratio:.0f}x; findings {sum(stats.findings.values())}", flush=True)
    if final:
        print("by mutation kind:", dict(stats.by_kind.most_common()))
        print("by result (per target call):", dict(stats.by_code.most_common()))
        print("findings:", dict(stats.findings.most_common()) or "none")


def replay(path: Path) -> int:
    """Run one saved input through every target and print what happens."""
    data = path.read_bytes()
    try:
        outcome = check_input(data, RandomChooser(random.Random(0)))
    except Finding as exc:
        traceback.print_exception(exc.cause or exc)
        print(f"FINDING {exc}")
        return 1
    print(outcome.results)
    return 0


# ================================================================================ atheris
def run_atheris(argv: list[str]) -> None:  # pragma: no cover - by hand only
    """Coverage-guided fuzzing: atheris chooses the mutations, the oracle is the same.

    The choices come from libFuzzer's input, so its corpus and crash files replay through this
    mode (``--atheris -- crash-<hash>``), not through ``--replay``. Slow (about 20 inputs/s on
    the 2-core machine: every loaded module is instrumented, numpy's Python parts included);
    it complements the random mode, it does not replace it.
    """
    import atheris

    atheris.instrument_all()  # spcodec is already imported: instrument what is loaded
    seeds = build_seeds()

    def one_input(raw: bytes) -> None:
        ch = AtherisChooser(atheris.FuzzedDataProvider(raw))
        _, data = make_mutant(seeds, ch, choice(ch, list(KIND_WEIGHTS)))
        check_input(data, ch)

    atheris.Setup([sys.argv[0]] + argv, one_input)
    atheris.Fuzz()


# =================================================================================== main
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--iterations", type=int, default=200_000)
    parser.add_argument("--seconds", type=float, default=float("inf"))
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=None,
                        help="folder for reproducers (default: a new temporary folder)")
    parser.add_argument("--time-bound", type=float, default=2.0,
                        help="seconds one input may take through all targets")
    parser.add_argument("--memory-every", type=int, default=25,
                        help="measure traced peak memory on every n-th input")
    parser.add_argument("--address-space-gib", type=float, default=8.0,
                        help="RLIMIT_AS for this process, so a runaway allocation fails")
    parser.add_argument("--replay", type=Path, default=None)
    parser.add_argument("--atheris", action="store_true")
    args, rest = parser.parse_known_args(argv)
    if args.replay:
        return replay(args.replay)
    limit = int(args.address_space_gib * 2**30)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    if args.atheris:
        run_atheris(rest)
        return 0
    out = args.out or Path(tempfile.mkdtemp(prefix="spcodec-fuzz-"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"reproducers go to {out}", flush=True)
    stats = fuzz(args.iterations, args.seconds, args.seed, out, args.time_bound,
                 args.memory_every)
    return 1 if stats.findings else 0


if __name__ == "__main__":
    sys.exit(main())
