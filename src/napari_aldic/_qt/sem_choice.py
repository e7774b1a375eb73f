"""What the dock's "SEM corrections (HRDIC)" section chooses (no Qt: the dock's
model imports it; the section itself is :mod:`.sem`; issue 27, docs/sem.md).

:class:`SEMChoice` (no Qt) is what the section says: a distortion and a drift
calibration file (each kept with the SHA-256 of its bytes, so a project opened
later finds out when a file was replaced), the scan start times of the pair
for the drift, and whether scan-line shifts are removed. It lives in the dock's
model (``DockModel.sem``): the Run reads it (``correlate_sem`` instead of
``correlate``), a project file keeps it. :class:`SEMPanel` shows and edits it;
a file is read with the engine's reader when it is chosen, so a bad one is
refused at once with one line naming it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from ..engine.io import file_sha256
from ..engine.sem import load_distortion, load_drift
from ..i18n import tr

__all__ = ["SEMChoice", "parse_times"]

_KINDS = ("distortion", "drift")


def parse_times(text: str) -> tuple[float, float] | None:
    """``"t_ref, t_def"`` (seconds) as two numbers; ``None`` when empty."""
    parts = [p for p in text.replace(",", " ").split() if p]
    if not parts:
        return None
    try:
        times = tuple(float(p) for p in parts)
    except ValueError:
        times = ()
    if len(times) != 2:
        raise ValueError(tr("scan start times {text!r}: give two numbers in seconds, the "
                            "reference's and the deformed image's").format(text=text))
    return times


def _load(kind: str, path: str):
    return (load_distortion if kind == "distortion" else load_drift)(path)


@dataclass(frozen=True)
class SEMChoice:
    """The SEM corrections chosen for one analysis (paths as given, with hashes)."""

    distortion: str | None = None
    distortion_sha256: str | None = None
    drift: str | None = None
    drift_sha256: str | None = None
    start_times: tuple[float, float] | None = None
    scan_lines: bool = False

    @property
    def active(self) -> bool:
        return bool(self.distortion or self.drift or self.scan_lines)

    def choose(self, kind: str, path) -> SEMChoice:
        """This choice with the ``kind`` ("distortion", "drift") file ``path``
        (``None``/empty: none), read and hashed now; ``ValueError`` naming the
        file when it is no such calibration."""
        if not path or str(path) in ("", "."):
            return replace(self, **{kind: None, f"{kind}_sha256": None})
        path = str(Path(path).expanduser())
        try:
            _load(kind, path)
            digest = file_sha256(path, f"{kind} calibration")
        except (OSError, ValueError) as exc:
            raise ValueError(" ".join(str(exc).split())) from None
        return replace(self, **{kind: path, f"{kind}_sha256": digest})

    def options(self) -> dict:
        """The keyword arguments of ``correlate_sem``: each file read again and
        checked against the hash taken when it was chosen."""
        out: dict = {"scan_lines": bool(self.scan_lines)}
        for kind in _KINDS:
            path = getattr(self, kind)
            if not path:
                continue
            model = _load(kind, path)
            if file_sha256(path) != getattr(self, f"{kind}_sha256"):
                raise ValueError(tr("the {kind} file {path} changed since it was chosen: "
                                    "choose it again").format(kind=kind, path=path))
            out[kind] = model
        if self.drift:
            out["start_times"] = self.start_times
        return out

    def words(self) -> str:
        """The corrections in words ("distortion d.json, scan lines")."""
        parts = [tr("distortion {name}").format(name=Path(self.distortion).name)] \
            if self.distortion else []
        if self.drift:
            parts.append(tr("drift {name}").format(name=Path(self.drift).name))
        if self.scan_lines:
            parts.append(tr("scan lines"))
        return ", ".join(parts)

    def to_dict(self) -> dict:
        return {"distortion": self.distortion, "distortion_sha256": self.distortion_sha256,
                "drift": self.drift, "drift_sha256": self.drift_sha256,
                "start_times": None if self.start_times is None else list(self.start_times),
                "scan_lines": bool(self.scan_lines)}

    @classmethod
    def from_dict(cls, d) -> SEMChoice | None:
        """The choice of a project's ``"sem"`` section (``None`` for none);
        ``ValueError`` when the section is damaged (files are not read here)."""
        if d is None:
            return None
        ok = isinstance(d, dict) and all(
            d.get(k) is None or isinstance(d.get(k), str)
            for k in ("distortion", "distortion_sha256", "drift", "drift_sha256"))
        times = d.get("start_times") if isinstance(d, dict) else None
        ok = ok and (times is None or (isinstance(times, list) and len(times) == 2 and all(
            isinstance(t, (int, float)) and not isinstance(t, bool) for t in times)))
        if not ok or not isinstance(d.get("scan_lines", False), bool):
            raise ValueError(tr("the project's 'sem' section is damaged"))
        return cls(d.get("distortion"), d.get("distortion_sha256"), d.get("drift"),
                   d.get("drift_sha256"), None if times is None else tuple(map(float, times)),
                   bool(d.get("scan_lines", False)))
