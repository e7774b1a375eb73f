"""Frames too large for an in-memory analysis: the input check warns before
the run and points to the block-by-block command line (issue 13: napari
must not freeze or run out of memory on an HRDIC mosaic without a word)."""

from types import SimpleNamespace

from napari_aldic._qt.checks import IN_MEMORY_BYTES_PER_PIXEL, Choices, problems


def _choices(rows: int, cols: int) -> Choices:
    img = SimpleNamespace(rgb=False, name="mosaic")
    return Choices(image=img, shape=(2, rows, cols), subset=31, step=8, window=5,
                   start=0, stop=1, stride=1, init="fft", reference="accumulative")


def test_mosaic_frames_warn_and_name_the_tiled_command():
    errors, warnings = problems(_choices(12_000, 9_000))
    assert errors == []  # a warning only: the machine may have the memory
    (text,) = [w for w in warnings if "block by block" in w]
    assert "napari-aldic run" in text and "9000 x 12000 px" in text
    assert f"{12_000 * 9_000 * IN_MEMORY_BYTES_PER_PIXEL / 1e9:.0f} GB" in text


def test_ordinary_frames_do_not_warn():
    errors, warnings = problems(_choices(4096, 4096))
    assert errors == [] and not any("block by block" in w for w in warnings)
