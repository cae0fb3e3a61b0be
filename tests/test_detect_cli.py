"""`capm-field detect`: the detector on image files (capm_field/detect_cli.py).

In-process (`capm_field.cli.main`), on the hand-made fixture photos. The detector's accuracy is
tested elsewhere (test_detector.py); here: that the command reads what a user hands it the way
the user sees it (EXIF orientation, grey and 16-bit files), restricts the search as asked, reports
every file, bad ones included, and loses nothing when interrupted.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from capm_field import cli, detect_cli
from capm_field.detector import detect_centre

FIX = Path(__file__).parent / "fixtures" / "plants"
TRUTH = json.loads((FIX / "truth.json").read_text())


def run(capsys, *args: str) -> tuple[int, str, str]:
    rc = cli.main(["detect", *args])
    out, err = capsys.readouterr()
    return rc, out, err


def with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """The JPEG with an EXIF APP1 segment holding only the Orientation tag (0x0112)."""
    tiff = b"MM\x00\x2a\x00\x00\x00\x08" + struct.pack(">H", 1) + struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0) + b"\x00" * 4
    app1 = b"Exif\x00\x00" + tiff
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpeg[2:]


def test_fixture_photos_answered_as_the_library_answers(tmp_path, capsys):
    out_json = tmp_path / "d.json"
    rc, out, _ = run(capsys, str(FIX), "--json", str(out_json))
    assert rc == 0
    doc = json.loads(out_json.read_text())
    assert doc["interrupted"] is False
    rows = {Path(r["file"]).name: r for r in doc["images"]}
    assert set(rows) == set(TRUTH)  # the directory's images, not truth.json
    for name, t in TRUTH.items():
        r = rows[name]
        assert r["error"] is None and r["reason"] is None
        img = cv2.imread(str(FIX / name))
        assert (r["width"], r["height"]) == (img.shape[1], img.shape[0])
        assert np.allclose(r["pixel"], detect_centre(img).pixel), name  # the library's answer on cv2.imread's image
        assert np.hypot(*(np.array(r["pixel"]) - t["centre"])) < 0.4 * t["plant_size_px"], name
        assert name in out and "centre (" in out
    assert "5 image(s): 5 centre(s) found" in out


def test_unreadable_files_are_reported_and_the_rest_still_answered(tmp_path, capsys):
    (tmp_path / "notes.jpg").write_text("not a photo")
    (tmp_path / "empty.png").write_bytes(b"")
    shutil.copy(FIX / "seedling.jpg", tmp_path / "seedling.jpg")
    empty_dir = tmp_path / "nothing"
    empty_dir.mkdir()
    out_json = tmp_path / "d.json"
    rc, out, _ = run(capsys, str(tmp_path / "notes.jpg"), str(tmp_path / "missing.jpg"), str(empty_dir),
                     str(tmp_path / "empty.png"), str(tmp_path / "seedling.jpg"), "--json", str(out_json))
    assert rc == 2
    rows = json.loads(out_json.read_text())["images"]
    assert [r["error"] is not None for r in rows] == [True, True, True, True, False]
    assert "not an image" in rows[0]["error"] and "no such file" in rows[1]["error"]
    assert "no image files" in rows[2]["error"] and "empty file" in rows[3]["error"]
    assert rows[4]["reason"] is None and rows[4]["pixel"] is not None
    assert out.count("error:") == 4 and "1 centre(s) found, 0 without an answer, 4 with an error" in out


def _png_header(w: int, h: int, rows: int = 8) -> bytes:
    """A PNG declaring w × h RGB px whose data holds `rows` rows of zeros: a few kB."""
    import zlib

    def chunk(t: bytes, d: bytes) -> bytes:
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))

    idat = zlib.compress(b"\x00" * (1 + 3 * w) * rows)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)) + chunk(b"IDAT", idat)
            + chunk(b"IEND", b""))


@pytest.mark.parametrize("w, h, pillow_limit", [(20_000, 20_000, True), (15_000, 14_000, False)])
def test_an_image_declaring_too_many_pixels_is_refused_from_its_header(tmp_path, capsys, monkeypatch, w, h, pillow_limit):
    """A PNG of a few kB declaring 20 000 × 20 000 px took 2.5 GB in OpenCV before the detector
    said bad_image; now its header refuses it: past Pillow's own bomb limit (~179 Mpx) by that
    error's pixel count, and with the limit switched off (another library may) by the size read."""
    from PIL import Image

    if not pillow_limit:
        monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", None)
    (tmp_path / "bomb.png").write_bytes(_png_header(w, h))
    rc, out, _ = run(capsys, str(tmp_path / "bomb.png"))
    assert rc == 2 and "over the 200 Mpx a frame or photo can be" in out, out
    with pytest.raises(ValueError, match="Mpx a frame or photo"):
        detect_cli.read_image(tmp_path / "bomb.png")
    (tmp_path / "under.png").write_bytes(_png_header(12_000, 12_000))  # 144 Mpx: past the header, OpenCV's to judge
    with pytest.raises(ValueError, match="not an image OpenCV can decode"):
        detect_cli.read_image(tmp_path / "under.png")
    (tmp_path / "ok.png").write_bytes(_png_header(640, 480, rows=480))  # a whole small one still reads
    assert detect_cli.read_image(tmp_path / "ok.png").shape == (480, 640, 3)


def test_exif_orientation_is_applied_as_the_photo_is_shown(tmp_path, capsys):
    img = cv2.imread(str(FIX / "grass_tuft.jpg"))
    ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 100])
    assert ok
    shown = cv2.imdecode(jpg, cv2.IMREAD_COLOR)  # the same pixels, before turning
    p = tmp_path / "turned.jpg"
    p.write_bytes(with_exif_orientation(jpg.tobytes(), 6))  # 6: shown turned 90° clockwise
    out_json = tmp_path / "d.json"
    assert run(capsys, str(p), "--json", str(out_json))[0] == 0
    r = json.loads(out_json.read_text())["images"][0]
    assert (r["width"], r["height"]) == (img.shape[0], img.shape[1])
    want = detect_centre(cv2.rotate(shown, cv2.ROTATE_90_CLOCKWISE)).pixel
    assert want is not None and np.allclose(r["pixel"], want)


@pytest.mark.parametrize("kind", ["grey", "16-bit", "alpha"])
def test_grey_16_bit_and_alpha_files_are_read(tmp_path, capsys, kind):
    img = cv2.imread(str(FIX / "rosette_vga.jpg"))
    if kind == "grey":
        data = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif kind == "16-bit":
        data = img.astype(np.uint16) * 257
    else:
        data = cv2.cvtColor(img, cv2.COLOR_BGR2BGRA)
    p = tmp_path / f"{kind}.png"
    cv2.imwrite(str(p), data)
    out_json = tmp_path / "d.json"
    assert run(capsys, str(p), "--json", str(out_json))[0] == 0
    r = json.loads(out_json.read_text())["images"][0]
    assert r["error"] is None and (r["width"], r["height"]) == (640, 480)
    if kind != "grey":  # colour kept: the same answer as the 8-bit BGR file
        assert r["reason"] is None
        assert np.allclose(r["pixel"], detect_centre(img).pixel, atol=1e-6)
    else:  # no colour, no vegetation index: an answer without a reason, never an error
        assert r["reason"] in ("no_plant", "bad_image")


def _two_tufts(tmp_path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """The grass tuft beside its mirror image: two plants, 480 px apart."""
    img = cv2.imread(str(FIX / "grass_tuft.jpg"))
    both = np.hstack([img, img[:, ::-1]])
    p = tmp_path / "two.png"
    cv2.imwrite(str(p), both)
    left = np.array(TRUTH["grass_tuft.jpg"]["centre"])
    right = np.array([2 * img.shape[1] - 1 - left[0], left[1]])
    return p, left, right


@pytest.mark.parametrize("side", ["left", "right"])
def test_roi_circle_and_ellipse_restrict_the_search(tmp_path, capsys, side):
    p, left, right = _two_tufts(tmp_path)
    want, other = (left, right) if side == "left" else (right, left)
    for roi in (f"{want[0]:.1f},{want[1]:.1f},90", f"{want[0]:.1f},{want[1]:.1f},200,150,20"):
        out_json = tmp_path / "d.json"
        assert run(capsys, str(p), "--roi", roi, "--json", str(out_json))[0] == 0
        doc = json.loads(out_json.read_text())
        px = np.array(doc["images"][0]["pixel"])
        assert doc["roi"] == roi
        assert np.linalg.norm(px - want) < 30 and np.linalg.norm(px - other) > 300


def test_roi_mask_restricts_the_search_and_must_match_the_image(tmp_path, capsys):
    p, left, right = _two_tufts(tmp_path)
    mask = np.zeros((360, 960), np.uint8)
    cv2.circle(mask, tuple(int(v) for v in right), 90, 255, -1)
    mp = tmp_path / "mask.png"
    cv2.imwrite(str(mp), mask)
    out_json = tmp_path / "d.json"
    assert run(capsys, str(p), "--roi-mask", str(mp), "--json", str(out_json))[0] == 0
    px = np.array(json.loads(out_json.read_text())["images"][0]["pixel"])
    assert np.linalg.norm(px - right) < 30
    rc, out, _ = run(capsys, str(FIX / "seedling.jpg"), "--roi-mask", str(mp))
    assert rc == 2 and "the ROI mask is 960x360, the image 240x180" in out


def test_annotated_copies_mark_the_centre_and_never_overwrite_each_other(tmp_path, capsys):
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        shutil.copy(FIX / "rosette_vga.jpg", tmp_path / d / "plant.jpg")
    ann = tmp_path / "marked" / "deeper"  # created
    out_json = tmp_path / "d.json"
    assert run(capsys, str(tmp_path / "a"), str(tmp_path / "b"), "--annotate", str(ann), "--json", str(out_json))[0] == 0
    rows = json.loads(out_json.read_text())["images"]
    assert [Path(r["annotated"]).name for r in rows] == ["plant.centre.jpg", "plant-2.centre.jpg"]
    src = cv2.imread(str(FIX / "rosette_vga.jpg")).astype(int)
    for r in rows:
        marked = cv2.imread(r["annotated"])
        assert marked.shape == src.shape
        u, v = (round(c) for c in r["pixel"])
        near = np.abs(marked[v - 8:v + 9, u - 8:u + 9].astype(int) - src[v - 8:v + 9, u - 8:u + 9]).max()
        far = np.abs(marked[-60:, -60:].astype(int) - src[-60:, -60:]).max()  # a corner away from marks and text
        assert near > 100 and far < 40  # (JPEG re-encoding moves far pixels a little)



def test_outputs_never_write_over_the_inputs(tmp_path, capsys):
    """`--json` naming one of the photos (directly, through a symlink, or found in a directory given
    as input) is refused before any work, the photo kept; `--annotate` into the photos' own
    directory never takes an input's name (`plant.centre.jpg` there is a photo, not an earlier mark)."""
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("plant.jpg", "plant.centre.jpg"):
        shutil.copy(FIX / "rosette_vga.jpg", photos / name)
    (tmp_path / "link.jpg").symlink_to(photos / "plant.jpg")
    before = (photos / "plant.jpg").read_bytes()
    for inputs, out in (([photos / "plant.jpg"], photos / "plant.jpg"), ([photos / "plant.jpg"], tmp_path / "link.jpg"),
                        ([photos], photos / "plant.centre.jpg"), ([FIX / "seedling.jpg", "--roi-mask", photos / "plant.jpg"],
                                                                  photos / "plant.jpg")):
        rc, out_text, err = run(capsys, *map(str, inputs), "--json", str(out))
        assert rc == 2 and "an input of this command; name another file" in err and out_text == "", err
    assert (photos / "plant.jpg").read_bytes() == before
    out_json = tmp_path / "d.json"
    assert run(capsys, str(photos), "--annotate", str(photos), "--json", str(out_json))[0] == 0
    rows = json.loads(out_json.read_text())["images"]
    assert sorted(Path(r["annotated"]).name for r in rows) == ["plant-2.centre.jpg", "plant.centre.centre.jpg"]
    assert (photos / "plant.centre.jpg").read_bytes() == (FIX / "rosette_vga.jpg").read_bytes()

@pytest.mark.parametrize("args, expect", [
    (["--roi", "1,2"], "give U,V,R (a circle) or U,V,W,H,ANGLE"),
    (["--roi", "10,10,0"], "the radius must be at least 1 px"),
    (["--roi", "120,90,1e-300"], "the radius must be at least 1 px"),  # was a ZeroDivisionError traceback
    (["--roi", "nan,1,2"], "must be finite"),
    (["--roi", "1e30,1,2"], "must be finite and within"),
    (["--roi", "a,b,c"], "not a list of numbers"),
    (["--roi", "1,1,5,0,0"], "width and height must be at least 2 px"),
    (["--roi", "120,90,1e-300,40,0"], "width and height must be at least 2 px"),
    (["--roi", "1,1,1", "--roi-mask", "m.png"], "not both"),
    (["--roi-mask", "/nonexistent/m.png"], "--roi-mask /nonexistent/m.png: cannot read it"),
    (["--json", "/nonexistent/d.json"], "directory /nonexistent does not exist"),
])
def test_bad_options_are_one_line_and_exit_2(tmp_path, capsys, args, expect):
    rc, out, err = run(capsys, str(FIX / "seedling.jpg"), *args)
    assert rc == 2 and expect in err and len(err.strip().splitlines()) == 1 and out == ""


def test_a_fifo_is_refused_not_read_forever(tmp_path, capsys):
    fifo = tmp_path / "camera.jpg"
    os.mkfifo(fifo)
    rc, out, _ = run(capsys, str(fifo))
    assert rc == 2 and "not a regular file" in out
    rc, _, err = run(capsys, str(FIX / "seedling.jpg"), "--roi-mask", str(fifo))
    assert rc == 2 and "not a regular file" in err


def test_annotate_onto_a_file_is_refused_before_any_work(tmp_path, capsys):
    f = tmp_path / "f"
    f.write_text("x")
    rc, out, err = run(capsys, str(FIX / "seedling.jpg"), "--annotate", str(f))
    assert rc == 2 and "is a file, not a directory" in err and out == ""


def test_interrupted_batch_keeps_what_was_done(tmp_path, capsys, monkeypatch):
    calls = []
    real = detect_cli.detect_centre

    def second_call_interrupted(img, roi):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(img, roi)

    monkeypatch.setattr(detect_cli, "detect_centre", second_call_interrupted)
    out_json = tmp_path / "d.json"
    rc, out, err = run(capsys, str(FIX), "--json", str(out_json))
    assert rc == 130 and "interrupted" in err
    doc = json.loads(out_json.read_text())
    assert doc["interrupted"] is True and len(doc["images"]) == 1 and doc["images"][0]["pixel"] is not None
