"""Capture input of parameter maps: image I/O, the capture document and loader, the synthetic renderer.

Expected values are computed here from the models directly (one broadcast ``eval`` in float64 over
all texels, directions derived in the test), not through the loader or the renderer.
"""
import json
import re

import colour
import numpy as np
import pytest

from data_synth.capture import capture_directions, flat_field, render_capture
from matfit.errors import DataFormatError
from matfit.maps import Capture, CaptureError, load_capture, write_capture_document
from matfit.maps import read_image, write_exr, write_png
from matfit.models import RoughConductor

H, W = 8, 8


def _maps(h=H, w=W):
    """Conductor maps: alpha from 0.05 to 0.6 across the image, a gold-like and a copper-like half."""
    alpha = np.linspace(0.05, 0.6, h * w).reshape(h, w)
    eta = np.where(np.arange(w)[None, :, None] < w // 2, [0.14, 0.37, 1.44], [0.27, 0.68, 1.3])
    k = np.where(np.arange(w)[None, :, None] < w // 2, [3.98, 2.38, 1.60], [3.6, 2.6, 2.3])
    return {"alpha": alpha, "eta": np.broadcast_to(eta, (h, w, 3)).copy(), "k": np.broadcast_to(k, (h, w, 3)).copy()}


def _reference(maps, wo, wi):
    """f (H, W, N, C) of the conductor maps in float64: ``wo``/``wi`` are (N, 3) or (H, W, N, 3)."""
    h, w = maps["alpha"].shape
    t = h * w
    model = RoughConductor(maps["alpha"].reshape(t, 1), maps["eta"].reshape(t, 1, 3), maps["k"].reshape(t, 1, 3))
    wo, wi = (np.asarray(x, np.float64) for x in (wo, wi))
    if wo.ndim == 4:
        wo, wi = wo.reshape(t, -1, 3), wi.reshape(t, -1, 3)
    return np.asarray(model.eval(wo, wi)).reshape(h, w, -1, 3)


def _check_close(values, expected, rel_bright, abs_peak):
    """Per image: |error| <= rel_bright * |f| where f is above 10 % of the image's peak, and
    |error| <= abs_peak * peak everywhere (quantization is uniform in code, not in value)."""
    peak = expected.max(axis=(0, 1, 3), keepdims=True)
    err = np.abs(values - expected)
    bright = expected > 0.1 * peak
    assert np.all(err[bright] <= rel_bright * expected[bright]), np.max(err[bright] / expected[bright])
    assert np.all(err <= abs_peak * peak), np.max(err / peak)


@pytest.mark.check
@pytest.mark.parametrize("fmt, rel, ab", [("png16", 1e-4, 3e-5), ("exr", 2e-5, 1e-6), ("png8", 2e-2, 6e-3)])
def test_round_trip_directions(tmp_path, fmt, rel, ab):
    maps = _maps()
    lights, cameras = capture_directions(24)
    folder = render_capture(tmp_path / "cap", maps, lights=lights, cameras=cameras, noise=0.0, fmt=fmt)
    cap = load_capture(folder)
    assert isinstance(cap, Capture) and cap.shared_directions
    assert cap.shape == (H, W) and cap.n_images == 24 and cap.n_channels == 3
    assert cap.values.dtype == np.float32 and cap.values.shape == (H, W, 24, 3)
    assert cap.valid.all()
    np.testing.assert_allclose(cap.wi, lights, atol=1e-6)
    np.testing.assert_allclose(cap.wo, cameras, atol=1e-6)
    _check_close(cap.values, _reference(maps, lights, cameras), rel, ab)
    assert [p.name for p in cap.files] == [f"img_{j:03d}.{'exr' if fmt == 'exr' else 'png'}" for j in range(24)]
    assert cap.meta["color_space"] == ("linear" if fmt == "exr" else "srgb")


@pytest.mark.check
def test_round_trip_positions(tmp_path):
    h, w = 12, 16
    maps = _maps(h, w)
    lights, cameras = capture_directions(12, seed=3)
    size = (2.0, 1.5)
    folder = render_capture(tmp_path, maps, lights=lights, cameras=cameras, noise=0.0, fmt="exr",
                            geometry="positions", sample_size=size)
    cap = load_capture(folder / "capture.json")
    assert not cap.shared_directions and cap.wo.shape == (h, w, 12, 3) and cap.wi.shape == (h, w, 12, 3)
    doc = json.loads((folder / "capture.json").read_text())
    assert doc["geometry"] == "positions" and doc["sample_size"] == list(size)
    # texel centres and directions computed here from the document
    light_pos, cam_pos = np.array(doc["lights"]), np.array(doc["cameras"])
    assert np.all(light_pos[:, 2] > 0) and np.linalg.norm(light_pos, axis=1).min() > 9 * max(size)
    rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    pts = np.stack([(cols + 0.5) / w * size[0] - size[0] / 2, size[1] / 2 - (rows + 0.5) / h * size[1],
                    np.zeros((h, w))], -1)[:, :, None, :]
    wi = light_pos - pts
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo = cam_pos - pts
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    np.testing.assert_allclose(cap.wi, wi, atol=1e-6)
    np.testing.assert_allclose(cap.wo, wo, atol=1e-6)
    expected = _reference(maps, wo, wi)
    # 2e-6 of the peak, not the 1e-6 of shared directions: here every texel's directions are
    # normalized in float32 by the renderer, and a lobe's slope turns their rounding into more
    # than the EXR's own error (measured 1.00013e-6 on one machine, below 1e-6 on another)
    _check_close(cap.values, expected, 2e-5, 2e-6)
    # the directions differ across the sample: the shared-direction model would not match
    shared = _reference(maps, np.repeat(cameras[None, None], h, 0).repeat(w, 1),
                        np.repeat(lights[None, None], h, 0).repeat(w, 1))
    assert np.max(np.abs(shared - expected)) > 1e-2 * expected.max()


def test_vignetting_is_divided_out(tmp_path):
    maps = _maps()
    plain = load_capture(render_capture(tmp_path / "a", maps, noise=0.0))
    folder = render_capture(tmp_path / "b", maps, noise=0.0, vignetting=True)
    vig = load_capture(folder)
    assert vig.meta["flat_field"] == "flat.png"
    flat, info = read_image(folder / "flat.png")
    assert info["bit_depth"] == 16 and flat.shape == (H, W, 1)
    assert flat.min() < 0.8 and flat.max() <= 1.0
    np.testing.assert_allclose(flat[..., 0], flat_field((H, W)), atol=1e-5)
    _check_close(vig.values, plain.values.astype(np.float64), 2e-4, 4e-5)


def test_noise_is_relative_and_seeded(tmp_path):
    maps = _maps()
    a = load_capture(render_capture(tmp_path / "a", maps, noise=0.05, fmt="exr", seed=1)).values
    b = load_capture(render_capture(tmp_path / "b", maps, noise=0.05, fmt="exr", seed=1)).values
    c = load_capture(render_capture(tmp_path / "c", maps, noise=0.0, fmt="exr")).values
    np.testing.assert_array_equal(a, b)
    ratio = a / c
    assert 0.03 < np.std(ratio) < 0.07 and abs(np.mean(ratio) - 1) < 0.02


def test_capture_directions_cover_the_specular_peak():
    lights, cameras = capture_directions(24, seed=0)
    np.testing.assert_allclose(np.linalg.norm(lights, axis=1), 1.0)
    np.testing.assert_allclose(np.linalg.norm(cameras, axis=1), 1.0)
    assert min(lights[:, 2].min(), cameras[:, 2].min()) > 0.15
    assert 2 <= len(np.unique(np.round(cameras, 9), axis=0)) <= 3
    assert np.degrees(np.arccos(cameras[:, 2])).max() <= 45.0
    hv = lights + cameras
    theta_h = np.degrees(np.arccos(hv[:, 2] / np.linalg.norm(hv, axis=1)))
    for target in (0, 1.5, 3, 5, 8, 12, 18, 25, 35, 50):
        assert np.min(np.abs(theta_h - target)) < 0.6, target
    assert np.sum(theta_h > 40) >= 3  # off-specular lights for the diffuse part
    l2, _ = capture_directions(24, seed=1)
    assert not np.allclose(lights, l2)


# --- hand-made captures -------------------------------------------------------------------------


def _doc(n, **kw):
    doc = {"images": [f"i{j}.png" for j in range(n)], "lights": [[0.0, 0.0, 1.0]] * n, "camera": [0.0, 0.0, 1.0]}
    doc.update(kw)
    return doc


def _pngs(folder, n, shape=(4, 5, 3), bit_depth=16, value=0.5):
    for j in range(n):
        write_png(folder / f"i{j}.png", np.full(shape, value), bit_depth=bit_depth)


def test_srgb_decoding_matches_colour(tmp_path):
    code = 30000
    write_png(tmp_path / "i0.png", np.full((2, 2, 3), code / 65535), bit_depth=16)
    write_capture_document(tmp_path, _doc(1))
    got = load_capture(tmp_path).values[0, 0, 0, 0]
    want = colour.cctf_decoding(code / 65535, function="sRGB")
    assert abs(got - want) <= 1e-6 * want
    write_capture_document(tmp_path, _doc(1, color_space="linear"))
    assert abs(load_capture(tmp_path).values[0, 0, 0, 0] - code / 65535) <= 1e-7


def test_radiometry_of_scale_irradiance_and_cosine(tmp_path):
    _pngs(tmp_path, 2, value=0.25)
    light = [0.6, 0.0, 0.8]
    write_capture_document(tmp_path, _doc(2, lights=[light, [0, 0, 5.0]], scale=[2.0, 0.5], irradiance=[4.0, 1.0],
                                          color_space="linear"))
    cap = load_capture(tmp_path)
    np.testing.assert_allclose(cap.wi[1], [0, 0, 1])  # normalized
    v = 16384 / 65535  # the code of 0.25
    np.testing.assert_allclose(cap.values[0, 0, :, 0], [v / (2 * 0.8 * 4), v / 0.5], rtol=1e-6)


def test_toml_document(tmp_path):
    _pngs(tmp_path, 1)
    (tmp_path / "capture.toml").write_text('format = "matfit-capture"\nversion = 1\nimages = ["i0.png"]\n'
                                           'lights = [[0, 0, 1]]\ncamera = [0, 0, 1]\ncolor_space = "linear"\n')
    cap = load_capture(tmp_path)
    assert abs(cap.values.mean() - 32768 / 65535) < 1e-6


def test_saturated_and_grazing_measurements_are_invalid(tmp_path):
    img = np.full((4, 5, 3), 0.5)
    img[1, 2, 1] = 1.0  # one channel at the largest code
    write_png(tmp_path / "i0.png", img, bit_depth=8)
    write_png(tmp_path / "i1.png", np.full((4, 5, 3), 0.5), bit_depth=8)
    write_capture_document(tmp_path, _doc(2, lights=[[0, 0, 1], [1.0, 0.0, 0.005]]))
    cap = load_capture(tmp_path)
    assert not cap.valid[1, 2, 0] and cap.valid[:, :, 0].sum() == 4 * 5 - 1
    assert not cap.valid[:, :, 1].any()  # cos(theta_i) = 0.005 <= 0.01
    assert np.isfinite(cap.values).all()


def test_zero_flat_field_is_invalid(tmp_path):
    write_exr(tmp_path / "a.exr", np.full((3, 3, 3), 0.2))
    flat = np.full((3, 3), 0.5)
    flat[0, 0] = 0.0
    write_png(tmp_path / "flat.png", flat, bit_depth=16)
    write_capture_document(tmp_path, {"images": ["a.exr"], "lights": [[0, 0, 1]], "camera": [0, 0, 1],
                                      "flat_field": "flat.png"})
    cap = load_capture(tmp_path)
    assert not cap.valid[0, 0, 0] and cap.valid.sum() == 8
    np.testing.assert_allclose(cap.values[1, 1, 0], 0.2 / (32768 / 65535), rtol=1e-6)


def test_read_image_formats(tmp_path):
    a = np.random.default_rng(0).uniform(size=(3, 4, 4))
    write_png(tmp_path / "rgba.png", a, bit_depth=16)
    got, info = read_image(tmp_path / "rgba.png")
    assert info == {"bit_depth": 16, "format": "png", "max_code": 65535}
    np.testing.assert_array_equal(got, (np.rint(a * 65535) / 65535).astype(np.float32))
    write_exr(tmp_path / "y.exr", a[..., 0])
    got, info = read_image(tmp_path / "y.exr")
    assert info == {"bit_depth": 32, "format": "exr", "max_code": None}
    np.testing.assert_array_equal(got[..., 0], a[..., 0].astype(np.float32))


# --- errors: one message naming the file ---------------------------------------------------------


def _raises(name):
    return pytest.raises(CaptureError, match=re.escape(name))


def test_error_no_document(tmp_path):
    with _raises("capture.json"):
        load_capture(tmp_path)


def test_error_bad_json(tmp_path):
    (tmp_path / "capture.json").write_text("{not json")
    with pytest.raises(CaptureError, match=r"capture\.json: not valid JSON"):
        load_capture(tmp_path)


def test_error_missing_image(tmp_path):
    _pngs(tmp_path, 2)
    write_capture_document(tmp_path, _doc(3))
    with _raises("i2.png"):
        load_capture(tmp_path)


def test_error_count_mismatch(tmp_path):
    _pngs(tmp_path, 3)
    write_capture_document(tmp_path, _doc(3, lights=[[0, 0, 1]] * 2))
    with pytest.raises(CaptureError, match=re.escape("capture.json: 3 images but 2 lights")):
        load_capture(tmp_path)


def test_error_different_sizes(tmp_path):
    _pngs(tmp_path, 2)
    write_png(tmp_path / "i2.png", np.full((4, 6, 3), 0.5))
    write_capture_document(tmp_path, _doc(3))
    with pytest.raises(CaptureError, match=r"i2\.png: shape \(4, 6, 3\).*i0\.png: \(4, 5, 3\)"):
        load_capture(tmp_path)


def test_error_different_channels(tmp_path):
    _pngs(tmp_path, 1)
    write_png(tmp_path / "i1.png", np.full((4, 5), 0.5))
    write_capture_document(tmp_path, _doc(2))
    with pytest.raises(CaptureError, match=r"i1\.png: shape \(4, 5, 1\)"):
        load_capture(tmp_path)


def test_error_different_bit_depths(tmp_path):
    _pngs(tmp_path, 1)
    write_png(tmp_path / "i1.png", np.full((4, 5, 3), 0.5), bit_depth=8)
    write_capture_document(tmp_path, _doc(2))
    with pytest.raises(CaptureError, match=r"i1\.png: 8-bit PNG differs from .*i0\.png: 16-bit PNG"):
        load_capture(tmp_path)


def test_error_4_bit_png(tmp_path):
    import png

    with open(tmp_path / "i0.png", "wb") as f:
        png.Writer(5, 4, greyscale=True, bitdepth=4).write(f, np.full((4, 5), 7, np.uint8))
    write_capture_document(tmp_path, _doc(1))
    with pytest.raises(CaptureError, match=r"i0\.png: expected 8- or 16-bit PNG, found 4-bit"):
        load_capture(tmp_path)
    with pytest.raises(DataFormatError, match=r"i0\.png: expected 8- or 16-bit PNG, found 4-bit"):
        read_image(tmp_path / "i0.png")


def test_error_palette_png(tmp_path):
    import png

    with open(tmp_path / "i0.png", "wb") as f:
        png.Writer(2, 2, palette=[(0, 0, 0), (255, 255, 255)], bitdepth=8).write(f, [[0, 1], [1, 0]])
    with pytest.raises(DataFormatError, match=r"i0\.png: palette PNG"):
        read_image(tmp_path / "i0.png")


def test_error_corrupt_and_unsupported_images(tmp_path):
    (tmp_path / "x.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    (tmp_path / "x.exr").write_bytes(b"garbage" * 10)
    (tmp_path / "x.jpg").write_bytes(b"")
    for name in ("x.png", "x.exr", "x.jpg", "missing.png"):
        with pytest.raises(DataFormatError, match=re.escape(name)):
            read_image(tmp_path / name)


@pytest.mark.parametrize("bad, what", [(np.nan, "1 non-finite"), (-0.5, "1 negative")])
def test_error_bad_exr_pixels(tmp_path, bad, what):
    img = np.full((3, 4, 3), 0.5, np.float32)
    img[2, 1, 0] = bad
    write_exr(tmp_path / "a.exr", np.full((3, 4, 3), 0.5))
    OpenEXR = pytest.importorskip("OpenEXR")
    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(hdr, {"R": img[..., 0].copy(), "G": img[..., 1].copy(), "B": img[..., 2].copy()}) as f:
        f.write(str(tmp_path / "b.exr"))
    write_capture_document(tmp_path, {"images": ["a.exr", "b.exr"], "lights": [[0, 0, 1]] * 2, "camera": [0, 0, 1]})
    with pytest.raises(CaptureError, match=re.escape("b.exr: " + what)):
        load_capture(tmp_path)


def test_error_unknown_key(tmp_path):
    _pngs(tmp_path, 1)
    (tmp_path / "capture.json").write_text(json.dumps({"format": "matfit-capture", "version": 1, **_doc(1),
                                                       "irradiances": 2.0}))
    with pytest.raises(CaptureError, match=r"capture\.json: unknown key 'irradiances'; known keys are .*irradiance"):
        load_capture(tmp_path)
    with pytest.raises(CaptureError, match="unknown key 'irradiances'"):
        write_capture_document(tmp_path, _doc(1, irradiances=2.0))


@pytest.mark.parametrize("entry, what", [([0, 1], "expected 3 finite numbers"), ([0, "a", 1], "expected 3 finite"),
                                         ([0, 0, float("nan")], "expected 3 finite"), ([0, 0, 0], "non-zero"),
                                         ([0.3, 0, -0.1], "below the horizon")])
def test_error_bad_direction(tmp_path, entry, what):
    _pngs(tmp_path, 2)
    write_capture_document(tmp_path, _doc(2, lights=[[0, 0, 1], entry]))
    with pytest.raises(CaptureError, match=r"capture\.json: lights\[1\]: .*" + what):
        load_capture(tmp_path)


def test_error_positions_without_sample_size(tmp_path):
    _pngs(tmp_path, 1)
    write_capture_document(tmp_path, _doc(1, geometry="positions", lights=[[0, 0, 10]], camera=[0, 0, 10]))
    with pytest.raises(CaptureError, match=r"capture\.json: missing key 'sample_size'"):
        load_capture(tmp_path)


def test_error_positions_below_the_sample(tmp_path):
    _pngs(tmp_path, 1)
    write_capture_document(tmp_path, _doc(1, geometry="positions", lights=[[0, 0, -1]], camera=[0, 0, 10],
                                          sample_size=[1, 1]))
    with pytest.raises(CaptureError, match=r"capture\.json: lights\[0\]: position must be above"):
        load_capture(tmp_path)


def test_error_wrong_format_and_flat_size(tmp_path):
    _pngs(tmp_path, 1)
    write_capture_document(tmp_path, _doc(1, format="other"))
    with pytest.raises(CaptureError, match=r"capture\.json: key 'format': expected 'matfit-capture', found 'other'"):
        load_capture(tmp_path)
    write_png(tmp_path / "flat.png", np.ones((3, 3)))
    write_capture_document(tmp_path, _doc(1, flat_field="flat.png"))
    with pytest.raises(CaptureError, match=r"flat\.png: shape \(3, 3, 1\) does not match"):
        load_capture(tmp_path)


# --- loading into files (out=...): memory maps written a band of rows at a time -------------------

import matfit.maps._capture as capture_module  # noqa: E402
from matfit.maps._images import open_image_rows, read_image_codes  # noqa: E402


def _band_rows(monkeypatch, rows, w, n, c, positions=False):
    """Make the banded loader assemble ``rows`` rows per band (1 if rows <= 1)."""
    monkeypatch.setattr(capture_module, "_BAND_BYTES", rows * w * n * (4 * c + 1 + (24 if positions else 0)))


def _assert_same_capture(a, b):
    for key in ("values", "valid", "wo", "wi"):
        x, y = getattr(a, key), getattr(b, key)
        assert x.dtype == y.dtype and x.shape == y.shape, key
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=key)
    assert a.files == b.files and a.meta == b.meta


@pytest.mark.parametrize("fmt, geometry, vignetting", [("png16", "directions", True), ("png8", "directions", False),
                                                       ("exr", "directions", True), ("exr", "positions", False),
                                                       ("png16", "positions", True)])
@pytest.mark.parametrize("rows", [1, 3, None])
def test_out_matches_in_memory(tmp_path, monkeypatch, fmt, geometry, vignetting, rows):
    h, w, n = 7, 6, 5
    lights, cameras = capture_directions(n, seed=2)
    folder = render_capture(tmp_path / "cap", _maps(h, w), lights=lights, cameras=cameras, noise=0.02, fmt=fmt,
                            vignetting=vignetting, geometry=geometry, seed=4)
    if rows is not None:  # several bands, the last one short (7 rows in bands of 3)
        _band_rows(monkeypatch, rows, w, n, 3, geometry == "positions")
    mem = load_capture(folder)
    disk = load_capture(folder, out=tmp_path / "out" / "nested")
    _assert_same_capture(disk, mem)
    assert isinstance(disk.values, np.memmap) and isinstance(disk.valid, np.memmap)
    assert not disk.values.flags.writeable and disk.values.flags.c_contiguous
    expected = ["valid.npy", "values.npy"] + (["wi.npy", "wo.npy"] if geometry == "positions" else [])
    assert sorted(p.name for p in (tmp_path / "out" / "nested").iterdir()) == expected
    if geometry == "positions":
        assert isinstance(disk.wo, np.memmap) and disk.wo.shape == (h, w, n, 3)
    else:
        assert not isinstance(disk.wo, np.memmap) and disk.shared_directions
    np.testing.assert_array_equal(np.load(tmp_path / "out" / "nested" / "values.npy"), mem.values)


def test_out_marks_saturated_grazing_and_zero_flat(tmp_path, monkeypatch):
    img = np.full((5, 4, 3), 0.5)
    img[3, 2, 1] = 1.0  # saturated
    write_png(tmp_path / "i0.png", img, bit_depth=8)
    write_png(tmp_path / "i1.png", np.full((5, 4, 3), 0.25), bit_depth=8)
    flat = np.full((5, 4), 0.5)
    flat[4, 0] = 0.0
    write_png(tmp_path / "flat.png", flat, bit_depth=16)
    write_capture_document(tmp_path, _doc(2, lights=[[0, 0, 1], [1.0, 0.0, 0.005]], flat_field="flat.png",
                                          scale=[1.0, 2.0]))
    _band_rows(monkeypatch, 2, 4, 2, 3)
    mem, disk = load_capture(tmp_path), load_capture(tmp_path, out=tmp_path / "out")
    _assert_same_capture(disk, mem)
    assert not disk.valid[3, 2, 0] and not disk.valid[4, 0, 0] and not disk.valid[:, :, 1].any()
    assert disk.valid[:, :, 0].sum() == 5 * 4 - 2


def test_out_interlaced_png(tmp_path):
    import png

    codes = np.random.default_rng(1).integers(0, 60000, size=(6, 5, 3), dtype=np.uint16)
    for j in range(2):
        with open(tmp_path / f"i{j}.png", "wb") as f:
            png.Writer(5, 6, greyscale=False, bitdepth=16, interlace=True).write(f, (codes + j).reshape(6, 15))
    write_capture_document(tmp_path, _doc(2))
    with open_image_rows(tmp_path / "i0.png") as im:
        assert im.interlaced
    mem = load_capture(tmp_path)
    _assert_same_capture(load_capture(tmp_path, out=tmp_path / "out"), mem)
    assert np.array_equal(mem.valid, np.ones((6, 5, 2), bool))


def test_out_replaces_previous_files(tmp_path):
    _pngs(tmp_path, 2, value=0.25)
    write_capture_document(tmp_path, _doc(2, color_space="linear"))
    first = load_capture(tmp_path, out=tmp_path / "out")
    before = np.array(first.values)
    del first
    _pngs(tmp_path, 2, value=0.5)
    again = load_capture(tmp_path, out=tmp_path / "out")
    np.testing.assert_array_equal(again.values, load_capture(tmp_path).values)
    assert not np.array_equal(again.values, before)


def _in_memory_message(path):
    with pytest.raises(CaptureError) as e:
        load_capture(path)
    return str(e.value)


def _count_writes(monkeypatch):
    """Record the rows written by the banded loader (to check an error came after some bands)."""
    rows = []
    write = capture_module._NpyFile.write_rows

    def counting(self, row, band):
        rows.append((self.path.name, row))
        return write(self, row, band)

    monkeypatch.setattr(capture_module._NpyFile, "write_rows", counting)
    return rows


def _no_results(out):
    return not out.exists() or not [p.name for p in out.iterdir() if p.name.startswith(("values", "valid", "wo", "wi"))]


def test_out_error_mid_way_leaves_no_files(tmp_path, monkeypatch):
    """Bad pixels in the last rows of the last image: bands were written before the error."""
    OpenEXR = pytest.importorskip("OpenEXR")
    h, w = 6, 4
    for j in range(3):
        write_exr(tmp_path / f"e{j}.exr", np.full((h, w, 3), 0.5))
    img = np.full((h, w, 3), 0.5, np.float32)
    img[5, 1, 0] = np.nan
    img[4, 2, 2] = np.inf
    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(hdr, {"R": img[..., 0].copy(), "G": img[..., 1].copy(), "B": img[..., 2].copy()}) as f:
        f.write(str(tmp_path / "e3.exr"))
    write_capture_document(tmp_path, {"images": [f"e{j}.exr" for j in range(4)], "lights": [[0, 0, 1]] * 4,
                                      "camera": [0, 0, 1], "geometry": "positions", "sample_size": [1, 1]})
    _band_rows(monkeypatch, 1, w, 4, 3, positions=True)
    writes = _count_writes(monkeypatch)
    want = _in_memory_message(tmp_path)
    assert "e3.exr: 2 non-finite pixel values" in want
    out = tmp_path / "out"
    with pytest.raises(CaptureError) as e:
        load_capture(tmp_path, out=out)
    assert str(e.value) == want  # the whole image's count, as in memory
    assert ("values.npy", 3) in writes and ("wo.npy", 3) in writes  # rows 0-3 were written first
    assert out.is_dir() and list(out.iterdir()) == []  # partial files removed


def test_out_truncated_png_leaves_no_files(tmp_path, monkeypatch):
    import png

    rng = np.random.default_rng(0)
    for j in range(2):  # noisy images in many small IDAT chunks: the data spans the file
        codes = rng.integers(6000, 60000, size=(120, 300), dtype=np.uint16)
        with open(tmp_path / f"i{j}.png", "wb") as f:
            png.Writer(100, 120, greyscale=False, bitdepth=16, chunk_limit=4096).write(f, codes)
    data = (tmp_path / "i1.png").read_bytes()
    (tmp_path / "i1.png").write_bytes(data[: len(data) * 2 // 3])
    write_capture_document(tmp_path, _doc(2))
    _band_rows(monkeypatch, 4, 100, 2, 3)
    writes = _count_writes(monkeypatch)
    want = _in_memory_message(tmp_path)
    assert "i1.png" in want
    with pytest.raises(CaptureError) as e:
        load_capture(tmp_path, out=tmp_path / "out")
    assert str(e.value) == want
    assert ("values.npy", 40) in writes  # the data ran out after some bands
    assert _no_results(tmp_path / "out") and not list((tmp_path / "out").glob("*.partial"))


@pytest.mark.parametrize("case", ["size", "depth", "missing", "flat", "corrupt header"])
def test_out_header_errors_before_any_file(tmp_path, case):
    _pngs(tmp_path, 2)
    doc = _doc(3)
    if case == "size":
        write_png(tmp_path / "i2.png", np.full((4, 6, 3), 0.5))
    elif case == "depth":
        write_png(tmp_path / "i2.png", np.full((4, 5, 3), 0.5), bit_depth=8)
    elif case == "flat":
        _pngs(tmp_path, 3)
        write_png(tmp_path / "flat.png", np.ones((3, 3)))
        doc = _doc(3, flat_field="flat.png")
    elif case == "corrupt header":
        (tmp_path / "i2.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    write_capture_document(tmp_path, doc)
    want = _in_memory_message(tmp_path)
    with pytest.raises(CaptureError) as e:
        load_capture(tmp_path, out=tmp_path / "out")
    assert str(e.value) == want
    assert not (tmp_path / "out").exists()  # nothing was started


def test_out_document_errors(tmp_path):
    with _raises("capture.json"):
        load_capture(tmp_path, out=tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kind", ["png8", "png16", "exr-half", "exr-window"])
def test_open_image_rows_matches_whole_reads(tmp_path, kind):
    rng = np.random.default_rng(5)
    a = rng.uniform(size=(9, 7, 3))
    path = tmp_path / ("x.png" if kind.startswith("png") else "x.exr")
    if kind.startswith("png"):
        write_png(path, a, bit_depth=int(kind[3:]))
    else:
        OpenEXR = pytest.importorskip("OpenEXR")
        hdr = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}
        if kind == "exr-window":  # a data window away from the origin
            hdr.update(dataWindow=((3, 10), (9, 18)), displayWindow=((0, 0), (19, 29)))
        dt = np.float16 if kind == "exr-half" else np.float32
        with OpenEXR.File(hdr, {k: a[..., i].astype(dt) for i, k in enumerate("RGB")}) as f:
            f.write(str(path))
    whole, info = read_image_codes(path)
    with open_image_rows(path) as im:
        assert im.shape == whole.shape and im.info == info
        parts = [im.read(4), im.read(0), im.read(4), im.read(4), im.read(4)]
        assert [p.shape[0] for p in parts] == [4, 0, 4, 1, 0]
        im.finish()
    got = np.concatenate(parts)
    assert got.dtype == whole.dtype
    np.testing.assert_array_equal(got, whole)


def test_open_image_rows_errors_as_whole_reads(tmp_path):
    rng = np.random.default_rng(0)
    write_png(tmp_path / "x.png", rng.uniform(size=(30, 20, 3)), bit_depth=16)
    data = (tmp_path / "x.png").read_bytes()
    (tmp_path / "x.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataFormatError) as whole:
        read_image_codes(tmp_path / "x.png")
    with pytest.raises(DataFormatError) as banded:
        with open_image_rows(tmp_path / "x.png") as im:
            while im.position < im.shape[0]:
                im.read(3)
            im.finish()
    assert str(banded.value) == str(whole.value) and "x.png" in str(whole.value)
    (tmp_path / "y.exr").write_bytes(b"garbage" * 10)
    with pytest.raises(DataFormatError) as whole:
        read_image_codes(tmp_path / "y.exr")
    with pytest.raises(DataFormatError) as banded:
        open_image_rows(tmp_path / "y.exr")
    assert str(banded.value) == str(whole.value)
