"""The command line keeps freed memory for reuse on glibc, unless the user tuned glibc."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

PROBE = "from spcodec.allocator import keep_freed_memory; print(keep_freed_memory())"


def _probe(**env: str) -> str:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("GLIBC_TUNABLES", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_")}
    done = subprocess.run([sys.executable, "-c", PROBE], env={**clean, **env},
                          capture_output=True, text=True, check=True)
    return done.stdout.strip()


def test_on_glibc_the_thresholds_are_set():
    if platform.libc_ver()[0] != "glibc":
        pytest.skip(f"not glibc ({platform.libc_ver()[0] or 'unknown'}): nothing to set")
    assert _probe() == "True"


@pytest.mark.parametrize("name", ["GLIBC_TUNABLES", "MALLOC_TRIM_THRESHOLD_"])
def test_a_users_own_allocator_settings_win(name):
    assert _probe(**{name: "glibc.malloc.trim_threshold=0" if name == "GLIBC_TUNABLES" else "0"}) \
        == "False"


def test_the_command_line_sets_them(monkeypatch):
    from spcodec import cli

    calls = []
    monkeypatch.setattr(cli, "keep_freed_memory", lambda: calls.append(1) or True)
    assert cli.main(["conformance", "--help"]) == 0
    assert calls == []  # --help exits before any work
    assert cli.main(["info", "missing-file.spc"]) != 0
    assert calls == [1]
