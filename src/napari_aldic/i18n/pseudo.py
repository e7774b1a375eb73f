"""The pseudo-locale ``qps``: every translated text visibly transformed.

Letters get accents and the text is put in ``⟦ ⟧``, so that a screenshot or a test
sees at once any text that did not pass through :func:`~napari_aldic.i18n.tr`.
Placeholders (``{name}``, ``{x:.2f}``), ``%s``-style formats and HTML tags are
kept intact, so formatting still works.
"""

from __future__ import annotations

import re

__all__ = ["pseudo_translate", "OPEN", "CLOSE"]

OPEN, CLOSE = "⟦", "⟧"
_ACCENTS = str.maketrans("aeiouyAEIOUYcnCNsz", "àéîöûýÀÉÎÖÛÝçñÇÑšž")
#: the parts kept as they are: {placeholders}, %(name)s / %d formats, <tags>, &entities;
_KEEP = re.compile(r"(\{[^{}]*\}|%(?:\([^)]*\))?[-#0 +]*\d*(?:\.\d+)?[sdifgeEr%]|<[^<>]*>"
                   r"|&[a-z]+;)")


def pseudo_translate(message: str) -> str:
    """``'Run {n} frames'`` -> ``'⟦Rûñ {n} fràméš⟧'``."""
    if not message:
        return message
    pieces = _KEEP.split(message)
    out = [p if i % 2 else p.translate(_ACCENTS) for i, p in enumerate(pieces)]
    return OPEN + "".join(out) + CLOSE
