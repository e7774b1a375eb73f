"""``python -m napari_aldic.cli``."""

import sys

from .app import main

sys.exit(main())
