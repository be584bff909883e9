"""Dataset loaders on small generated datasets in every format, on broken ones, and on real data."""

from __future__ import annotations

import json
import math
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from spcodec.errors import UsageError
from spcodec.imaging.datasets import (
    DatasetError,
    Distortion,
    MissingImageWarning,
    Undistorter,
    detect_format,
    load_dataset,
)
from spcodec.imaging.datasets.colmap import pinhole_and_distortion
from spcodec.imaging.datasets.colmap_model import (
    quaternion_to_matrix,
    read_cameras_binary,
    read_model,
    read_points_binary,
)
from spcodec.imaging.datasets.llff import load_llff

from conftest import data_dir

DATA = data_dir()

# A camera rotated +90 degrees about the world y axis, centred at C = (1, 2, 3):
# R = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]] (world-to-camera), t = -R C = (-3, -2, 1).
# The world point X = (-1, 1.75, 3.5) has camera coordinates R X + t = (0.5, -0.25, 2), so it
# lands at (cx + fx * 0.25, cy - fy * 0.125). These numbers are worked out by hand on purpose.
QVEC = (math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)
TVEC = (-3.0, -2.0, 1.0)
CENTRE = np.array([1.0, 2.0, 3.0])
POINT = np.array([[-1.0, 1.75, 3.5]])
W, H = 64, 48
FX, FY, CX, CY = 50.0, 40.0, 31.0, 25.0


def _expected_pixel(fx: float = FX, fy: float = FY, cx: float = CX, cy: float = CY):
    return np.array([cx + fx * 0.25, cy - fy * 0.125])


def _write_png(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)


def _pattern(width: int = W, height: int = H, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


def _assert_one_line_dataset_error(excinfo: pytest.ExceptionInfo, *needles: str) -> None:
    err = excinfo.value
    assert isinstance(err, DatasetError) and err.code == "dataset-invalid"
    text = str(err)
    assert "\n" not in text and text.endswith("[dataset-invalid]")
    for needle in needles:
        assert needle in text, text


# ------------------------------------------------------------------------------ COLMAP writers
# Written straight from the documented layouts, independently of the reader under test.
_MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4,
              "FULL_OPENCV": 6}


def _write_colmap_binary(folder: Path, cameras, images, points) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    data = struct.pack("<Q", len(cameras))
    for cam_id, model, width, height, params in cameras:
        data += struct.pack("<iiQQ", cam_id, _MODEL_IDS.get(model, model), width, height)
        data += struct.pack(f"<{len(params)}d", *params)
    (folder / "cameras.bin").write_bytes(data)
    data = struct.pack("<Q", len(images))
    for image_id, qvec, tvec, cam_id, name, obs in images:
        data += struct.pack("<i7di", image_id, *qvec, *tvec, cam_id)
        data += name.encode() + b"\x00" + struct.pack("<Q", len(obs))
        for x, y, pid in obs:
            data += struct.pack("<ddq", x, y, pid)
    (folder / "images.bin").write_bytes(data)
    data = struct.pack("<Q", len(points))
    for pid, xyz, rgb, err, track in points:
        data += struct.pack("<Q3d3BdQ", pid, *xyz, *rgb, err, len(track))
        for image_id, index in track:
            data += struct.pack("<ii", image_id, index)
    (folder / "points3D.bin").write_bytes(data)


def _write_colmap_text(folder: Path, cameras, images, points) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, ..."]
    lines += [f"{i} {m} {w} {h} " + " ".join(repr(p) for p in params)
              for i, m, w, h, params in cameras]
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:", f"# Number of images: {len(images)}"]
    for image_id, qvec, tvec, cam_id, name, obs in images:
        lines.append(f"{image_id} " + " ".join(repr(v) for v in (*qvec, *tvec)) +
                     f" {cam_id} {name}")
        lines.append(" ".join(f"{x!r} {y!r} {pid}" for x, y, pid in obs))  # may be empty
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    lines = ["# 3D point list"]
    for pid, xyz, rgb, err, track in points:
        lines.append(f"{pid} {xyz[0]!r} {xyz[1]!r} {xyz[2]!r} {rgb[0]} {rgb[1]} {rgb[2]} {err!r} "
                     + " ".join(f"{a} {b}" for a, b in track))
    (folder / "points3D.txt").write_text("\n".join(lines) + "\n")


def _colmap_scene(root: Path, binary: bool, model: str = "PINHOLE", params=None,
                  count: int = 10, missing: tuple[str, ...] = ()) -> Path:
    params = params or (FX, FY, CX, CY)
    cameras = [(1, model, W, H, params)]
    images = []
    for i in range(count):
        name = f"frame_{i:02d}.png"
        obs = [(10.5, 20.25, 7), (3.0, 4.0, -1)] if i % 2 == 0 else []
        images.append((i + 1, QVEC, TVEC, 1, name, obs))
        if name not in missing:
            _write_png(root / "images" / name, _pattern(seed=i))
    points = [(7, tuple(float(v) for v in POINT[0]), (255, 128, 0), 0.5, [(1, 0), (3, 0)])]
    writer = _write_colmap_binary if binary else _write_colmap_text
    writer(root / "sparse" / "0", cameras, images, points)
    return root


# ------------------------------------------------------------------------------------ COLMAP
@pytest.mark.parametrize("binary", [True, False], ids=["binary", "text"])
def test_colmap_camera_projects_the_known_point(tmp_path: Path, binary: bool) -> None:
    root = _colmap_scene(tmp_path / "scene", binary)
    assert detect_format(root) == "colmap"
    ds = load_dataset(root)
    assert ds.format == "colmap" and len(ds.views) == 10
    for view in ds.views:
        cam = view.camera
        assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (W, H, FX, FY, CX, CY)
        np.testing.assert_allclose(cam.position, CENTRE, atol=1e-12)
        uv, depth = cam.project(POINT)
        np.testing.assert_allclose(uv[0], _expected_pixel(), atol=1e-9)
        assert depth[0] == pytest.approx(2.0)
    np.testing.assert_allclose(ds.points, POINT)
    np.testing.assert_array_equal(ds.point_colors, [[255, 128, 0]])
    image = ds.views[3].load_image()
    assert image.shape == (H, W, 3) and image.dtype == np.float32
    np.testing.assert_allclose(image, _pattern(seed=int(ds.views[3].name[-2:])) / 255.0, atol=1e-6)


def test_quaternion_convention_matches_axis_angle() -> None:
    """COLMAP quaternions are Hamilton (w, x, y, z): compare with Rodrigues' formula."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(-np.pi, np.pi)
        q = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        expected = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k
        np.testing.assert_allclose(quaternion_to_matrix(3.0 * q), expected, atol=1e-12)
    # 90 degrees about z turns x into y.
    np.testing.assert_allclose(quaternion_to_matrix([math.cos(math.pi / 4), 0, 0,
                                                     math.sin(math.pi / 4)]) @ [1, 0, 0],
                               [0, 1, 0], atol=1e-12)


def test_colmap_text_and_binary_models_read_the_same(tmp_path: Path) -> None:
    text = read_model(_colmap_scene(tmp_path / "t", False) / "sparse" / "0")
    binary = read_model(_colmap_scene(tmp_path / "b", True) / "sparse" / "0")
    assert text.cameras == binary.cameras
    for image_id, image in binary.images.items():
        other = text.images[image_id]
        assert (image.name, image.camera_id) == (other.name, other.camera_id)
        np.testing.assert_array_equal(image.qvec, other.qvec)
        np.testing.assert_array_equal(image.xys, other.xys)
        np.testing.assert_array_equal(image.point3d_ids, other.point3d_ids)
    assert binary.images[1].point3d_ids.tolist() == [7, -1]
    assert binary.images[2].xys.shape == (0, 2)  # the empty 2D-point line of a text model
    np.testing.assert_array_equal(text.points.xyz, binary.points.xyz)


def test_colmap_hold_out_split_is_every_eighth_by_name(tmp_path: Path) -> None:
    ds = load_dataset(_colmap_scene(tmp_path / "s", True, count=17))
    assert [v.name for v in ds.test] == ["frame_00", "frame_08", "frame_16"]
    assert len(ds.train) == 14 and not {v.name for v in ds.train} & {v.name for v in ds.test}
    ds4 = load_dataset(tmp_path / "s", test_every=4)
    assert [v.name for v in ds4.test] == ["frame_00", "frame_04", "frame_08", "frame_12",
                                          "frame_16"]


def test_colmap_missing_images_are_skipped_with_a_warning(tmp_path: Path) -> None:
    root = _colmap_scene(tmp_path / "s", True, missing=("frame_03.png", "frame_04.png"))
    with pytest.warns(MissingImageWarning, match=r"skipped 2 of 10 .*frame_03\.png"):
        ds = load_dataset(root)
    assert len(ds.views) == 8 and "frame_03" not in {v.name for v in ds.views}


@pytest.mark.parametrize("model,params,distortion", [
    ("SIMPLE_PINHOLE", (FX, CX, CY), Distortion()),
    ("SIMPLE_RADIAL", (FX, CX, CY, 0.05), Distortion(k1=0.05)),
    ("RADIAL", (FX, CX, CY, 0.05, -0.01), Distortion(k1=0.05, k2=-0.01)),
    ("OPENCV", (FX, FY, CX, CY, 0.05, -0.01, 0.001, -0.002),
     Distortion(k1=0.05, k2=-0.01, p1=0.001, p2=-0.002)),
])
def test_colmap_camera_models(tmp_path: Path, model: str, params, distortion: Distortion) -> None:
    ds = load_dataset(_colmap_scene(tmp_path / "s", True, model=model, params=params))
    view = ds.views[0]
    fy = FY if model in ("PINHOLE", "OPENCV") else FX
    assert (view.camera.fx, view.camera.fy, view.camera.cx, view.camera.cy) == (FX, fy, CX, CY)
    np.testing.assert_allclose(view.camera.project(POINT)[0][0], _expected_pixel(fy=fy),
                               atol=1e-9)
    if distortion.is_identity:
        assert view.undistorter is None and view.valid_mask() is None
    else:
        assert view.undistorter.distortion == distortion
        assert view.load_image().shape == (H, W, 3)


def test_colmap_downscale_scales_camera_and_image(tmp_path: Path) -> None:
    root = _colmap_scene(tmp_path / "s", True)
    ds = load_dataset(root, downscale=2)
    view = ds.views[0]
    cam = view.camera
    assert (cam.width, cam.height) == (W // 2, H // 2)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (FX / 2, FY / 2, CX / 2, CY / 2)
    np.testing.assert_allclose(cam.project(POINT)[0][0], _expected_pixel() / 2, atol=1e-9)
    full = load_dataset(root).views[0].load_image()
    np.testing.assert_allclose(view.load_image()[3, 5], full[6:8, 10:12].mean(axis=(0, 1)),
                               atol=1e-6)
    # 64x48 by 5: whole 5x5 blocks only (12x9) and intrinsics divided exactly by 5.
    cam5 = load_dataset(root, downscale=5).views[0].camera
    assert (cam5.width, cam5.height, cam5.cx) == (12, 9, CX / 5)
    assert load_dataset(root, downscale=5).views[0].load_image().shape == (9, 12, 3)


# ------------------------------------------------------------------------------ transforms.json
def _c2w_gl(position, forward, up) -> list[list[float]]:
    """Camera-to-world in the OpenGL/Blender convention from a position and viewing direction."""
    forward = np.asarray(forward, float) / np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, true_up, -forward, position
    return m.tolist()


def _rgba(width: int, height: int, seed: int) -> np.ndarray:
    rgba = _pattern(width, height, seed=seed)
    alpha = np.full((height, width, 1), 255, np.uint8)
    alpha[0, :] = 0  # first row fully transparent
    alpha[1, :] = 128  # second row half transparent
    return np.concatenate([rgba, alpha], axis=2)


def _transforms_scene(root: Path, width: int = 32, height: int = 24) -> Path:
    """NeRF-synthetic style: train + test JSON, extension-less paths, RGBA, one missing frame."""
    angle = 2 * math.atan(width / 2 / 40.0)  # fx = 40
    for split, count in (("train", 5), ("test", 3)):
        frames = []
        for i in range(count):
            pose = _c2w_gl([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]) if i == 0 else \
                _c2w_gl([4.0 * math.cos(i), 4.0 * math.sin(i), 1.0],
                        [-math.cos(i), -math.sin(i), -0.25], [0.0, 0.0, 1.0])
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": pose})
            if not (split == "test" and i == 2):  # test/r_2 is missing on purpose
                _write_png(root / split / f"r_{i}.png", _rgba(width, height, seed=10 * i))
        (root / f"transforms_{split}.json").write_text(
            json.dumps({"camera_angle_x": angle, "frames": frames}))
    return root


def test_transforms_cameras_convert_opengl_to_opencv(tmp_path: Path) -> None:
    root = _transforms_scene(tmp_path / "lego")
    with pytest.warns(MissingImageWarning, match=r"skipped 1 of 3 .*test/r_2"):
        ds = load_dataset(root)
    assert ds.format == "transforms" and (len(ds.train), len(ds.test)) == (5, 2)
    cam = next(v.camera for v in ds.train if v.name == "train/r_0")
    assert cam.fx == pytest.approx(40.0) and cam.fy == pytest.approx(40.0)
    assert (cam.cx, cam.cy, cam.width, cam.height) == (16.0, 12.0, 32, 24)
    # Identity OpenGL pose: the camera looks down world -z with world +y up in the image.
    points = np.array([[0.0, 0.0, -2.0], [0.5, 0.25, -2.0]])
    uv, depth = cam.project(points)
    np.testing.assert_allclose(uv, [[16.0, 12.0], [16.0 + 40 * 0.25, 12.0 - 40 * 0.125]],
                               atol=1e-9)
    np.testing.assert_allclose(depth, [2.0, 2.0])
    # Orbit poses: looking at a point 4 units ahead along the viewing direction hits the centre.
    for view in ds.views:
        if view.name.endswith("r_0"):
            continue
        i = int(view.name[-1])
        forward = np.array([-math.cos(i), -math.sin(i), -0.25])
        ahead = np.array([4 * math.cos(i), 4 * math.sin(i), 1.0]) + forward
        uv, depth = view.camera.project(ahead[None])
        np.testing.assert_allclose(uv[0], [16.0, 12.0], atol=1e-9)
        assert depth[0] == pytest.approx(np.linalg.norm(forward))
        # World +z is up in these views (the pose's up vector): a point above is higher.
        uv_up, _ = view.camera.project((ahead + [0, 0, 0.1])[None])
        assert uv_up[0, 1] < 12.0


def test_transforms_rgba_is_composited_on_the_background(tmp_path: Path) -> None:
    root = _transforms_scene(tmp_path / "lego")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MissingImageWarning)
        white = load_dataset(root)
        black = load_dataset(root, background="black")
        grey = load_dataset(root, background=(0.2, 0.4, 0.6))
    np.testing.assert_array_equal(white.background, [1, 1, 1])  # RGBA images: white by default
    rgb = _rgba(32, 24, seed=0)[:, :, :3] / 255.0
    view = next(v for v in white.train if v.name == "train/r_0")
    img = view.load_image()
    np.testing.assert_allclose(img[0], 1.0)
    np.testing.assert_allclose(img[1], rgb[1] * 128 / 255 + (1 - 128 / 255), atol=1e-6)
    np.testing.assert_allclose(img[2:], rgb[2:], atol=1e-6)
    np.testing.assert_allclose(next(v for v in black.train if v.name == "train/r_0")
                               .load_image()[0], 0.0)
    np.testing.assert_allclose(next(v for v in grey.train if v.name == "train/r_0")
                               .load_image()[0], np.tile([0.2, 0.4, 0.6], (32, 1)), atol=1e-6)
    with pytest.raises(UsageError):
        load_dataset(root, background="purple")


def test_single_transforms_json_with_intrinsics_overrides_and_split(tmp_path: Path) -> None:
    root = tmp_path / "ngp"
    frames = []
    for i in range(17):
        frame = {"file_path": f"images/{i:04d}.jpg",
                 "transform_matrix": _c2w_gl([0, 0, 0], [0, 0, -1], [0, 1, 0])}
        if i == 5:
            frame.update({"fl_x": 60.0, "cx": 10.0})  # a per-frame override
        frames.append(frame)
        (root / "images").mkdir(parents=True, exist_ok=True)
        Image.fromarray(_pattern(40, 30, seed=i)).save(root / "images" / f"{i:04d}.jpg")
    (root / "transforms.json").write_text(json.dumps(
        {"fl_x": 50.0, "fl_y": 45.0, "w": 40, "h": 30, "frames": frames}))
    ds = load_dataset(root)
    assert np.array_equal(ds.background, [0, 0, 0])  # JPEGs have no alpha: black
    assert [v.name for v in ds.test] == ["images/0000", "images/0008", "images/0016"]
    assert len(ds.train) == 14
    cams = {v.name: v.camera for v in ds.views}
    c = cams["images/0001"]
    assert (c.fx, c.fy, c.cx, c.cy) == (50.0, 45.0, 20.0, 15.0)
    c = cams["images/0005"]
    assert (c.fx, c.fy, c.cx, c.cy) == (60.0, 45.0, 10.0, 15.0)
    # The same file given directly
    assert len(load_dataset(root / "transforms.json").views) == 17


def test_transforms_distortion_is_undistorted(tmp_path: Path) -> None:
    root = tmp_path / "fox"
    _write_png(root / "images" / "a.png", _pattern(40, 30))
    (root / "transforms.json").write_text(json.dumps({
        "fl_x": 30.0, "fl_y": 30.0, "k1": 0.1, "k2": -0.02, "p1": 0.001, "p2": 0.002,
        "frames": [{"file_path": "images/a.png",
                    "transform_matrix": _c2w_gl([0, 0, 0], [0, 0, -1], [0, 1, 0])}]}))
    view = load_dataset(root).views[0]
    assert view.undistorter.distortion == Distortion(k1=0.1, k2=-0.02, p1=0.001, p2=0.002)
    assert (view.camera.fx, view.camera.cx) == (30.0, 20.0)  # same size and intrinsics kept
    mask = view.valid_mask()
    assert mask is not None and 0.5 < mask.mean() < 1.0 and mask[15, 20]
    assert view.load_image().shape == (30, 40, 3)


# ------------------------------------------------------------------------------------------ LLFF
def _llff_scene(root: Path, count: int = 9) -> Path:
    """Cameras at z = 5 (+ x offsets) looking at -z, image right = +x, image down = -y."""
    rows = []
    for i in range(count):
        down, right, back = [0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]
        centre = [0.5 * i, 0.0, 5.0]
        hwf = [48.0, 64.0, 50.0]  # full resolution 64x48, f = 50
        pose = np.array([down, right, back, centre, hwf]).T  # 3x5, columns as LLFF stores them
        rows.append(np.concatenate([pose.reshape(-1), [1.0, 10.0]]))
        _write_png(root / "images_2" / f"IMG_{i:03d}.png", _pattern(32, 24, seed=i))
    np.save(root / "poses_bounds.npy", np.array(rows))
    return root


def test_llff_poses_follow_the_down_right_back_convention(tmp_path: Path) -> None:
    root = _llff_scene(tmp_path / "fern")
    assert detect_format(root) == "llff"
    ds = load_dataset(root)
    assert ds.format == "llff" and (len(ds.train), len(ds.test)) == (7, 2)
    assert [v.name for v in ds.test] == ["IMG_000", "IMG_008"]
    for view in ds.views:
        cam = view.camera
        i = int(view.name[-3:])
        assert (cam.width, cam.height, cam.fx, cam.cx, cam.cy) == (32, 24, 25.0, 16.0, 12.0)
        target = np.array([[0.5 * i, 0.0, 0.0], [0.5 * i + 1.0, 0.0, 0.0], [0.5 * i, 1.0, 0.0]])
        uv, depth = cam.project(target)
        np.testing.assert_allclose(depth, 5.0)
        np.testing.assert_allclose(uv, [[16.0, 12.0], [16.0 + 25.0 / 5, 12.0],
                                        [16.0, 12.0 - 25.0 / 5]], atol=1e-9)
    assert ds.views[0].load_image().shape == (24, 32, 3)
    assert load_dataset(root, downscale=2).views[0].load_image().shape == (12, 16, 3)


# ---------------------------------------------------------------------------------- bad datasets
def test_missing_and_empty_dataset_folders(tmp_path: Path) -> None:
    with pytest.raises(DatasetError) as info:
        load_dataset(tmp_path / "nowhere")
    _assert_one_line_dataset_error(info, "does not exist")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError) as info:
        load_dataset(tmp_path / "empty")
    _assert_one_line_dataset_error(info, "is empty")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "notes.txt").write_text("hello")
    with pytest.raises(DatasetError) as info:
        load_dataset(tmp_path / "junk")
    _assert_one_line_dataset_error(info, "no dataset found")


def test_datasets_without_images(tmp_path: Path) -> None:
    root = _colmap_scene(tmp_path / "c", True, missing=tuple(f"frame_{i:02d}.png"
                                                             for i in range(10)))
    (root / "images").mkdir()  # present but empty
    with pytest.warns(MissingImageWarning), pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "no usable views")
    (root / "images").rmdir()
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "no images/ folder")
    nerf = _transforms_scene(tmp_path / "n")
    for png in nerf.rglob("*.png"):
        png.unlink()
    with pytest.warns(MissingImageWarning), pytest.raises(DatasetError) as info:
        load_dataset(nerf)
    _assert_one_line_dataset_error(info, "no usable views")
    llff = _llff_scene(tmp_path / "l")
    for png in (llff / "images_2").glob("*.png"):
        png.unlink()
    with pytest.raises(DatasetError) as info:
        load_dataset(llff)
    _assert_one_line_dataset_error(info, "9 poses", "images_2/ has 0")


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "text"])
def test_unsupported_camera_model(tmp_path: Path, binary: bool) -> None:
    root = _colmap_scene(tmp_path / "s", binary, model="FULL_OPENCV", params=(FX,) * 12)
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "FULL_OPENCV", "not supported")


def test_unknown_binary_camera_model_id(tmp_path: Path) -> None:
    root = _colmap_scene(tmp_path / "s", True)
    data = bytearray((root / "sparse" / "0" / "cameras.bin").read_bytes())
    data[12:16] = struct.pack("<i", 99)  # the model id of the first camera
    (root / "sparse" / "0" / "cameras.bin").write_bytes(bytes(data))
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "unknown COLMAP model id 99")


def test_truncated_and_garbled_colmap_files(tmp_path: Path) -> None:
    root = _colmap_scene(tmp_path / "s", True)
    images = root / "sparse" / "0" / "images.bin"
    images.write_bytes(images.read_bytes()[:-5])
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "truncated", "images.bin")
    text = _colmap_scene(tmp_path / "t", False)
    (text / "sparse" / "0" / "images.txt").write_text("1 0.5 zero 0 0 0 0 0 1 a.png\n\n")
    with pytest.raises(DatasetError) as info:
        load_dataset(text)
    _assert_one_line_dataset_error(info, "images.txt:1", "cannot parse")


def test_colmap_model_without_images_file(tmp_path: Path) -> None:
    root = _colmap_scene(tmp_path / "s", True)
    (root / "sparse" / "0" / "images.bin").unlink()
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "no images.bin or images.txt")


@pytest.mark.parametrize("matrix,needle", [
    ("not a matrix", "transform_matrix"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "4x4"),
    ([[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]], "not orthonormal"),
    ([[1, 0, 0, float("nan")], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "finite"),
])
def test_unparsable_transforms_poses(tmp_path: Path, matrix, needle: str) -> None:
    root = tmp_path / "n"
    _write_png(root / "a.png", _pattern(8, 8))
    (root / "transforms.json").write_text(json.dumps(
        {"camera_angle_x": 0.7, "frames": [{"file_path": "a.png", "transform_matrix": matrix}]}))
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "frame 0", needle)


def test_invalid_transforms_json_and_missing_focal(tmp_path: Path) -> None:
    root = tmp_path / "n"
    root.mkdir()
    (root / "transforms.json").write_text("{ frames: [")
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "not valid JSON")
    _write_png(root / "a.png", _pattern(8, 8))
    (root / "transforms.json").write_text(json.dumps(
        {"frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]}))
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "no focal length")


def test_unparsable_llff_poses(tmp_path: Path) -> None:
    root = _llff_scene(tmp_path / "l")
    np.save(root / "poses_bounds.npy", np.zeros((9, 10)))
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "(N, 17)")
    (root / "poses_bounds.npy").write_bytes(b"garbage")
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "not a readable .npy")
    np.save(root / "poses_bounds.npy", np.zeros((9, 17)))
    with pytest.raises(DatasetError) as info:
        load_dataset(root)
    _assert_one_line_dataset_error(info, "not a rotation")


def test_bad_arguments_are_usage_errors(tmp_path: Path) -> None:
    root = _colmap_scene(tmp_path / "s", True)
    for bad in (0, -2, 1.5, True):
        with pytest.raises(UsageError):
            load_dataset(root, downscale=bad)
    with pytest.raises(UsageError):
        load_dataset(root, test_every=1)


# ---------------------------------------------------------------------------------- undistortion
def _stripes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A smooth analytic pattern of normalized camera coordinates (period ~ 10 pixels here)."""
    return np.stack([0.5 + 0.4 * np.sin(18 * x), 0.5 + 0.4 * np.cos(15 * y),
                     0.5 + 0.3 * np.sin(11 * (x + y))], axis=-1).astype(np.float32)


@pytest.mark.parametrize("distortion", [
    Distortion(k1=0.05),  # like beer (SIMPLE_RADIAL)
    Distortion(k1=0.0578, k2=-0.0805, p1=-0.00098, p2=0.00016),  # fox's coefficients
    Distortion(k1=-0.2, k2=0.05, p1=0.002, p2=-0.001),  # strong barrel
])
def test_undistortion_recovers_a_known_pattern(distortion: Distortion) -> None:
    width, height, f, cx, cy = 120, 90, 100.0, 59.0, 46.0
    # The captured (distorted) image: pixel (u, v) saw the ray of the ideal point undistort(u, v).
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    ideal_x, ideal_y = distortion.undistort_points((u - cx) / f, (v - cy) / f)
    captured = _stripes(ideal_x, ideal_y)
    undistorter = Undistorter(width, height, f, f, cx, cy, distortion)
    result = undistorter.undistort(captured)
    expected = _stripes((u - cx) / f, (v - cy) / f)  # what a pinhole camera sees
    valid = undistorter.valid_mask()
    interior = valid & np.pad(np.ones((height - 4, width - 4), bool), 2)
    assert valid.mean() > 0.85
    error = np.abs(result - expected)[interior]
    assert error.mean() < 0.01 and error.max() < 0.06  # bilinear resampling error only
    assert np.abs(captured - expected)[interior].mean() > 3 * error.mean()  # it did something


def test_distortion_inverse_round_trips() -> None:
    dist = Distortion(k1=0.0578, k2=-0.0805, k3=0.01, p1=-0.00098, p2=0.00016)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-0.6, 0.6, 500), rng.uniform(-0.8, 0.8, 500)
    xd, yd = dist.distort_points(x, y)
    back_x, back_y = dist.undistort_points(xd, yd)
    np.testing.assert_allclose(back_x, x, atol=1e-10)
    np.testing.assert_allclose(back_y, y, atol=1e-10)
    # The forward model: radial and tangential terms as in OpenCV/COLMAP.
    xd, yd = Distortion(k1=0.1, p1=0.01, p2=0.02).distort_points(np.array([0.5]), np.array([0.2]))
    r2 = 0.29
    assert xd[0] == pytest.approx(0.5 * (1 + 0.1 * r2) + 2 * 0.01 * 0.1 + 0.02 * (r2 + 0.5))
    assert yd[0] == pytest.approx(0.2 * (1 + 0.1 * r2) + 0.01 * (r2 + 0.08) + 2 * 0.02 * 0.1)


# ----------------------------------------------------------------------------------- real data
def _real(name: str) -> Path:
    path = DATA / name
    if not path.is_dir():
        pytest.skip(f"real dataset {path} is not present (set SPCODEC_DATA)")
    return path


@pytest.mark.slow
def test_real_lego() -> None:
    root = _real("nerf_synthetic_lego")
    with pytest.warns(MissingImageWarning, match="skipped 175 of 200"):
        ds = load_dataset(root)
    assert (len(ds.train), len(ds.test)) == (100, 25)
    np.testing.assert_array_equal(ds.background, [1, 1, 1])
    for view in ds.views:
        cam = view.camera
        assert (cam.width, cam.height) == (800, 800)
        assert cam.fx == pytest.approx(0.5 * 800 / math.tan(0.5 * 0.6911112070083618))
        uv, depth = cam.project(np.zeros((1, 3)))  # every Blender camera looks at the origin
        np.testing.assert_allclose(uv[0], [400.0, 400.0], atol=0.01)
        assert 3.5 < depth[0] < 4.5
    image = ds.test[0].load_image()
    assert image.shape == (800, 800, 3)
    assert image[0, 0].tolist() == [1.0, 1.0, 1.0]  # transparent corner on white
    with pytest.warns(MissingImageWarning):
        small = load_dataset(root, downscale=4, background="black")
    assert small.test[0].load_image().shape == (200, 200, 3)
    assert small.test[0].camera.fx == pytest.approx(ds.test[0].camera.fx / 4)


@pytest.mark.slow
def test_real_fox() -> None:
    ds = load_dataset(_real("instant_ngp_fox"))
    assert (len(ds.train), len(ds.test)) == (58, 9)
    cams = [v.camera for v in ds.views]
    assert all((c.width, c.height) == (1080, 1920) for c in cams)
    assert cams[0].fx == pytest.approx(1375.52) and cams[0].cy == pytest.approx(965.268)
    assert ds.views[0].undistorter.distortion.k1 == pytest.approx(0.0578421)
    # One camera for all frames: one shared undistorter whose sampling map is kept.
    assert all(v.undistorter is ds.views[0].undistorter for v in ds.views)
    assert ds.views[0].undistorter.keep_maps
    # The cameras orbit the fox: the point closest to all optical axes is seen by every camera.
    a, b = np.zeros((3, 3)), np.zeros(3)
    for c in cams:
        d = c.rotation[2]
        a += np.eye(3) - np.outer(d, d)
        b += (np.eye(3) - np.outer(d, d)) @ c.position
    focus = np.linalg.solve(a, b)
    for c in cams:
        uv, depth = c.project(focus[None])
        assert depth[0] > 0
        assert 0.2 * 1080 < uv[0, 0] < 0.8 * 1080 and 0.2 * 1920 < uv[0, 1] < 0.8 * 1920
    mask = ds.test[0].valid_mask()
    assert mask is not None and 0.95 < mask.mean() < 1.0
    image = ds.test[1].load_image()
    assert image.shape == (1920, 1080, 3) and 0.05 < image.mean() < 0.95


@pytest.mark.slow
def test_real_beer_reprojects_colmap_points() -> None:
    root = _real("beer_colmap")
    ds = load_dataset(root)
    assert ds.format == "colmap" and (len(ds.train), len(ds.test)) == (62, 9)
    assert all((v.camera.width, v.camera.height) == (720, 1280) for v in ds.views)
    assert ds.points.shape == (4414, 3)
    model = read_model(root / "sparse" / "0")
    index = {int(pid): k for k, pid in enumerate(model.points.ids)}
    views = {v.name: v for v in ds.views}
    errors = []
    for image in model.images.values():
        view = views[Path(image.name).stem]
        (fx, fy, cx, cy), distortion = pinhole_and_distortion(model.cameras[image.camera_id])
        seen = image.point3d_ids >= 0
        xyz = model.points.xyz[[index[int(p)] for p in image.point3d_ids[seen]]]
        uv, depth = view.camera.project(xyz)
        assert (depth > 0).all()
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < 720) & (uv[:, 1] >= 0) & (uv[:, 1] < 1280)
        assert inside.mean() > 0.99
        # Observations are in the distorted image; undistort them to compare with the pinhole.
        x, y = distortion.undistort_points((image.xys[seen, 0] - cx) / fx,
                                           (image.xys[seen, 1] - cy) / fy)
        errors.append(np.hypot(uv[:, 0] - (x * fx + cx), uv[:, 1] - (y * fy + cy)))
    errors = np.concatenate(errors)
    assert len(errors) > 10000 and np.mean(errors) < 1.5 and np.median(errors) < 1.0
    # beer also ships poses_bounds.npy: the LLFF reading must give COLMAP's poses.
    llff = {v.name: v.camera for v in load_llff(root, 1, np.zeros(3, np.float32), 8).views}
    for name, view in views.items():
        np.testing.assert_allclose(llff[name].world_to_camera, view.camera.world_to_camera,
                                   atol=1e-6)
    image = ds.test[0].load_image()
    assert image.shape == (1280, 720, 3)
    assert 0.9 < ds.test[0].valid_mask().mean() < 1.0
    assert not ds.test[0].undistorter.keep_maps  # one camera per image: no map is kept around


@pytest.mark.slow
def test_real_fern_llff() -> None:
    root = _real("llff_fern")
    assert detect_format(root) == "llff"  # sparse/0 has no images.bin
    ds = load_dataset(root)
    assert (len(ds.train), len(ds.test)) == (17, 3)
    assert [v.name for v in ds.test] == ["image000", "image008", "image016"]
    cam = ds.views[0].camera
    assert (cam.width, cam.height, cam.cx, cam.cy) == (504, 378, 252.0, 189.0)
    assert cam.fx == pytest.approx(3260.52633 / 8, rel=1e-5)
    cameras = read_cameras_binary(root / "sparse" / "0" / "cameras.bin")
    assert cameras[1].model == "SIMPLE_RADIAL" and cameras[1].params[0] == pytest.approx(3260.526,
                                                                                          rel=1e-5)
    points = read_points_binary(root / "sparse" / "0" / "points3D.bin").xyz
    for view in ds.views:  # a forward-facing capture: nearly all points are in every frame
        uv, depth = view.camera.project(points)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < 504) & (uv[:, 1] >= 0) & (uv[:, 1] < 378)
        assert (depth > 0).all() and inside.mean() > 0.9
    image = ds.test[0].load_image()
    assert image.shape == (378, 504, 3)
    half = load_dataset(root, downscale=2)
    assert half.test[0].load_image().shape == (189, 252, 3)
    assert half.test[0].camera.fx == pytest.approx(cam.fx / 2)
