"""Progress display for the command line: one line per stage, a bar for counted stages.

On a terminal a counted stage shows a tqdm bar (rate, ETA and the figures the stage reports, such
as a training step's loss and PSNR); elsewhere (a log file, CI) it prints a line every 5 % with
the same figures, so a long run is never silent. Everything goes to standard error, never to
standard output (where ``--json`` documents go).

With ``delay`` (``spcodec eval`` uses 2 s) a stage shows nothing until it has run that long: a
quick command prints only its result, a long stage still gets its bar or lines and its summary.
"""

from __future__ import annotations

import functools
import sys
import time
from typing import TextIO

from .stages import Stage

_LOG_STEPS = 20
"""Lines printed over a counted stage when stderr is not a terminal."""


class _PrintedStage(Stage):
    def __init__(self, name: str, total: int | None, index: int, enabled: bool,
                 delay: float = 0.0) -> None:
        self.name, self.index, self.enabled, self.total = name, index, enabled, total
        self.delay = delay
        self.start = time.perf_counter()
        self.count = 0
        self.earlier = 0
        """Steps an earlier run did (resumed): counted as done, not in this run's rate."""
        self.bar = None
        self.shown = False
        """Whether anything of this stage was printed yet (its first line waits for ``delay``)."""
        if enabled:
            if total and sys.stderr.isatty():
                from tqdm import tqdm
                self.bar = tqdm(total=total, desc=f"[{index}] {name}", leave=False,
                                file=sys.stderr, dynamic_ncols=True, delay=delay)
                self.shown = not delay
            elif not delay:
                self._announce()

    def _announce(self) -> None:
        """The stage's first line (once), unless a bar stands for it."""
        if not self.shown:
            self.shown = True
            if self.bar is None:
                print(f"[{self.index}] {self.name} ...", file=sys.stderr, flush=True)

    def _due(self) -> bool:
        """Whether the stage has run long enough to be shown."""
        return self.shown or time.perf_counter() - self.start >= self.delay

    def resumed(self, count: int) -> None:
        self.count = self.earlier = count
        if self.bar is not None:
            self.bar.n = self.bar.last_print_n = self.bar.initial = count
            self.bar.refresh()
        if self.enabled:
            self._say(f"[{self.index}] {self.name}: resuming at step {count}/{self.total}")

    def update(self, count: int = 1, **figures: float) -> None:
        self.count += count
        eta_all = figures.pop("eta_all", None)
        shown = {k: f"{v:.4g}" for k, v in figures.items()}
        if eta_all is not None:
            shown["ETA all"] = _clock(eta_all)
        if self.bar is not None:
            if shown:
                self.bar.set_postfix(shown, refresh=False)
            self.bar.update(count)
        elif self.enabled and self.total and self._log_due(count) and self._due():
            self._announce()
            elapsed = time.perf_counter() - self.start
            rate = (self.count - self.earlier) / elapsed if elapsed > 0 else 0.0
            eta = (self.total - self.count) / rate if rate > 0 else float("nan")
            extra = "".join(f", {k} {v}" for k, v in shown.items() if k != "ETA all")
            total = f", all stages {shown['ETA all']}" if "ETA all" in shown else ""
            print(f"[{self.index}] {self.name} {self.count}/{self.total}{extra}, "
                  f"{rate:.2f} it/s, ETA {_clock(eta)}{total}", file=sys.stderr, flush=True)

    def note(self, message: str) -> None:
        if self.enabled:
            self._announce()
            self._say(f"[{self.index}] {message}")

    def _say(self, line: str) -> None:
        if self.bar is not None:
            self.bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr, flush=True)

    def _log_due(self, count: int) -> bool:
        step = max(1, self.total // _LOG_STEPS)
        return self.count // step != (self.count - count) // step or self.count == self.total

    def abandon(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        elif self.enabled and self.shown and self.total and \
                self.count % max(1, self.total // _LOG_STEPS):
            print(file=sys.stderr, flush=True)

    def done(self, summary: str = "") -> None:
        if self.bar is not None:
            self.bar.close()
        if self.enabled and self._due():
            elapsed = time.perf_counter() - self.start
            print(f"[{self.index}] {self.name}: {summary} ({elapsed:.1f} s)", file=sys.stderr,
                  flush=True)


def _clock(seconds: float) -> str:
    if seconds != seconds:  # NaN
        return "?"
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class StageReporter:
    """Creates numbered stage reporters; pass ``reporter.stage`` as the pipeline's progress.

    ``delay``: seconds a stage runs before anything of it is shown (0: at once)."""

    def __init__(self, enabled: bool = True, delay: float = 0.0) -> None:
        self.enabled, self.count, self.delay = enabled, 0, delay
        self.current: _PrintedStage | None = None

    def stage(self, name: str, total: int | None) -> Stage:
        self.count += 1
        self.current = _PrintedStage(name, total, self.count, self.enabled, self.delay)
        return self.current

    def interrupt(self) -> None:
        """End the stage in progress without a summary, so whatever is printed next starts on
        a line of its own (not glued to a progress bar)."""
        if self.current is not None:
            self.current.abandon()
def precision_line(options: dict) -> str:
    """The precision search's choice in a few words: each codebook's entry dimension x entries,
    and the positions' grid when it was searched too."""
    codebooks = ", ".join(f"{name.lower()} {o['entry_dim']}x{o['entries']}"
                          for name, o in options.items() if "entry_dim" in o)
    grid = options.get("POSITION")
    return f"codebooks (entry dimension x entries): {codebooks}" + (
        f"; positions at {grid['bits']} bits" if grid else "")


def print_summary(stats: dict, stream: TextIO | None = None) -> None:
    """The human summary of an encode: counts, bytes per section, ratios, sketch errors (to
    ``stream``, standard output by default). Bits per Gaussian count the Gaussians the file
    stores, not those pruning dropped."""
    print_ = functools.partial(print, file=stream or sys.stdout)
    n, size = stats["gaussians"], stats["bytes"]
    stored = stats["sketch_gaussians"] + stats["patch_gaussians"]
    sk = stats["sketch"]
    pruned = f"; {n:,} in the input" if stored != n else ""
    print_(f"{stats.get('output', 'output')}: {size:,} bytes for {stored:,} Gaussians "
           f"({8 * size / max(stored, 1):.1f} bits per Gaussian{pruned})")
    if "input_bytes" in stats:
        print_(f"  ratio vs input PLY: {stats['input_bytes'] / size:.1f}x "
              f"({stats['input_bytes']:,} bytes)")
    print_(f"  sketch: {stats['sketch_gaussians']:,} Gaussians in "
          f"{sk.get('clusters_encoded', 0)} clusters; patch: {stats['patch_gaussians']:,} "
          f"Gaussians in {stats['patch_layers']} layers")
    for name, length in stats["sections"].items():
        if length:
            print_(f"  {name:<20} {length:>12,} bytes")
    preview = stats.get("preview")
    if preview:
        print_(f"  preview: {preview['gaussians']:,} Gaussians in {preview['bytes']:,} bytes, "
               f"shown until layer {preview['takeover_layer']} arrives")
    err = stats.get("sketch_error")
    if err:
        print_("  decoded sketch vs original (mean / p95):")
        labels = {"position_rel_diameter": ("position, % of diameter", 100.0),
                  "log_scale_abs": ("log scale", 1.0), "rotation_deg": ("rotation, degrees", 1.0),
                  "opacity_abs": ("opacity", 1.0), "color_dc_abs": ("colour (RGB)", 1.0)}
        for key, (label, factor) in labels.items():
            v = err[key]
            print_(f"    {label:<24} {v['mean'] * factor:.4g} / {v['p95'] * factor:.4g}")
    rate = stats.get("rate")
    if rate:
        actual = stats["bytes"]
        if rate.get("preset_point"):  # no target: the bytes the search predicts for the shapes
            spent = rate["precision"]["preset_bytes"]
            what = (f"its codebooks' {spent:,} bytes (as the search predicts them) spent by the "
                    "search" if "options" in rate["precision"] else
                    "nothing predicted to beat its own codebooks")
            print_(f"  the preset's point: {what}")
        else:
            print_(f"  target {rate['target_bytes']:,} bytes: predicted "
                   f"{rate['predicted_bytes']:,}, actual {actual:,} "
                   f"({100 * (actual / rate['target_bytes'] - 1):+.1f} %)"
                   + (", trimmed to fit" if rate.get("trimmed") else ""))
        if rate.get("note"):
            print_(f"  note: {rate['note']}")
        options = rate.get("precision", {}).get("options")
        if options:  # the precision search's choice (encoder/allocation.py)
            count = "every Gaussian kept" if stored >= n else f"{stored:,} of {n:,} Gaussians kept"
            print_(f"  {count}; " + precision_line(options)
                   + (", the sketch dropped for precision"
                   if stats.get("sketch", {}).get("dropped_for_precision") else ""))
    aim = stats.get("quality_target")
    if aim and "precision" in aim:
        chosen = aim["precision"]
        print_(f"  target {aim['target_psnr']:g} dB close up: point {chosen['chosen_point'] + 1} of "
               f"{chosen['curve_points']} of the precision curve reaches {chosen['psnr']:.2f} dB "
               f"with every Gaussian kept; {precision_line(chosen['options'])}")
    if aim and "count_without_retraining" in aim:
        line = (f"  target {aim['target_psnr']:g} dB close up: {aim['count_without_retraining']:,} "
                f"patch Gaussians reach {aim['psnr_without_retraining']:.2f} dB without "
                "retraining")
        if "count_retrained" in aim:
            line += (f"; retrained, {aim['count_retrained']:,} reach "
                     f"{aim['psnr_retrained']:.2f} dB before the finish")
            if not aim["reached"]:
                line += " (short of the target even with all of them: the best this encode makes)"
        print_(line)
    retrain = stats.get("retrain")
    if retrain:
        print_(f"  retrain ({retrain['prune']} pruning) on the training views: "
              f"{retrain['psnr_before']:.2f} dB before, {retrain['psnr_retrained']:.2f} dB "
              f"retrained"
              + (f" ({retrain['psnr_snapped']:.2f} dB through its codebooks)"
                 if "psnr_snapped" in retrain else "")
              + f", {retrain['psnr_quantized']:.2f} dB quantized"
              + (f", {retrain['psnr_finished']:.2f} dB after the finish"
                 if "psnr_finished" in retrain else ""))
    quality = stats.get("quality")
    if quality:
        print_(f"  quality: PSNR {quality['psnr']:.2f} dB, SSIM {quality['ssim']:.4f} against "
              f"{quality['against']} ({quality['views']} views of {quality['width']}x"
              f"{quality['height']}; `spcodec eval` reports the same)")
        for close in quality.get("closeups", []):
            print_(f"    closer, at {close['distance']:g} of the distance: PSNR {close['psnr']:.2f} "
                  f"dB, SSIM {close['ssim']:.4f} ({close['width']}x{close['height']})")
    skipped = stats.get("evaluation")
    if skipped and skipped.get("skipped"):
        command = skipped.get("command") or "spcodec eval OUT.spc --reference IN.ply"
        print_(f"  quality: not evaluated (--no-eval); `{command}` measures it")
    total = sum(stats["seconds"].values())
    print_("  time: " + ", ".join(f"{k} {v:.1f} s" for k, v in stats["seconds"].items())
          + f" (total {total:.1f} s)")
