"""Dataset adapters: find the trials under a folder and describe them.

A :class:`Trial` is a recording file plus its dataset kind and groups; it is loaded lazily
(in the worker that runs it). :func:`discover` understands:

* a BROAD folder (``*.hdf5`` with ``trials.json`` for the groups);
* the simulated GNSS flights (``<scenario>/<scenario>.h5``, groups ``gnss`` and the scenario);
* PX4 ULog files (``*.ulg``, group ``ulog``);
* CSV recordings (``*.csv``, group ``csv``);

and a folder holding several of these (such as ``../shared/data``), one level down.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from ..types import Recording

__all__ = ["Trial", "discover"]


@dataclass(frozen=True)
class Trial:
    name: str
    dataset: str  # "broad" | "gnss" | "ulog" | "csv"
    path: str
    groups: tuple[str, ...] = ()

    @property
    def fingerprint(self) -> str:
        """Changes when the file changes (path, size, modification time)."""
        st = Path(self.path).stat()
        return f"{Path(self.path).resolve()}:{st.st_size}:{st.st_mtime_ns}"

    def load(self) -> Recording:
        from ..io import load

        return load(self.path)


def _broad(folder: Path) -> list[Trial]:
    groups: dict[str, list[str]] = {}
    tj = folder / "trials.json"
    if tj.is_file():
        try:
            groups = {k: v.get("groups", []) for k, v in json.loads(tj.read_text()).get("trials", {}).items()}
        except (ValueError, AttributeError, TypeError) as exc:  # not JSON, not UTF-8, not BROAD's layout
            raise InputError(f"{tj}: not BROAD's trials.json ({type(exc).__name__}: {exc})") from None
    return [Trial(p.stem, "broad", str(p), tuple(groups.get(p.stem, ["all_trials"]))) for p in sorted(folder.glob("*.hdf5"))]


def _gnss(folder: Path) -> list[Trial]:
    out = []
    for p in sorted(list(folder.glob("*/*.h5")) + list(folder.glob("*.h5"))):
        out.append(Trial(p.stem, "gnss", str(p), ("gnss", p.stem)))
    return out


def _files(folder: Path) -> list[Trial]:
    trials = []
    if any(folder.glob("*.hdf5")):
        trials += _broad(folder)
    trials += _gnss(folder)
    trials += [Trial(p.stem, "ulog", str(p), ("ulog",)) for p in sorted(folder.glob("*.ulg"))]
    trials += [Trial(p.stem, "csv", str(p), ("csv",)) for p in sorted(folder.glob("*.csv"))]
    return trials


def discover(data, trials: list[str] | None = None) -> list[Trial]:
    """The trials in ``data`` (a folder or a file), optionally only those named in ``trials``
    (exact names or unique prefixes)."""
    root = Path(data)
    if not root.exists():
        raise InputError(f"data folder {str(root)!r} does not exist")
    if root.is_file():
        suffix = root.suffix.lower()
        kind = {".hdf5": "broad", ".h5": "gnss", ".ulg": "ulog", ".csv": "csv"}.get(suffix)
        if kind is None:
            raise InputError(f"{root.name}: not a recording fusionkit can read")
        found = [Trial(root.stem, kind, str(root), (kind,))]
    else:
        found = _files(root)
        if not found:  # a folder of datasets
            for sub in sorted(d for d in root.iterdir() if d.is_dir()):
                found += _files(sub)
        if not found:
            raise InputError(f"no recordings (*.hdf5, */*.h5, *.ulg, *.csv) found in {str(root)!r}")
    if trials:
        picked = []
        for want in trials:
            hits = [t for t in found if t.name == want] or [t for t in found if t.name.startswith(want)]
            if len(hits) != 1:
                names = ", ".join(t.name for t in found)
                raise InputError(f"trial {want!r} matches {len(hits)} recordings; known: {names}")
            picked.append(hits[0])
        found = picked
    return found
