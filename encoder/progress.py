"""Progress display for the command line: one line per stage, a bar for counted stages."""

from __future__ import annotations

import sys
import time

from .pipeline import Stage


class _PrintedStage(Stage):
    def __init__(self, name: str, total: int | None, index: int, enabled: bool) -> None:
        self.name, self.index, self.enabled = name, index, enabled
        self.start = time.perf_counter()
        self.bar = None
        if enabled:
            if total and sys.stderr.isatty():
                from tqdm import tqdm
                self.bar = tqdm(total=total, desc=f"[{index}] {name}", unit="cluster",
                                leave=False, file=sys.stderr)
            else:
                print(f"[{index}] {name} ...", file=sys.stderr, flush=True)

    def update(self, count: int = 1) -> None:
        if self.bar is not None:
            self.bar.update(count)

    def done(self, summary: str = "") -> None:
        if self.bar is not None:
            self.bar.close()
        if self.enabled:
            elapsed = time.perf_counter() - self.start
            print(f"[{self.index}] {self.name}: {summary} ({elapsed:.1f} s)", file=sys.stderr,
                  flush=True)


class StageReporter:
    """Creates numbered stage reporters; pass ``reporter.stage`` as the pipeline's progress."""

    def __init__(self, enabled: bool = True) -> None:
        self.enabled, self.count = enabled, 0

    def stage(self, name: str, total: int | None) -> Stage:
        self.count += 1
        return _PrintedStage(name, total, self.count, self.enabled)


def print_summary(stats: dict) -> None:
    """The human summary of an encode: counts, bytes per section, ratios, sketch errors."""
    n, size = stats["gaussians"], stats["bytes"]
    sk = stats["sketch"]
    print(f"{stats.get('output', 'output')}: {size:,} bytes for {n:,} Gaussians "
          f"({8 * size / n:.1f} bits per Gaussian)")
    if "input_bytes" in stats:
        print(f"  ratio vs input PLY: {stats['input_bytes'] / size:.1f}x "
              f"({stats['input_bytes']:,} bytes)")
    print(f"  sketch: {stats['sketch_gaussians']:,} Gaussians in "
          f"{sk.get('clusters_encoded', 0)} clusters; patch: {stats['patch_gaussians']:,} "
          f"Gaussians in {stats['patch_layers']} layers")
    for name, length in stats["sections"].items():
        if length:
            print(f"  {name:<20} {length:>12,} bytes")
    err = stats.get("sketch_error")
    if err:
        print("  decoded sketch vs original (mean / p95):")
        labels = {"position_rel_diameter": ("position, % of diameter", 100.0),
                  "log_scale_abs": ("log scale", 1.0), "rotation_deg": ("rotation, degrees", 1.0),
                  "opacity_abs": ("opacity", 1.0), "color_dc_abs": ("colour (RGB)", 1.0)}
        for key, (label, factor) in labels.items():
            v = err[key]
            print(f"    {label:<24} {v['mean'] * factor:.4g} / {v['p95'] * factor:.4g}")
    total = sum(stats["seconds"].values())
    print("  time: " + ", ".join(f"{k} {v:.1f} s" for k, v in stats["seconds"].items())
          + f" (total {total:.1f} s)")
