"""Point cloud and mesh ingestion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ldlmap.core.errors import InputError
from ldlmap.io.mesh import MeshSampling, sample_mesh
from ldlmap.io.cloud import PointCloud
from ldlmap.io.pointcloud import read_point_cloud, write_point_cloud


def _cloud(n: int = 500, seed: int = 0, colors: bool = True) -> PointCloud:
    rng = np.random.default_rng(seed)
    return PointCloud(rng.normal(size=(n, 3)) * 3.0, rng.integers(0, 256, (n, 3), dtype=np.uint8) if colors else None)


@pytest.mark.parametrize("suffix", [".ply", ".txt"])
@pytest.mark.parametrize("colors", [True, False])
def test_write_read_roundtrip_exact(tmp_path: Path, suffix: str, colors: bool) -> None:
    pc = _cloud(colors=colors)
    path = write_point_cloud(tmp_path / f"c{suffix}", pc)
    back = read_point_cloud(path)
    assert np.array_equal(back.points, pc.points)
    assert (back.colors is None) == (not colors)
    if colors:
        assert np.array_equal(back.colors, pc.colors)
    assert [p.name for p in tmp_path.iterdir()] == [f"c{suffix}"]  # no temporary left behind


def test_pcd_via_open3d(tmp_path: Path) -> None:
    import open3d as o3d

    pc = _cloud(100, seed=1)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pc.points))
    cloud.colors = o3d.utility.Vector3dVector(pc.colors / 255.0)
    o3d.io.write_point_cloud(str(tmp_path / "c.pcd"), cloud)
    back = read_point_cloud(tmp_path / "c.pcd")
    assert np.allclose(back.points, pc.points, atol=1e-5) and np.array_equal(back.colors, pc.colors)


def test_ply_variants(tmp_path: Path) -> None:
    import open3d as o3d

    pc = _cloud(50, seed=4)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pc.points))
    cloud.colors = o3d.utility.Vector3dVector(pc.colors / 255.0)
    for ascii_mode in (False, True):
        path = tmp_path / f"o3d_{ascii_mode}.ply"
        o3d.io.write_point_cloud(str(path), cloud, write_ascii=ascii_mode)
        back = read_point_cloud(path)
        assert np.allclose(back.points, pc.points, atol=1e-6) and np.array_equal(back.colors, pc.colors)
    (tmp_path / "a.ply").write_text("ply\nformat ascii 1.0\ncomment hi\nelement vertex 2\nproperty float x\n"
                                    "property float y\nproperty float z\nproperty float red\nproperty float green\n"
                                    "property float blue\nend_header\n0 1 2 1 0 0.5\n3 4 5 0 1 0\n")
    back = read_point_cloud(tmp_path / "a.ply")
    assert back.points.tolist() == [[0, 1, 2], [3, 4, 5]] and back.colors.tolist() == [[255, 0, 128], [0, 255, 0]]


def test_text_variants(tmp_path: Path) -> None:
    (tmp_path / "comma.txt").write_text("# x,y,z,r,g,b\n1.5,2,3,10,20,30\n-1, 0.25, 7, 255, 0, 1\n")
    pc = read_point_cloud(tmp_path / "comma.txt")
    assert np.array_equal(pc.points, [[1.5, 2, 3], [-1, 0.25, 7]]) and pc.colors.tolist() == [[10, 20, 30], [255, 0, 1]]
    (tmp_path / "xyz.txt").write_text("1 2 3\n4\t5\t6\n")
    pc = read_point_cloud(tmp_path / "xyz.txt")
    assert pc.colors is None and pc.points.shape == (2, 3)
    (tmp_path / "count.txt").write_text("2\n1 2 3 0.5 0.25 1.0\n4 5 6 0 0 0\n")  # header count + [0, 1] colors
    pc = read_point_cloud(tmp_path / "count.txt")
    assert pc.colors.tolist() == [[128, 64, 255], [0, 0, 0]]


def test_bounds_and_subsample() -> None:
    pc = PointCloud(np.array([[0, 1, 2], [3, -1, 5], [1, 1, 1.0]]))
    lo, hi = pc.bounds()
    assert lo.tolist() == [0, -1, 1] and hi.tolist() == [3, 1, 5]
    big = _cloud(1000, seed=2)
    sub = big.subsample(100, seed=3)
    assert len(sub) == 100 and np.array_equal(sub.points, big.subsample(100, seed=3).points)
    idx = [np.flatnonzero((big.points == p).all(1))[0] for p in sub.points]
    assert np.all(np.diff(idx) > 0)  # a subset, original order kept
    assert np.array_equal(big.colors[idx], sub.colors)
    assert big.subsample(5000) is big


def test_bad_inputs(tmp_path: Path) -> None:
    cases = {
        "missing.ply": (None, "not found"),
        "cloud.las": (b"x", "unsupported point cloud format .las .*supported: .ply, .pcd, .txt"),
        "empty.txt": (b"# nothing\n", "empty"),
        "nan.txt": (b"0 0 0\nnan 1 2\n", "NaN/inf"),
        "cols.txt": (b"0 0 0 1\n1 1 1 2\n", "3 \\(x y z\\) or 6"),
        "ragged.txt": (b"0 0 0 1 2 3\n1 1 1 2\n", "malformed"),
        "word.txt": (b"0 0 0\n1 a 1\n", "malformed"),
        "range.txt": (b"0 0 0 300 0 0\n", "0-255"),
        "bad.ply": (b"not a ply", "not a PLY"),
        "trunc.ply": (b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty double x\n"
                      b"property double y\nproperty double z\nend_header\n\x00\x01", "truncated"),
    }
    for name, (data, msg) in cases.items():
        if data is not None:
            (tmp_path / name).write_bytes(data)
        with pytest.raises(InputError, match=msg) as info:
            read_point_cloud(tmp_path / name)
        assert "\n" not in str(info.value)
    with pytest.raises(InputError, match="cannot write point cloud format .pcd"):
        write_point_cloud(tmp_path / "out.pcd", _cloud(3))
    with pytest.raises(InputError, match="shape"):
        PointCloud(np.zeros((4, 2)))


# ------------------------------------------------------------------------------------- meshes


def _textured_quad(folder: Path) -> Path:
    """A 2 x 1 m quad whose texture is red on the left half and blue on the right half."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    tex = np.zeros((32, 64, 3), np.uint8)
    tex[:, :32] = (0, 0, 255)  # BGR red
    tex[:, 32:] = (255, 0, 0)  # BGR blue
    cv2.imwrite(str(folder / "quad_tex.png"), tex)
    (folder / "quad.mtl").write_text("newmtl wall\nKa 1 1 1\nKd 1 1 1\nmap_Kd quad_tex.png\n")
    (folder / "quad.obj").write_text("mtllib quad.mtl\nv 0 0 0\nv 2 0 0\nv 2 0 1\nv 0 0 1\n"
                                     "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl wall\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    return folder / "quad.obj"


def test_textured_mesh_colors_transferred(tmp_path: Path) -> None:
    obj = _textured_quad(tmp_path)
    pc = sample_mesh(obj, 3000)
    assert len(pc) == 3000 and pc.colors is not None
    assert np.allclose(pc.points[:, 1], 0.0) and pc.points[:, 0].min() >= 0 and pc.points[:, 0].max() <= 2
    left, right = pc.points[:, 0] < 0.95, pc.points[:, 0] > 1.05
    assert 0.4 < left.mean() < 0.55  # area-uniform sampling
    assert np.all(pc.colors[left] == [255, 0, 0]) and np.all(pc.colors[right] == [0, 0, 255])
    assert np.array_equal(sample_mesh(obj, 3000).points, pc.points)  # seeded
    poisson = sample_mesh(obj, 500, MeshSampling(method="poisson"))
    pl = poisson.points[:, 0] < 0.95
    assert 300 < len(poisson) < 700 and np.all(poisson.colors[pl] == [255, 0, 0])
    # read_point_cloud delegates meshes.
    assert len(read_point_cloud(obj, mesh_samples=200)) == 200


def test_vertex_colored_ply_mesh(tmp_path: Path) -> None:
    ply = tmp_path / "tri.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                   "property uchar red\nproperty uchar green\nproperty uchar blue\nelement face 1\n"
                   "property list uchar int vertex_indices\nend_header\n0 0 0 255 0 0\n1 0 0 0 255 0\n"
                   "0 1 0 0 0 255\n3 0 1 2\n")
    pc = read_point_cloud(ply, mesh_samples=300)
    assert len(pc) == 300
    x, y = pc.points[:, 0], pc.points[:, 1]
    expected = np.stack([1 - x - y, x, y], axis=1) * 255  # barycentric interpolation of vertex colors
    assert np.abs(pc.colors.astype(float) - expected).max() <= 2.0


def test_mesh_bad_inputs(tmp_path: Path) -> None:
    obj = _textured_quad(tmp_path / "a")
    (tmp_path / "a" / "quad_tex.png").unlink()
    with pytest.raises(InputError, match="texture image quad_tex.png referenced by .*quad.mtl not found"):
        sample_mesh(obj, 10)
    (tmp_path / "a" / "quad.mtl").unlink()
    with pytest.raises(InputError, match="material library quad.mtl"):
        sample_mesh(obj, 10)
    (tmp_path / "pts.obj").write_text("v 0 0 0\nv 1 0 0\n")
    with pytest.raises(InputError, match="no faces"):
        sample_mesh(tmp_path / "pts.obj", 10)
    with pytest.raises(InputError, match="not found"):
        sample_mesh(tmp_path / "none.obj", 10)
