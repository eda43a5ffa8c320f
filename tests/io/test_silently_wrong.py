"""Issue 18, "nothing silently wrong" (engine side): inputs that used to load as a wrong head, with exit 0.

Each test loads the input as a user would (``load_ct`` with the options the CLI and the import dialog
pass) and checks what comes out: the data the right way up, a refusal naming the fix, or the warning.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from datasets import shared_data
from made_inputs import photo
from pdehead_addon import CTImportError, load_ct


def load_w(path, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ct = load_ct(path, **kw)
    return ct, [str(w.message) for w in caught]


# ------------------------------------------------------------------ 1. one default orientation for stacks
@pytest.fixture(scope="module")
def tiff8_superior():
    """CThead's 8-bit TIFFs as its README says they are: file 1 at the top of the head."""
    return load_ct(shared_data("cthead_stanford", "tiff8"), spacing=(2, 1, 1), first_slice="superior")


def test_image_stack_auto_puts_the_crown_on_top_and_says_so(tiff8_superior):
    """`pdehead.py .../tiff8 --spacing 2 1 1` (no --first-slice): the crown at the first file is detected
    and the stack flipped, said as information naming first_slice, not as a warning: the choice is right for
    a correct stack (main put the crown at the bottom, silently)."""
    ct, warns = load_w(shared_data("cthead_stanford", "tiff8"), spacing=(2, 1, 1))
    np.testing.assert_array_equal(ct.data, tiff8_superior.data)
    assert ct.meta["orientation"] == "LPI" and ct.meta["first_slice"] == "superior"
    assert ct.meta["crown"]["end"] == "high"                      # k increases superior: the crown on top
    assert not any("crown" in w for w in warns), warns
    hit = [n for n in ct.meta["info"] if "crown" in n]
    assert len(hit) == 1 and "first_slice='inferior'" in hit[0] and "cthead-8bit001.tif" in hit[0], ct.meta
    # the top slices are air above the vertex, the bottom ones the jaw: cross-sections grow downward
    top, bottom = ct.data[-3:].mean(), ct.data[:3].mean()
    assert bottom > 3 * top, (top, bottom)


def test_explicit_first_slice_wins_and_is_questioned(tiff8_superior):
    ct, warns = load_w(shared_data("cthead_stanford", "tiff8"), spacing=(2, 1, 1), first_slice="inferior")
    np.testing.assert_array_equal(ct.data, tiff8_superior.data[::-1])      # not flipped
    assert ct.meta["orientation"] == "LPS"
    assert any("may be upside down" in w and "first_slice='inferior'" in w for w in warns), warns
    ct, warns = load_w(shared_data("cthead_stanford", "tiff8"), spacing=(2, 1, 1), orientation="LPI")
    np.testing.assert_array_equal(ct.data, tiff8_superior.data)
    assert not any("crown" in w for w in warns), warns
    # "auto" is the same as not saying
    ct, _ = load_w(shared_data("cthead_stanford", "tiff8"), spacing=(2, 1, 1), first_slice="auto")
    np.testing.assert_array_equal(ct.data, tiff8_superior.data)


def test_raw_auto_is_the_same_rule_as_images(cthead_ct):
    """Raw slices without first_slice: the same Auto rule (the dialog used to send 'superior' for raw only)."""
    ct, warns = load_w(shared_data("cthead_stanford", "raw16"), format="raw", shape=(256, 256), dtype=">i2",
                       spacing=(2, 1, 1))
    np.testing.assert_array_equal(ct.data, cthead_ct.data)                 # = first_slice="superior"
    assert not any("crown" in w for w in warns), warns                    # a correct stack: no warning
    assert any("crown" in n and "first_slice='inferior'" in n for n in ct.meta["info"]), ct.meta


def test_stack_with_the_crown_last_is_not_flipped(tmp_path):
    """The phantom written crown-last (inferior first, the default): nothing flipped, nothing said."""
    from pdehead_addon import make_phantom
    ph = make_phantom(noise=0.0)
    path = tmp_path / "ph.raw"
    np.rint(ph.ct.data).astype(">i2").tofile(path)
    ct, warns = load_w(path, format="raw", shape=ph.ct.shape, dtype=">i2", spacing=ph.ct.spacing)
    np.testing.assert_array_equal(ct.data, np.rint(ph.ct.data))
    assert warns == [] and ct.meta["crown"]["end"] == "high"


# ------------------------------------------------------------------ 2. byte order, spacing, head height
def test_wrong_byte_order_is_refused_naming_the_right_one(tmp_path):
    """CThead's big-endian slices read as '<i2' gave -32768..32524 and a bullet "head" with exit 0."""
    folder = shared_data("cthead_stanford", "raw16")
    with pytest.raises(CTImportError, match=r"wrong byte order.*dtype='>i2' \(big-endian\)") as err:
        load_ct(folder, format="raw", shape=(256, 256), dtype="<i2", spacing=(2, 1, 1))
    assert "-32768.." in str(err.value) and "0..3272" in str(err.value)
    with pytest.raises(CTImportError, match="dtype='>i2'"):             # the dialog's way: byte_order
        load_ct(folder, format="raw", shape=(256, 256), dtype="i2", byte_order="little", spacing=(2, 1, 1))
    # little-endian data read as little-endian loads; as big-endian it is refused the other way round
    small = tmp_path / "le.raw"
    vol = np.stack([np.fromfile(folder / f"CThead.{n}", ">i2").reshape(256, 256) for n in range(40, 56)])
    vol.astype("<i2").tofile(small)
    ct = load_ct(small, shape=(256, 256), dtype="<i2", spacing=(2, 1, 1))
    assert ct.data.min() == 0 and ct.data.max() <= 3272
    with pytest.raises(CTImportError, match="dtype='<i2' \\(little-endian\\)"):
        load_ct(small, shape=(256, 256), dtype=">i2", spacing=(2, 1, 1))


def test_image_stack_without_spacing_says_1mm_and_not_a_human_head():
    ct, warns = load_w(shared_data("cthead_stanford", "tiff8"))
    assert ct.spacing == (1.0, 1.0, 1.0)
    assert any("no spacing given: assumed (dz, dy, dx) = (1, 1, 1) mm" in w for w in warns), warns
    hit = [w for w in warns if "not a human head" in w]
    assert len(hit) == 1 and "slice step of 1 mm" in hit[0] and "spacing=(dz, dy, dx)" in hit[0], warns
    height = ct.meta["crown"]["vertex_to_widest_mm"]
    assert 30 < height < 60
    ct, warns = load_w(shared_data("cthead_stanford", "tiff8"), spacing=(2, 1, 1))
    assert not any("not a human head" in w for w in warns) and ct.meta["crown"]["vertex_to_widest_mm"] > 70


def test_partial_scan_without_crown_is_allowed(tmp_path):
    """Files 40-99 of CThead (no crown in the scan) at a wrong 1 mm step: no crown, no height verdict."""
    folder = tmp_path / "partial"
    folder.mkdir()
    for n in range(40, 100):
        (folder / f"cthead-8bit{n:03d}.tif").symlink_to(shared_data("cthead_stanford", "tiff8") /
                                                        f"cthead-8bit{n:03d}.tif")
    ct, warns = load_w(folder, spacing=(1, 1, 1))
    assert ct.meta["crown"]["end"] == "unknown" and ct.meta["crown"]["vertex_to_widest_mm"] is None
    assert not any("not a human head" in w or "crown" in w for w in warns), warns
    assert ct.meta["orientation"] == "LPS"                     # the documented default: first file inferior


# ------------------------------------------------------------------ 3. photographs are not a head CT
def test_folder_of_photos_is_refused_with_what_was_seen(tmp_path):
    from PIL import Image
    rng = np.random.default_rng(18)
    folder = tmp_path / "holiday"
    folder.mkdir()
    for k in range(20):
        Image.fromarray(photo(rng)).save(folder / f"IMG_{k + 1:04d}.png")
    with pytest.raises(CTImportError, match="does not look like a head CT") as err:
        load_ct(folder)
    message = str(err.value)
    assert "colour images" in message and "20 image(s) of 320 x 240 pixels" in message, message
    # the same pictures in grey: no air around a head in the histogram
    grey = tmp_path / "grey"
    grey.mkdir()
    for k in range(12):
        Image.fromarray(photo(rng, block=False)).convert("L").save(grey / f"scan{k + 1}.png")
    with pytest.raises(CTImportError, match="does not look like a head CT.*no air/soft-tissue histogram"):
        load_ct(grey, spacing=(1, 1, 1))


def test_grey_ct_saved_as_colour_png_still_loads(tmp_path):
    """A CT exported as RGB PNGs (equal channels) is not a photo."""
    from PIL import Image

    from pdehead_addon import make_phantom
    ph = make_phantom(noise=0.0)
    grey = np.clip((ph.ct.data + 1000.0) / 8.0, 0, 255).astype(np.uint8)
    folder = tmp_path / "rgb"
    folder.mkdir()
    for k, image in enumerate(grey):
        Image.fromarray(np.repeat(image[..., None], 3, axis=-1)).save(folder / f"s{k + 1:03d}.png")
    ct, warns = load_w(folder, spacing=ph.ct.spacing)
    np.testing.assert_allclose(ct.data, grey.astype(np.float32), atol=1.0)
    assert any("colour images converted to grey" in w for w in warns)


# ------------------------------------------------------------------ 4. messages in the words of where they are shown
def test_engine_messages_become_flags_or_dialog_fields():
    from pdehead_addon.core.wording import for_cli, for_dialog
    crown = "read with the first file superior; pass first_slice='inferior' if the first file is the bottom"
    assert for_cli(crown).endswith("; pass --first-slice inferior if the first file is the bottom")
    assert for_dialog(crown).endswith("; set 'First Slice' Inferior if the first file is the bottom")
    face = "if the first rows hold the back of the head pass orientation='LAI'"
    assert for_cli(face).endswith("pass --orientation LAI") and for_dialog(face).endswith("set 'Orientation' LAI")
    raw = "for headerless raw slices pass format='raw', shape=(ny, nx) and a dtype such as dtype='>i2'"
    assert for_cli(raw).endswith("pass --format raw, --raw-shape NY NX and a dtype such as --dtype '>i2'")
    assert "'Byte Order' Big Endian" in for_dialog(raw) and "'Slice Shape'" in for_dialog(raw)
    # float32 noise rounded; a DICOM UID and a version string untouched; one line
    text = for_cli("spacing=(2.0, 0.05000000074505806, 1.0) ignored for\nuid 1.2.840.10008.5.1.4.1.1.2 v2.38.1")
    assert text == "--spacing 2 0.05 1 ignored for uid 1.2.840.10008.5.1.4.1.1.2 v2.38.1"


def test_byte_order_error_in_cli_and_dialog_words(tmp_path):
    from pdehead_addon.core.wording import for_cli, for_dialog
    with pytest.raises(CTImportError) as err:
        load_ct(shared_data("cthead_stanford", "raw16"), format="raw", shape=(256, 256), dtype="<i2",
                spacing=(2, 1, 1))
    assert "pass --dtype '>i2'" in for_cli(str(err.value)) and "dtype=" not in for_cli(str(err.value))
    assert "set 'Data Type' int16 with 'Byte Order' Big Endian" in for_dialog(str(err.value))
