"""User text (units, file and folder names) with newlines, quotes, ``&``,
``-->`` or ``$...$`` does not break CSV headers, VTU/PVD XML or the PDF report
(issue 11, section 3): the written files are parsed back (csv module,
xml.etree) and the report is rendered."""

from __future__ import annotations

import re

import numpy as np
import pytest

from napari_aldic.engine import correlate, synthetic as S


@pytest.fixture(scope="module")
def result():
    ref, dfm = S.speckle_pair((128, 128), S.Translation(0.4, -0.2), seed=1)
    return correlate(ref, dfm, subset=31, step=8)


#: a unit and a time unit that would break a naive CSV header, XML or mathtext
NASTY_UNIT = 'µm "q", a&b\n--> $\\frac{x}$'
NASTY_TIME = "s$^$ <&>\n--"
#: a file name with XML and CSV specials
NASTY_NAME = 'run "a"&b --> $x$'


@pytest.fixture
def frames_nasty(result, tmp_path):
    """Two frames saved in a folder with a nasty name, and nasty units."""
    from dataclasses import replace

    from napari_aldic.engine import Units

    a = replace(result, meta={**result.meta, "frame": 1})
    b = replace(result, u=result.u * 2, meta={**result.meta, "frame": 2})
    folder = tmp_path / NASTY_NAME
    folder.mkdir()
    a.save(folder / "frame_00001.npz")
    b.save(folder / "frame_00002.npz")
    units = Units(pixel_size=0.5, unit=NASTY_UNIT, frame_interval=2.0, time_unit=NASTY_TIME)
    return folder, units


def test_user_text_does_not_break_the_csv(frames_nasty, result, tmp_path):
    import csv

    from napari_aldic.engine.io import export_csv, read_csv

    folder, units = frames_nasty
    path = export_csv(folder, tmp_path / f"{NASTY_NAME}.csv", units=units, strain=False)
    with open(path, encoding="utf-8", newline="") as fh:
        body = [line for line in fh if not line.startswith("#")]
    rows = list(csv.reader(body))
    header = rows[0]
    assert len(rows) == 1 + 2 * len(result)
    assert all(len(r) == len(header) for r in rows)
    assert "u [" + " ".join(NASTY_UNIT.split()) + "]" in header
    back = read_csv(path)
    assert back["units"]["u"] == NASTY_UNIT  # exact, from the JSON header line
    assert back["settings"] == units
    u = back["columns"]["u"].reshape(2, -1)
    ok = result.valid
    assert np.allclose(u[0][ok], 0.5 * result.u[ok]) and np.allclose(u[1][ok], result.u[ok])


def test_user_text_does_not_break_vtu_and_pvd(frames_nasty, tmp_path):
    import xml.etree.ElementTree as ET

    from napari_aldic.engine.io import export_vtu, read_vtu

    folder, units = frames_nasty
    written = export_vtu(folder, tmp_path / f"{NASTY_NAME}.vtu", units=units, strain=False)
    assert len(written) == 3 and written[-1].suffix == ".pvd"
    for path in written:
        ET.parse(path)  # well-formed XML, comments included
    sets = ET.parse(written[-1]).getroot().findall("Collection/DataSet")
    assert [d.get("file") for d in sets] == [p.name for p in written[:2]]
    assert all((tmp_path / d.get("file")).exists() for d in sets)
    back = read_vtu(written[1])
    assert np.array_equal(back["field_data"]["frame"], [2])


def test_user_text_does_not_break_the_pdf_report(frames_nasty, tmp_path):
    from napari_aldic.engine import export_report
    from napari_aldic.engine.viz import report_page_count

    folder, units = frames_nasty
    path = export_report(folder, tmp_path / f"{NASTY_NAME}.pdf", units=units,
                         title=NASTY_UNIT)
    data = path.read_bytes()
    assert data.startswith(b"%PDF")
    assert len(re.findall(rb"/Type\s*/Page\b", data)) == report_page_count(2, n_total=2)
