"""SuperPoint network, post-processing and weights resolution (no network access)."""

from __future__ import annotations

import urllib.error

import numpy as np
import pytest
import torch

from ldlmap.core.errors import InputError
from ldlmap.features import get_backend
from ldlmap.features import weights as wmod
from ldlmap.features.superpoint import SuperPointBackend, build_superpoint, nms_keep, sample_descriptors

# The official MagicLeap superpoint_v1.pth state dict: names and shapes.
OFFICIAL = {
    "conv1a": (64, 1, 3, 3), "conv1b": (64, 64, 3, 3), "conv2a": (64, 64, 3, 3), "conv2b": (64, 64, 3, 3),
    "conv3a": (128, 64, 3, 3), "conv3b": (128, 128, 3, 3), "conv4a": (128, 128, 3, 3),
    "conv4b": (128, 128, 3, 3), "convPa": (256, 128, 3, 3), "convPb": (65, 256, 1, 1),
    "convDa": (256, 128, 3, 3), "convDb": (256, 256, 1, 1),
}


def _image(h: int = 96, w: int = 160, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (h // 8, w // 8, 3), dtype=np.uint8)
    return np.repeat(np.repeat(small, 8, 0), 8, 1)


@pytest.fixture()
def checkpoint(tmp_path, monkeypatch):
    """A random-initialised checkpoint in a tmp folder; cache and env isolated from the user's."""
    monkeypatch.setenv("LDL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("LDL_SUPERPOINT_WEIGHTS", raising=False)
    torch.manual_seed(0)
    net = build_superpoint()
    path = tmp_path / "sp_random.pth"
    torch.save(net.state_dict(), path)
    return net, path


def test_state_dict_matches_official_keys():
    sd = build_superpoint().state_dict()
    want = {f"{k}.weight": s for k, s in OFFICIAL.items()} | {f"{k}.bias": (s[0],) for k, s in OFFICIAL.items()}
    assert {k: tuple(v.shape) for k, v in sd.items()} == want


def test_outputs_shapes_nms_grid_and_unit_descriptors(checkpoint):
    net, path = checkpoint
    sp = SuperPointBackend(weights=str(path), keypoint_threshold=0.0, max_keypoints=0)
    img = _image(100, 150)  # not a multiple of 8: padded internally
    f = sp.extract(img)
    K = len(f)
    assert K > 20 and f.keypoints.shape == (K, 2) and f.scores.shape == (K,)
    assert f.descriptors.shape == (K, 256) and f.descriptors.dtype == np.float16
    assert sp.descriptor_dtype == np.float16 and sp.name == "superpoint"
    # Keypoints sit on pixel centres, away from the border, separated by more than the NMS radius.
    frac = f.keypoints - 0.5
    assert np.array_equal(frac, np.round(frac))
    assert f.keypoints.min() >= 4.5 and f.keypoints[:, 0].max() <= 150 - 4.5 and f.keypoints[:, 1].max() <= 100 - 4.5
    cheb = np.abs(f.keypoints[:, None] - f.keypoints[None]).max(axis=2) + np.eye(K) * 99
    assert cheb.min() > 4
    np.testing.assert_allclose(np.linalg.norm(f.descriptors.astype(np.float32), axis=1), 1.0, atol=2e-3)
    assert np.all(np.diff(f.scores) <= 0)
    assert len(sp.extract(img, max_keypoints=7)) == 7
    mask = np.zeros(img.shape[:2], bool)
    mask[:, 75:] = True
    assert (sp.extract(img, mask=mask).keypoints[:, 0] > 75).all()


def test_save_load_gives_identical_outputs(checkpoint, tmp_path):
    net, path = checkpoint
    img = _image(seed=3)
    a = SuperPointBackend(net=net, keypoint_threshold=0.0).extract(img)
    b = SuperPointBackend(weights=str(path), keypoint_threshold=0.0).extract(img)
    np.testing.assert_array_equal(a.keypoints, b.keypoints)
    np.testing.assert_array_equal(a.scores, b.scores)
    np.testing.assert_array_equal(a.descriptors, b.descriptors)
    # Cosine matching of float16 unit descriptors recovers a permutation (random-weight
    # descriptors are all nearly parallel, so use random ones here).
    desc = torch.nn.functional.normalize(torch.randn(300, 256), dim=1).numpy().astype(np.float16)
    perm = np.random.default_rng(0).permutation(300)
    m = SuperPointBackend(net=net).match(desc, desc[perm])
    assert len(m) == 300 and np.array_equal(perm[m[:, 1]], m[:, 0])


def test_weights_resolution_routes(checkpoint, tmp_path, monkeypatch):
    net, path = checkpoint
    # 1. explicit path
    assert wmod.resolve_weights("superpoint", path) == path
    with pytest.raises(InputError, match="weights not found"):
        wmod.resolve_weights("superpoint", tmp_path / "missing.pth")
    # 2. environment variable
    monkeypatch.setenv("LDL_SUPERPOINT_WEIGHTS", str(path))
    assert wmod.resolve_weights("superpoint") == path
    assert isinstance(get_backend("superpoint"), SuperPointBackend)
    monkeypatch.setenv("LDL_SUPERPOINT_WEIGHTS", str(tmp_path / "nope.pth"))
    with pytest.raises(InputError, match="LDL_SUPERPOINT_WEIGHTS"):
        wmod.resolve_weights("superpoint")
    monkeypatch.delenv("LDL_SUPERPOINT_WEIGHTS")
    # 4. first-use download (a file:// URL: no network) into the cache under the versioned name
    spec = wmod.WEIGHTS["superpoint"]
    monkeypatch.setitem(wmod.WEIGHTS, "superpoint", wmod.WeightSpec(
        filename=spec.filename, url=path.as_uri(), env_var=spec.env_var, version=spec.version))
    got = wmod.resolve_weights("superpoint")
    assert got == tmp_path / "cache" / "superpoint_v1.pth" and got.read_bytes() == path.read_bytes()
    # 3. cache hit: no download attempted
    monkeypatch.setattr(wmod, "download", lambda url, dst: pytest.fail("downloaded despite cache"))
    assert wmod.resolve_weights("superpoint") == got
    img = _image(seed=4)
    a = SuperPointBackend(net=net, keypoint_threshold=0.0).extract(img)
    c = get_backend("superpoint", keypoint_threshold=0.0).extract(img)
    np.testing.assert_array_equal(a.descriptors, c.descriptors)


def test_offline_and_bad_checkpoints_fail_clearly(checkpoint, tmp_path, monkeypatch):
    net, path = checkpoint

    def offline(url, dst):
        raise urllib.error.URLError("no route to host")

    monkeypatch.setattr(wmod, "download", offline)
    with pytest.raises(InputError) as exc:
        get_backend("superpoint")
    msg = str(exc.value)
    assert "\n" not in msg and "--weights PATH" in msg and "LDL_SUPERPOINT_WEIGHTS" in msg
    assert str(tmp_path / "cache") in msg and "superpoint_v1.pth" in msg and "no route to host" in msg
    assert not list((tmp_path / "cache").glob("*"))  # no partial file left
    # A checksum mismatch is a failure too, and leaves nothing in the cache.
    spec = wmod.WEIGHTS["superpoint"]
    monkeypatch.setitem(wmod.WEIGHTS, "superpoint", wmod.WeightSpec(
        filename=spec.filename, url=path.as_uri(), env_var=spec.env_var, version=spec.version, sha256="0" * 64))
    monkeypatch.setattr(wmod, "download", lambda url, dst: dst.write_bytes(path.read_bytes()))
    with pytest.raises(InputError, match="checksum mismatch"):
        wmod.resolve_weights("superpoint")
    assert not (tmp_path / "cache" / "superpoint_v1.pth").exists()
    corrupt = tmp_path / "corrupt.pth"
    corrupt.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="cannot read SuperPoint weights"):
        get_backend("superpoint", weights=str(corrupt))
    sd = net.state_dict()
    sd.pop("convDb.bias")
    sd["extra.weight"] = torch.zeros(1)
    wrong = tmp_path / "wrong.pth"
    torch.save(sd, wrong)
    with pytest.raises(InputError, match="missing.*convDb.bias.*unexpected.*extra.weight"):
        get_backend("superpoint", weights=str(wrong))
    torch.save({"state_dict": net.state_dict()}, tmp_path / "wrapped.pth")
    assert get_backend("superpoint", weights=str(tmp_path / "wrapped.pth")).name == "superpoint"


def test_nms_keep_against_brute_force_with_ties():
    g = torch.Generator().manual_seed(0)
    s = torch.rand(1, 40, 50, generator=g)
    s = torch.round(s * 8) / 8  # many ties
    keep = nms_keep(s, 2)[0].numpy()
    S = s[0].numpy()
    H, W = S.shape
    for r, c in zip(*np.nonzero(keep)):
        win = S[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3]
        assert S[r, c] == win.max() > 0
    pts = np.argwhere(keep)
    cheb = np.abs(pts[:, None] - pts[None]).max(axis=2) + np.eye(len(pts), dtype=int) * 99
    assert cheb.min() > 2
    # Every strict local maximum survives.
    strict = [(r, c) for r in range(H) for c in range(W)
              if S[r, c] > 0 and (S[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3] == S[r, c]).sum() == 1
              and S[r, c] == S[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3].max()]
    assert all(keep[r, c] for r, c in strict) and len(strict) > 0


def test_descriptor_sampling_at_cell_centres():
    d = torch.nn.functional.normalize(torch.randn(1, 8, 5, 7), dim=1)
    uv = torch.tensor([[8 * 3 + 4.0, 8 * 2 + 4.0], [4.0, 4.0], [8 * 6 + 4.0, 8 * 4 + 4.0]])
    got = sample_descriptors(d, uv)
    want = torch.stack([d[0, :, 2, 3], d[0, :, 0, 0], d[0, :, 4, 6]])
    torch.testing.assert_close(got, want, atol=1e-6, rtol=1e-5)
    mid = sample_descriptors(d, torch.tensor([[8.0, 4.0]]))  # half-way between cells 0 and 1
    torch.testing.assert_close(mid[0], torch.nn.functional.normalize(d[0, :, 0, 0] + d[0, :, 0, 1], dim=0))


def test_lightglue_pairs_with_superpoint_only_when_its_weights_are_present(checkpoint, tmp_path, monkeypatch):
    from kornia.feature import LightGlue

    from ldlmap.features import Features

    net, path = checkpoint
    monkeypatch.delenv("LDL_SUPERPOINT_LIGHTGLUE_WEIGHTS", raising=False)
    sp = SuperPointBackend(weights=str(path))
    assert sp.matcher_name == "mutual-nn" and sp.query_keypoints == 8192
    torch.manual_seed(1)
    lg = tmp_path / "sp_lightglue_random.pth"
    torch.save(LightGlue(None, input_dim=256).state_dict(), lg)
    monkeypatch.setenv("LDL_SUPERPOINT_LIGHTGLUE_WEIGHTS", str(lg))
    sp = SuperPointBackend(weights=str(path), keypoint_threshold=0.0, max_keypoints=200)
    assert sp.matcher_name == "lightglue" and sp.query_keypoints == 200
    f = sp.extract(_image(96, 160))
    m = sp.match_views(f, (160, 96), [f, Features(f.keypoints[:0], f.scores[:0], f.descriptors[:0])], (160, 96))
    assert len(m) == 2 and m[0].shape[1] == 2 and len(m[1]) == 0
    monkeypatch.setenv("LDL_SUPERPOINT_LIGHTGLUE_WEIGHTS", str(tmp_path / "missing.pth"))  # set but wrong: an error
    with pytest.raises(InputError, match="superpoint_lightglue weights not found"):
        SuperPointBackend(weights=str(path))
