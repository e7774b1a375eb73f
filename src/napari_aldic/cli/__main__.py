"""``python -m napari_aldic.cli``."""

from . import console_main

console_main()
