"""glTF output (KHR_gaussian_splatting): read back with a real glTF library (pygltflib)."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import spcodec
from spcodec.cli import main
from spcodec.cloud import GaussianCloud
from spcodec.errors import UsageError
from spcodec.gltf import COMPRESSION, EXTENSION, glb_bytes, sh_attribute, write_glb

pygltflib = pytest.importorskip("pygltflib", reason="pygltflib (dev extra) reads the GLB back")

_NUMPY = {("SCALAR", 5126): 1, ("VEC3", 5126): 3, ("VEC4", 5126): 4}


def _accessor(gltf, blob: bytes, index: int) -> np.ndarray:
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    width = _NUMPY[(accessor.type, accessor.componentType)]
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    data = np.frombuffer(blob, "<f4", count=accessor.count * width, offset=start)
    assert view.byteLength >= data.nbytes
    return data.reshape(accessor.count, width)


def attributes_of(path) -> tuple[dict, dict[str, np.ndarray]]:
    """The primitive's attribute table from the JSON chunk, and the arrays via pygltflib."""
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob()
    document = json.loads(gltf.to_json())
    primitive = document["meshes"][0]["primitives"][0]
    arrays = {name: _accessor(gltf, blob, index) for name, index in primitive["attributes"].items()}
    return document, arrays


def test_decoded_scene_round_trips_through_pygltflib(tmp_path, small_file):
    cloud = spcodec.decode(small_file)
    path = tmp_path / "scene.glb"
    write_glb(path, cloud)
    document, arrays = attributes_of(path)

    assert document["asset"]["version"] == "2.0"
    assert EXTENSION in document["extensionsUsed"]
    primitive = document["meshes"][0]["primitives"][0]
    assert primitive["mode"] == 0  # POINTS
    assert primitive["extensions"][EXTENSION] == {"kernel": "ellipse",
                                                   "colorSpace": "srgb_rec709_display"}
    expected = {"POSITION", f"{EXTENSION}:ROTATION", f"{EXTENSION}:SCALE", f"{EXTENSION}:OPACITY",
                "COLOR_0"}
    expected |= {sh_attribute(d, n) for d in range(cloud.sh_degree + 1) for n in range(2 * d + 1)}
    assert set(arrays) == expected and cloud.sh_degree == 3 and len(expected) == 5 + 16
    # viewers without the extension draw COLOR_0: the DC colour, clamped, with the opacity
    colour = np.clip(0.5 + 0.28209479177387814 * cloud.sh_dc.astype(np.float64), 0, 1)
    np.testing.assert_allclose(arrays["COLOR_0"][:, :3], colour, atol=1e-6)

    np.testing.assert_array_equal(arrays["POSITION"], cloud.means)
    position = document["accessors"][primitive["attributes"]["POSITION"]]
    np.testing.assert_allclose(position["min"], cloud.means.min(axis=0))
    np.testing.assert_allclose(position["max"], cloud.means.max(axis=0))
    # glTF quaternions are (x, y, z, w), unit length; ours are (w, x, y, z)
    rotation = arrays[f"{EXTENSION}:ROTATION"]
    np.testing.assert_allclose(np.linalg.norm(rotation, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(rotation[:, [3, 0, 1, 2]], cloud.quats, atol=1e-6)
    # linear scales, opacity after the sigmoid
    np.testing.assert_allclose(np.log(arrays[f"{EXTENSION}:SCALE"]), cloud.scales, atol=1e-5)
    opacity = arrays[f"{EXTENSION}:OPACITY"][:, 0]
    assert ((opacity >= 0) & (opacity <= 1)).all()
    np.testing.assert_allclose(opacity, 1 / (1 + np.exp(-cloud.opacities.astype(np.float64))),
                               rtol=1e-6)
    # SH: degree 0 is the DC term; degree l coefficient n is f_rest coefficient l*l - 1 + n
    np.testing.assert_array_equal(arrays[sh_attribute(0, 0)], cloud.sh_dc)
    for degree in (1, 2, 3):
        for n in range(2 * degree + 1):
            np.testing.assert_array_equal(arrays[sh_attribute(degree, n)],
                                          cloud.sh_rest[:, degree * degree - 1 + n])


@pytest.mark.parametrize("up, axis", [("-y", [0, -1, 0]), ("+z", [0, 0, 1]), ("+y", [0, 1, 0]),
                                      ("-x", [-1, 0, 0]), (None, [0, -1, 0])])
def test_the_node_turns_the_scene_up_axis_into_gltf_plus_y(small_file, up, axis):
    """glTF is +Y up: the Gaussians stay as decoded, the node's rotation stands them upright
    (a file that does not say is -y up, the encoder's default)."""
    data = glb_bytes(spcodec.decode(small_file), up=up)
    document = json.loads(data[20:20 + struct.unpack_from("<I", data, 12)[0]])
    x, y, z, w = document["nodes"][0].get("rotation", [0, 0, 0, 1])
    v = np.array(axis, float)
    q = np.array([x, y, z])  # rotate v by the unit quaternion (x, y, z, w)
    turned = v + 2 * w * np.cross(q, v) + 2 * np.cross(q, np.cross(q, v))
    np.testing.assert_allclose(turned, [0, 1, 0], atol=1e-12)
    assert np.isclose(x * x + y * y + z * z + w * w, 1.0)


def test_decode_to_glb_reads_the_up_axis_the_file_stores(tmp_path, capsys):
    from spcodec.synthetic import make_scene

    ply, spc, glb = tmp_path / "s.ply", tmp_path / "s.spc", tmp_path / "s.glb"
    spcodec.write_ply(ply, make_scene(1, curves=1, per_curve=40, blobs=100).cloud)
    assert main(["encode", str(ply), "-o", str(spc), "--no-retrain", "--up=+z", "--quiet"]) == 0
    assert main(["decode", str(spc), "-o", str(glb)]) == 0
    document, _ = attributes_of(glb)
    np.testing.assert_allclose(document["nodes"][0]["rotation"], [-0.5 ** 0.5, 0, 0, 0.5 ** 0.5])


def test_a_compressed_glb_carries_the_spc_itself(tmp_path, capsys, small_file):
    """SPCODEC_gaussian_splatting_compression_spc: the buffer view is the .spc byte for byte;
    the accessors declare what it decodes to (no data of their own)."""
    src, out = tmp_path / "s.spc", tmp_path / "s.glb"
    src.write_bytes(small_file)
    assert main(["embed", str(src), "-o", str(out)]) == 0
    gltf = pygltflib.GLTF2().load(str(out))
    document = json.loads(gltf.to_json())
    assert COMPRESSION in document["extensionsUsed"] and document["extensionsRequired"] == \
        [COMPRESSION]
    splat = document["meshes"][0]["primitives"][0]["extensions"][EXTENSION]
    view = document["bufferViews"][splat["extensions"][COMPRESSION]["bufferView"]]
    blob = gltf.binary_blob()
    assert blob[view.get("byteOffset", 0):][:view["byteLength"]] == small_file
    cloud = spcodec.decode(small_file)
    primitive = document["meshes"][0]["primitives"][0]
    for index in primitive["attributes"].values():
        accessor = document["accessors"][index]
        assert "bufferView" not in accessor and accessor["count"] == len(cloud)
    position = document["accessors"][primitive["attributes"]["POSITION"]]
    np.testing.assert_allclose(position["min"], cloud.means.min(axis=0))
    assert main(["embed", str(src), "-o", str(tmp_path / "s.gltf")]) == 2


def test_glb_container_is_well_formed(small_file):
    data = glb_bytes(spcodec.decode(small_file))
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data)) and length % 4 == 0
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    document = json.loads(data[20:20 + json_length])
    bin_length, bin_type = struct.unpack_from("<II", data, 20 + json_length)
    assert bin_type == 0x004E4942 and bin_length >= document["buffers"][0]["byteLength"]
    assert 28 + json_length + bin_length == len(data)
    for view in document["bufferViews"]:
        assert view["byteOffset"] % 4 == 0
        assert view["byteOffset"] + view["byteLength"] <= document["buffers"][0]["byteLength"]


@given(sh_degree=st.integers(0, 3), n=st.integers(1, 40), seed=st.integers(0, 2**16))
def test_any_cloud_writes_a_readable_glb(tmp_path_factory, sh_degree, n, seed):
    """Every SH degree gives exactly the attributes of its degrees, and unnormalized or zero
    quaternions become unit (x, y, z, w) quaternions."""
    rng = np.random.default_rng(seed)
    cloud = GaussianCloud(
        means=rng.normal(size=(n, 3)), scales=rng.normal(-3, 1, size=(n, 3)),
        quats=rng.normal(size=(n, 4)) * 3, opacities=rng.normal(size=n) * 4,
        sh_dc=rng.normal(size=(n, 3)), sh_rest=rng.normal(size=(n, (sh_degree + 1) ** 2 - 1, 3)))
    cloud.quats[0] = 0.0
    path = tmp_path_factory.mktemp("glb") / "c.glb"
    write_glb(path, cloud)
    _, arrays = attributes_of(path)
    sh_names = {name for name in arrays if ":SH_DEGREE_" in name}
    assert len(sh_names) == (sh_degree + 1) ** 2
    rotation = arrays[f"{EXTENSION}:ROTATION"]
    np.testing.assert_allclose(np.linalg.norm(rotation, axis=1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(rotation[0], [0, 0, 0, 1])  # identity, w last
    unit = cloud.quats[1:] / np.linalg.norm(cloud.quats[1:], axis=1, keepdims=True)
    np.testing.assert_allclose(rotation[1:, [3, 0, 1, 2]], unit, atol=1e-6)


def test_cli_decode_to_glb_and_refusals(capsys, tmp_path, small_file):
    src = tmp_path / "s.spc"
    src.write_bytes(small_file)
    out = tmp_path / "s.glb"
    assert main(["decode", str(src), "-o", str(out), "--max-layer", "0"]) == 0
    _, arrays = attributes_of(out)
    assert len(arrays["POSITION"]) == spcodec.decode_layers(small_file).header.layers[0].gaussian_count
    capsys.readouterr()
    assert main(["decode", str(src), "-o", str(tmp_path / "s.gltf")]) == 2
    _, err = capsys.readouterr()
    assert ".glb" in err and err.count("\n") == 1 and not (tmp_path / "s.gltf").exists()


def test_empty_or_huge_scales_are_refused_without_output(tmp_path):
    with pytest.raises(UsageError, match="empty"):
        write_glb(tmp_path / "e.glb", GaussianCloud.empty())
    cloud = GaussianCloud.zeros(2)
    cloud.scales[1] = 200.0  # exp(200) overflows float32
    with pytest.raises(UsageError, match="too large"):
        write_glb(tmp_path / "h.glb", cloud)
    assert list(tmp_path.iterdir()) == []
