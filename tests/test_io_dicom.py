"""DICOM series as scanners and PACS write them: found by content, read with their geometry and
rescale, broken ones refused with one clear message."""

import re
import shutil

import numpy as np
import pytest

pytest.importorskip("pydicom")

from scanner_files import ROOT, ball_ct, write_dicom_series  # noqa: E402

from hortishape.errors import VolumeError  # noqa: E402
from hortishape.io import find_sources, read_volume  # noqa: E402


def _starts(path, text):
    return "^" + re.escape(f"{path}: ") + ".*" + re.escape(text)


def test_an_extensionless_series_reads_with_its_geometry_and_rescale(tmp_path):
    data = ball_ct(seed=1)
    # SliceThickness (the slab's width) differs from the step between slices: the positions decide
    write_dicom_series(tmp_path / "scan", data, spacing=(0.4, 0.5, 0.8), origin=(-8, 3, 100),
                       series_uid=ROOT + "2", slope=0.5, intercept=-1024, thickness=1.5)
    vol = read_volume(tmp_path / "scan")
    np.testing.assert_array_equal(vol.data, data)  # stored values times 0.5 minus 1024
    np.testing.assert_allclose(vol.spacing, [0.4, 0.5, 0.8], rtol=1e-9)
    np.testing.assert_allclose(vol.origin, [-8, 3, 100])
    np.testing.assert_array_equal(vol.direction, np.eye(3))
    assert vol.spacing_source == "DICOM PixelSpacing and ImagePositionPatient"
    # the order of the slices is their position, not their names
    reversed_names = tmp_path / "reversed"
    write_dicom_series(reversed_names, data, series_uid=ROOT + "3", names="{:08d}")
    for f in reversed_names.iterdir():
        f.rename(reversed_names / f"X{99999999 - int(f.name):08d}")
    np.testing.assert_array_equal(read_volume(reversed_names).data, data)


def test_the_same_as_simpleitk_reads_it(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    data = ball_ct(n=24, seed=2)
    write_dicom_series(tmp_path / "s", data, spacing=(0.3, 0.35, 0.6), origin=(1, 2, 3), series_uid=ROOT + "4",
                       slope=1.0, intercept=-1024)
    reader = sitk.ImageSeriesReader()
    reader.SetFileNames(sitk.ImageSeriesReader.GetGDCMSeriesFileNames(str(tmp_path / "s")))
    theirs = reader.Execute()
    ours = read_volume(tmp_path / "s")
    np.testing.assert_array_equal(ours.data, sitk.GetArrayFromImage(theirs).transpose(2, 1, 0))
    np.testing.assert_allclose(ours.spacing, theirs.GetSpacing(), rtol=1e-9)
    np.testing.assert_allclose(ours.origin, theirs.GetOrigin(), atol=1e-9)


def test_a_study_folder_of_several_series_gives_one_scan_each(tmp_path):
    study = tmp_path / "scans"
    data = [ball_ct(n=20, seed=k) for k in range(4)]
    # one series per folder, the folders named as a PACS export names them
    write_dicom_series(study / "patient" / "apple_a", data[0], series_uid=ROOT + "10", description="CT 1.0")
    write_dicom_series(study / "patient" / "apple_b", data[1], series_uid=ROOT + "11", description="CT 1.0")
    # two series whose slices share one folder: named by their SeriesDescription
    write_dicom_series(study / "mixed", data[2], series_uid=ROOT + "12", description="tray 3", names="A{:03d}")
    write_dicom_series(study / "mixed", data[3], series_uid=ROOT + "13", description="tray 4", names="B{:03d}")
    # a localizer of one slice, a DICOMDIR index and a note: not scans, and the first and last are said so
    write_dicom_series(study / "scout", data[0][:, :, :1], series_uid=ROOT + "14", description="scout")
    shutil.copy(study / "scout" / "IM0000", study / "DICOMDIR")  # read as an index by its name
    (study / "notes.txt").write_text("scanned on Monday")
    found = find_sources(study)
    assert [v.name for v in found.volumes] == ["apple_a", "apple_b", "tray_3", "tray_4"]
    assert [v.kind for v in found.volumes] == ["dicom"] * 4
    skipped = dict(found.skipped)
    assert set(skipped) == {str(study / "notes.txt"), str(study / "scout" / "IM0000")}
    assert "one slice" in skipped[str(study / "scout" / "IM0000")]
    for v, d in zip(found.volumes, data):
        np.testing.assert_array_equal(read_volume(v).data, d)
    # a folder of two series cannot be read as one volume; the message names them
    with pytest.raises(VolumeError, match=_starts(study / "mixed", "holds 2 DICOM series (tray_3, tray_4)")):
        read_volume(study / "mixed")


def test_clashing_names_get_their_folders_names(tmp_path):
    data = ball_ct(n=16)
    for k, study in enumerate(("monday", "tuesday")):
        write_dicom_series(tmp_path / study / "SE0001", data, series_uid=ROOT + f"2{k}")
    assert [v.name for v in find_sources(tmp_path).volumes] == ["monday_SE0001", "tuesday_SE0001"]


@pytest.mark.parametrize(
    "case, expected",
    [
        ("missing", "about 1 slice(s) missing: 1.6 mm between slices IM0004 and IM0006, 0.8 mm elsewhere"),
        ("tilt", "stacked 26.6 degrees off their normal (a gantry tilt)"),
        ("truncated", "slice IM0003: cannot decode its pixels"),
        ("other size", "slice IM0002 is 10 x 11 pixels, the others 12 x 12"),
        ("same place", "lie at the same place"),
    ],
)
def test_a_broken_series_is_refused_with_one_clear_message(tmp_path, case, expected):
    data = ball_ct(n=12)
    folder = tmp_path / "scan"
    if case == "missing":
        write_dicom_series(folder, data, series_uid=ROOT + "30", skip=(5,))
    elif case == "tilt":
        write_dicom_series(folder, data, series_uid=ROOT + "30", tilt_mm=0.4)
    else:
        write_dicom_series(folder, data, series_uid=ROOT + "30")
    if case == "truncated":
        raw = (folder / "IM0003").read_bytes()
        (folder / "IM0003").write_bytes(raw[:-100])
    elif case == "other size":
        write_dicom_series(tmp_path / "small", data[:10, :11, :3], series_uid=ROOT + "30")
        shutil.copy(tmp_path / "small" / "IM0002", folder / "IM0002")
    elif case == "same place":
        shutil.copy(folder / "IM0003", folder / "IM0003b")
    with pytest.raises(VolumeError, match=_starts(folder, expected)) as err:
        read_volume(folder)
    assert "\n" not in str(err.value)


def test_a_multi_frame_file_is_one_volume(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    data = np.arange(5 * 6 * 7, dtype=np.uint16).reshape(7, 6, 5)  # (z, y, x)
    image = sitk.GetImageFromArray(data)
    image.SetSpacing((0.5, 0.6, 0.7))
    image.SetOrigin((1, 2, 3))
    (tmp_path / "mf").mkdir()
    writer = sitk.ImageFileWriter()
    writer.SetImageIO("GDCMImageIO")
    writer.SetFileName(str(tmp_path / "mf" / "IMG0001"))  # all frames in one file, no extension
    writer.Execute(image)
    found = find_sources(tmp_path)
    assert [(v.name, v.kind) for v in found.volumes] == [("mf", "dicom")] and found.skipped == ()
    vol = read_volume(found.volumes[0])
    np.testing.assert_array_equal(vol.data, data.transpose(2, 1, 0))
    np.testing.assert_allclose(vol.spacing, [0.5, 0.6, 0.7])
    np.testing.assert_allclose(vol.origin, [1, 2, 3])
    np.testing.assert_array_equal(read_volume(tmp_path / "mf" / "IMG0001").data, vol.data)  # the file named


def test_one_slice_named_on_its_own_is_refused_with_what_to_pass(tmp_path):
    write_dicom_series(tmp_path / "scan", ball_ct(n=8), series_uid=ROOT + "40")
    with pytest.raises(VolumeError, match=_starts(tmp_path / "scan" / "IM0003", "pass the folder of the series")):
        read_volume(tmp_path / "scan" / "IM0003")


def test_without_pydicom_a_survey_says_what_is_missing(tmp_path, monkeypatch):
    import sys

    write_dicom_series(tmp_path / "scan", ball_ct(n=8), series_uid=ROOT + "41")
    (tmp_path / "README").write_text("no extension, not DICOM")
    monkeypatch.setitem(sys.modules, "pydicom", None)
    found = find_sources(tmp_path)
    assert found.volumes == ()
    reasons = dict(found.skipped)
    assert "needs the optional dependency pydicom" in reasons[str(tmp_path / "scan")]  # its 8 slices, in one line
    assert reasons[str(tmp_path / "README")] == "not a mesh, a volume or a DICOM file"
