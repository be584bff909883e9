"""Shared fixtures: where real data lives, hypothesis profiles, small encoded scenes."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path
from types import ModuleType

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("ci", max_examples=40, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", max_examples=25, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("long", max_examples=1000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))

REPO = Path(__file__).resolve().parents[1]


def load_bench_script(name: str) -> ModuleType:
    """``bench/NAME.py`` as a module (once per session): tests of what a bench script itself
    does, which no package installs."""
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, REPO / "bench" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


@pytest.fixture(scope="session", autouse=True)
def private_render_cache(tmp_path_factory):
    """``spcodec eval`` caches reference renders under ``$XDG_CACHE_HOME``: the suite's go to a
    folder of its own, never into the user's cache."""
    before = os.environ.get("XDG_CACHE_HOME")
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("xdg-cache"))
    yield
    if before is None:
        os.environ.pop("XDG_CACHE_HOME", None)
    else:
        os.environ["XDG_CACHE_HOME"] = before


@pytest.fixture(scope="module")
def single_torch_thread():
    """Torch on one thread for a module of small training runs: on the 2-core machine its own
    threads only add contention (``pytestmark = pytest.mark.usefixtures(...)``)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def data_dir() -> Path:
    """The real-data folder: $SPCODEC_DATA, else the nearest ``shared/data`` above the repository
    (``../shared/data`` in CI; further up from a git worktree)."""
    if "SPCODEC_DATA" in os.environ:
        return Path(os.environ["SPCODEC_DATA"])
    for parent in REPO.parents:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    return REPO.parent / "shared" / "data"


def real_file(relative: str) -> Path:
    """Path of a real data file, or skip the test with the reason when it is absent."""
    path = data_dir() / relative
    if not path.exists():
        pytest.skip(f"real data {relative} not found under {data_dir()} (set SPCODEC_DATA)")
    return path


def write_transforms_dataset(root: Path, cloud, cameras_train, cameras_test) -> None:
    """A NeRF-style dataset (transforms_{train,test}.json + PNGs) whose images are renders of
    ``cloud`` at the given cameras."""
    import json

    import numpy as np

    from spcodec.imaging.images import write_png
    from spcodec.imaging.render import render_image

    root.mkdir(parents=True, exist_ok=True)
    for split, cams in (("train", cameras_train), ("test", cameras_test)):
        frames = []
        for i, cam in enumerate(cams):
            name = f"{split}_{i:02d}"
            write_png(root / f"{name}.png", render_image(cloud, cam, device="cpu"))
            c2w = np.linalg.inv(cam.world_to_camera) @ np.diag([1.0, -1.0, -1.0, 1.0])
            frames.append({"file_path": name, "transform_matrix": c2w.tolist()})
        doc = {"camera_angle_x": cams[0].fov_x, "frames": frames}
        (root / f"transforms_{split}.json").write_text(json.dumps(doc))


def real_plys() -> list[Path]:
    """Every PLY under the data folder (empty when the folder is absent)."""
    root = data_dir()
    return sorted(root.rglob("*.ply")) if root.is_dir() else []


@pytest.fixture(scope="session")
def small_scene():
    """A small valid encoded scene: 4 clusters, 2 patch layers, SH degree 3, metadata."""
    from spcodec.synthetic import random_encoded_scene
    return random_encoded_scene(seed=7, clusters=4, patch_layers=2, patch_size=150, sh_degree=3,
                                metadata={"generator": "tests"})


@pytest.fixture(scope="session")
def small_file(small_scene) -> bytes:
    from spcodec.writer import build_bitstream
    return build_bitstream(small_scene)
