"""Layout of every report page and figure, checked mechanically: every text that
matplotlib draws is recorded with its box on the page; no two texts overlap, no
text covers another plot (a colour bar over a title), no table text leaves its
cell, nothing leaves the page, legend colours are distinct, maps fill the page.
The PDF itself is rendered to PNG (pypdfium2) page by page."""

from __future__ import annotations

import contextlib
import itertools

import numpy as np
import pytest

from napari_aldic.engine import DICResult, Reason, Units, synthetic as S, track
from napari_aldic.engine.viz import (
    displacement_figure,
    export_report,
    field_figure,
    report_page_count,
)
from napari_aldic.engine.viz.report import report_pages
from napari_aldic.engine.viz.style import REASON_COLOURS

MM = Units(pixel_size=0.05, unit="mm", frame_interval=0.5, time_unit="s")


# ------------------------------------------------------------------ the checker
@contextlib.contextmanager
def _recording(fig, out):
    """Record ``(text, box)`` of every non-empty text of ``fig`` that is drawn."""
    from matplotlib.text import Text

    draw = Text.draw

    def recorded(self, renderer):
        draw(self, renderer)
        if self.get_figure(root=True) is fig and self.get_visible() and self.get_text().strip():
            out.append((self, self.get_window_extent(renderer)))

    Text.draw = recorded
    try:
        yield out
    finally:
        Text.draw = draw


def _overlap(a, b, tol):
    return min(a.x1, b.x1) - max(a.x0, b.x0) > tol and min(a.y1, b.y1) - max(a.y0, b.y0) > tol


def layout_problems(fig, tol: float = 1.0) -> list[str]:
    """Every layout defect of ``fig`` drawn at 100 dpi (boxes in pixels)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.table import Table

    canvas = FigureCanvasAgg(fig)
    fig.set_dpi(100)
    texts = []
    with _recording(fig, texts):
        canvas.draw()
    renderer = canvas.get_renderer()
    assert len(texts) > 5, "nothing recorded: the checker is broken"
    W, H = fig.bbox.width, fig.bbox.height
    boxes = [(ax, ax.bbox, f"axes {ax.get_label()!r}") for ax in fig.get_axes()
             if ax.get_visible() and ax.axison]
    cell_of = {}
    for table in fig.findobj(Table):
        for key, cell in table.get_celld().items():
            box = cell.get_window_extent(renderer)
            boxes.append((table, box, f"table cell {key}"))
            cell_of[id(cell.get_text())] = (table, box)
    problems = []
    for text, b in texts:
        name = text.get_text()
        if b.x0 < -tol or b.y0 < -tol or b.x1 > W + tol or b.y1 > H + tol:
            problems.append(f"outside the page: {name!r}")
        own = cell_of.get(id(text))
        if own is not None and not (b.x0 >= own[1].x0 - tol and b.x1 <= own[1].x1 + tol
                                    and b.y0 >= own[1].y0 - tol and b.y1 <= own[1].y1 + tol):
            problems.append(f"text leaves its table cell: {name!r}")
        for owner, box, what in boxes:
            if owner is text.axes or (own is not None and owner is own[0]):
                continue
            if _overlap(b, box, tol):
                problems.append(f"text {name!r} covers {what}")
    for (t1, b1), (t2, b2) in itertools.combinations(texts, 2):
        if _overlap(b1, b2, tol):
            problems.append(f"texts overlap: {t1.get_text()!r} and {t2.get_text()!r}")
    return problems


def legend_colours(fig) -> list[list[tuple]]:
    """The colours of the entries of every legend of ``fig``."""
    from matplotlib.colors import to_rgba
    from matplotlib.legend import Legend

    out = []
    for legend in fig.findobj(Legend):
        cols = []
        for h in legend.legend_handles:
            c = h.get_facecolor() if hasattr(h, "get_facecolor") and not hasattr(
                h, "get_markerfacecolor") else h.get_color()
            cols.append(tuple(np.round(to_rgba(c), 3)))
        out.append(cols)
    return out


def map_area(fig) -> float:
    """Fraction of the page covered by the data area of its maps (colour bars not
    counted)."""
    total = 0.0
    for ax in fig.get_axes():
        if ax.get_label() != "<colorbar>" and ax.axison and (ax.images or ax.collections):
            pos = ax.get_position()
            total += pos.width * pos.height
    return total


def test_the_checker_finds_each_kind_of_defect():
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 3))
    ax = fig.add_axes((0.1, 0.1, 0.5, 0.5))
    ax.set_title("a title that is wide")
    fig.add_axes((0.3, 0.55, 0.3, 0.3))  # covers the title
    fig.text(0.12, 0.2, "first")
    fig.text(0.13, 0.2, "second")  # on top of "first"
    fig.text(0.95, 0.5, "off the edge")
    tab = fig.add_axes((0.65, 0.1, 0.3, 0.3))
    tab.axis("off")
    table = tab.table(cellText=[["a text far too long for its cell"]], colWidths=[0.3],
                      loc="center")
    table.auto_set_font_size(False)
    table.set_fontsize(10)
    found = "\n".join(layout_problems(fig))
    for what in ("covers axes", "texts overlap: 'first' and 'second'",
                 "outside the page: 'off the edge'", "leaves its table cell"):
        assert what in found, what


# ------------------------------------------------------------------ data
def _flagged(res: DICResult, seed: int = 0) -> DICResult:
    """A copy of ``res`` with every reason code on a few nodes (best attempt kept)."""
    out = DICResult(**{**res.__dict__})
    out.reason, out.valid = res.reason.copy(), res.valid.copy()
    out.meta = dict(res.meta)
    codes = [int(r) for r in Reason if r != 0]
    rng = np.random.default_rng(seed)
    for j, i in enumerate(rng.choice(len(res), 2 * len(codes), replace=False)):
        out.reason[i] = codes[j % len(codes)]
        out.valid[i] = False
    return out


@pytest.fixture(scope="module")
def tall_pair():
    """A tall (256 x 96) pair that moves 5 px down: v is one-signed."""
    field = S.Affine.strain_rotation(exx=0.01, eyy=-0.004, center=(48, 128), t=(0.3, -5.0))
    ref, dfm = S.speckle_pair((256, 96), field, seed=3)
    return ref, dfm, field


@pytest.fixture(scope="module")
def tall_result(tall_pair):
    from napari_aldic.engine import correlate

    ref, dfm, _ = tall_pair
    res = correlate(ref, dfm, subset=21, step=8)
    res.meta["inputs"] = {"reference": "/data/tall/ref_000.tif",
                          "deformed": "/data/tall/def_001.tif", "frame": 1}
    return _flagged(res)


def _check_pages(figs, map_pages):
    for i, fig in enumerate(figs):
        problems = layout_problems(fig)
        assert not problems, f"page {i + 1}: " + "; ".join(problems[:5])
        for colours in legend_colours(fig):
            assert len(set(colours)) == len(colours), f"page {i + 1}: legend colours repeat"
        if i in map_pages:
            assert map_area(fig) > 0.28, f"page {i + 1}: maps fill {map_area(fig):.0%}"


# ------------------------------------------------------------------ report pages
@pytest.mark.slow  # ~8 s: eight pages drawn twice
def test_report_pages_of_a_sequence_are_laid_out_cleanly(export_sequence, export_stack):
    seq = [export_sequence[0], _flagged(export_sequence[1], 1), export_sequence[2],
           _flagged(export_sequence[3], 2)]
    figs = list(report_pages(seq, units=MM, line=(10, 64, 118, 64), image=export_stack[0],
                             frames=[1, 3]))
    assert len(figs) == report_page_count(2, line=True, n_total=4) == 7
    _check_pages(figs, map_pages={2, 3})
    # the mesh page shows every reason, each in its own colour
    mesh = legend_colours(figs[1])[0]
    assert len(mesh) == len(Reason) + 1  # and the profile line


def test_report_of_a_single_pair_has_no_page_against_frame(tall_result):
    figs = list(report_pages(tall_result, line=(48, 10, 48, 240)))
    assert len(figs) == report_page_count(1, line=True) == 5
    _check_pages(figs, map_pages={2})
    labels = [ax.get_xlabel() for fig in figs for ax in fig.get_axes()]
    assert "frame" not in labels and not any(t.startswith("time") for t in labels)


def test_report_without_strain_is_laid_out_cleanly(export_sequence):
    figs = list(report_pages(export_sequence, strain=False, frames=[2]))
    assert len(figs) == report_page_count(1, n_total=4)
    _check_pages(figs, map_pages={2})


def test_reason_colours_are_distinct():
    from matplotlib.colors import to_rgb

    assert set(REASON_COLOURS) == {int(r) for r in Reason}
    rgb = [np.array(to_rgb(c)) for c in REASON_COLOURS.values()]
    closest = min(np.linalg.norm(a - b) for a, b in itertools.combinations(rgb, 2))
    assert closest > 0.15


@pytest.mark.slow  # ~6 s
def test_pdf_pages_render(tmp_path, export_sequence, export_stack):
    import pypdfium2 as pdfium

    path = export_report(export_sequence, tmp_path / "r.pdf", units=MM, frames=[3],
                         line=(10, 64, 118, 64), image=export_stack[0])
    pdf = pdfium.PdfDocument(str(path))
    try:
        assert len(pdf) == report_page_count(1, line=True, n_total=4)
        for i in range(len(pdf)):
            img = np.asarray(pdf[i].render(scale=0.6).to_pil().convert("L"), float)
            assert img.std() > 10 and (img < 200).mean() > 0.01, f"page {i + 1} is blank"
            assert img.shape[0] > img.shape[1] * 0.6
    finally:
        pdf.close()


# ------------------------------------------------------------------ provenance
def _page_text(fig) -> str:
    return "\n".join(t.get_text() for t in fig.texts)


def test_first_page_names_the_images_and_the_choices_made(export_stack):
    seq = track(export_stack[:3], subset=21, step=12, method="aldic", reference="incremental")
    first = _page_text(next(iter(report_pages(seq, strain=False))))
    assert "incremental" in first and "accumulative" not in first
    assert "reference image: frame 0" in first
    table = next(iter(report_pages(seq, strain=False))).findobj(
        lambda a: hasattr(a, "get_celld"))[0]
    cells = {table.get_celld()[r, 0].get_text().get_text():
             table.get_celld()[r, 1].get_text().get_text()
             for r in range(1, 40) if (r, 0) in table.get_celld()}
    smooth = [seq[k].meta["regularisation"]["smooth_px"] for k in (1, 2)]
    lo, hi = min(smooth), max(smooth)
    expect = f"{lo:.2f} px" if lo == hi else f"{lo:.2f} to {hi:.2f} px"
    assert cells["smooth"] == expect  # as chosen, not "auto"
    assert cells["interpolation"] == seq[2].meta["interpolation"]


def test_a_run_folder_of_plain_files_is_still_called_incremental(tmp_path, export_stack):
    seq = track(export_stack[:3], subset=21, step=12, reference="incremental")
    for k in (1, 2):
        seq[k].meta["inputs"] = {"reference": "scan/img_0.tif",
                                 "deformed": f"scan/img_{k}.tif", "frame": k}
        seq[k].save(tmp_path / f"frame{k:03d}.npz")
    first = _page_text(next(iter(report_pages(tmp_path, strain=False))))
    assert "tracking: incremental" in first
    assert "reference image: scan/img_0.tif" in first
    assert "frame 1: scan/img_1.tif; frame 2: scan/img_2.tif" in first


# ------------------------------------------------------------------ figures
def test_displacement_figure_uses_units_and_the_data_range(tall_pair, tall_result):
    ref, _, field = tall_pair
    res = DICResult(**{**tall_result.__dict__})
    res.meta = {**tall_result.meta, "units": {"pixel_size": 0.05, "unit": "mm",
                                              "frame_interval": None, "time_unit": "s"}}
    fig = displacement_figure(res, truth=field, image=ref, title="frame 1")
    assert not layout_problems(fig)
    axes = [ax for ax in fig.get_axes() if ax.get_label() != "<colorbar>"]
    bars = [ax for ax in fig.get_axes() if ax.get_label() == "<colorbar>"]
    assert {ax.get_xlabel() for ax in axes} == {"x (mm)"}
    assert bars[0].get_ylabel() == "u (mm)" and bars[1].get_ylabel() == "v (mm)"
    assert "Local DIC" in fig.get_suptitle() and fig.get_suptitle().startswith("frame 1")
    # v is about -5 px everywhere: its colours span the data, not a symmetric +-5
    v = res.v[res.valid] * 0.05
    lo, hi = axes[1].images[-1].get_clim()
    assert lo >= v.min() - 1e-9 and hi <= v.max() + 1e-9 and hi < 0
    # u changes sign: a symmetric diverging scale
    ulo, uhi = axes[0].images[-1].get_clim()
    assert ulo == pytest.approx(-uhi)


def test_colour_bar_ticks_of_a_narrow_range_read_differently():
    # v of a nearly rigid shift: -0.0201 to -0.0199 mm (3 digits: every tick "-0.02")
    from matplotlib.figure import Figure

    from napari_aldic.engine.viz.layout import compact_ticks

    for lo, hi in ((-0.0201, -0.0199), (100.0, 100.004), (-1.2, 1.2), (0.0, 6e-5)):
        fig = Figure()
        ax = fig.add_subplot()
        ax.set_ylim(lo, hi)
        compact_ticks(ax.yaxis)
        fig.canvas.draw()
        labels = [t.get_text() for t in ax.get_yticklabels() if t.get_text()]
        assert len(labels) >= 3 and len(set(labels)) == len(labels), labels
        assert all(len(t) <= 9 for t in labels), labels


def test_field_figures_are_laid_out_cleanly(export_sequence, tall_result):
    for data, name in ((export_sequence, "exy"), (tall_result, "magnitude"),
                       (export_sequence, "zncc")):
        fig = field_figure(data, name, units=MM)
        assert not layout_problems(fig), name


def test_report_of_a_run_folder_names_the_folder_and_the_stack(export_run_folder):
    from napari_aldic.engine.io import collect_frames
    from napari_aldic.engine.viz.provenance import image_sources

    frames, _units, info = collect_frames(export_run_folder, strain=False)
    lines = image_sources(list(frames), info)
    assert any(str(export_run_folder) in ln and "run folder" in ln for ln in lines), lines
