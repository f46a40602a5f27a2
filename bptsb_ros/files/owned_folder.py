"""A folder a program owns because it made it: a manifest inside lists what it wrote; nothing else is touched.

``bptsb report`` copies figures into ``<page stem>_figures/``. That folder is marked with
:data:`MANIFEST` (JSON: the files and folders the report wrote there, as POSIX paths relative to the folder).
:meth:`OwnedFolder.open` refuses an existing folder without the manifest (somebody else's); a rerun replaces
only the files the manifest lists and removes those it no longer needs; a file somebody added keeps its
place, and if the report would have to write over it, :meth:`OwnedFolder.write` refuses, naming it, before
anything is touched. Symbolic links inside the folder are never followed: a path through one is refused.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from bptsb_ros.files.safe_write import atomic_writer, write_atomic

MANIFEST = ".bptsb-report-manifest.json"
WRITTEN_BY = "bptsb report"
_MAX_MANIFEST_BYTES = 10_000_000


class OwnedFolderError(RuntimeError):
    """The folder is not ours to write, or a path in it is not; the message (one line) names it."""


@dataclass
class OwnedFolder:
    """``root``: the folder; ``files``/``dirs``: what an earlier run wrote there (relative POSIX paths)."""

    root: Path
    files: set[str] = field(default_factory=set)
    dirs: set[str] = field(default_factory=set)

    @classmethod
    def open(cls, root: str | Path) -> OwnedFolder:
        """The folder ``root`` if it is absent or was made by this program (its manifest is there and valid)."""
        root = Path(root)
        if root.is_symlink():
            raise OwnedFolderError(f"{root} is a symbolic link; bptsb report writes only into a folder it made")
        if not root.exists():
            return cls(root)
        manifest = root / MANIFEST
        if not root.is_dir():
            raise OwnedFolderError(f"{root} exists and is not a folder; move it away or choose another --out")
        if manifest.is_symlink() or not manifest.is_file():
            raise OwnedFolderError(f"{root} exists and was not made by bptsb report (no {MANIFEST} in it); "
                                   "move it away or choose another --out")
        try:
            if manifest.stat().st_size > _MAX_MANIFEST_BYTES:
                raise ValueError("too large")
            data = json.loads(manifest.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as err:
            raise OwnedFolderError(f"{manifest}: unreadable ({err}); not touching {root}") from None
        if (not isinstance(data, dict) or data.get("written_by") != WRITTEN_BY
                or not all(isinstance(data.get(k), list) for k in ("files", "dirs"))):
            raise OwnedFolderError(f"{manifest}: not a manifest of {WRITTEN_BY}; not touching {root}")
        for entry in data["files"] + data["dirs"]:
            if not _is_plain_relative(entry):
                raise OwnedFolderError(f"{manifest}: lists {entry!r:.80}, not a path inside the folder; "
                                       f"not touching {root}")
        return cls(root, set(data["files"]), set(data["dirs"]))

    def write(self, copies: dict[str, Path]) -> None:
        """Make the folder hold exactly the files it wrote before that are still wanted plus ``copies``
        (relative POSIX path → source file): first check every target (refusing, with nothing touched, a
        file the manifest does not list or a path through a symbolic link), then copy, then remove the
        earlier files no longer wanted and the folders it made that are left empty."""
        for rel in sorted(copies):
            if not _is_plain_relative(rel) or rel == MANIFEST:
                raise OwnedFolderError(f"{rel!r}: not a file name inside {self.root}")
            target = self._checked(rel)
            for parent in target.parents:
                if parent == self.root:
                    break
                if parent.exists() and not parent.is_dir():
                    raise OwnedFolderError(f"{parent} is in the way (not a folder); move it away (nothing was "
                                           "changed)")
            if (target.exists() or target.is_symlink()) and (rel not in self.files or not target.is_file()):
                raise OwnedFolderError(f"{target} was not written by bptsb report; move it away (nothing was "
                                       "changed)")
        if not copies and not self.root.exists():
            return
        made = {d for d in self.dirs if (self.root / d).is_dir()}
        for rel in copies:  # the folders this run makes, so that a later run may remove them when empty
            for parent in PurePosixPath(rel).parents:
                if str(parent) != "." and not (self.root / parent).exists():
                    made.add(str(parent))
        self.root.mkdir(parents=True, exist_ok=True)
        # the manifest first names everything this run may leave behind, so a crash leaves nothing unowned
        self._write_manifest(self.files | set(copies), made)
        for rel, src in copies.items():
            target = self.root / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            with open(src, "rb") as source, atomic_writer(target) as copy:
                shutil.copyfileobj(source, copy)
            shutil.copystat(src, target)
        for rel in sorted(self.files - set(copies)):
            target = self._checked(rel, refuse=False)
            if target is not None and target.is_file() and not target.is_symlink():
                target.unlink()
        for rel in sorted(made, key=lambda d: -len(PurePosixPath(d).parts)):  # deepest first
            path = self._checked(rel, refuse=False)
            if path is not None and path.is_dir() and not any(path.iterdir()):
                path.rmdir()
        made = {d for d in made if (self.root / d).is_dir()}
        self.files, self.dirs = set(copies), made
        if copies or made:
            self._write_manifest(self.files, self.dirs)
            return
        (self.root / MANIFEST).unlink()
        if not any(self.root.iterdir()):
            self.root.rmdir()

    def _checked(self, rel: str, *, refuse: bool = True) -> Path | None:
        """``root/rel`` if no part of it below ``root`` is a symbolic link; else refuse (or None)."""
        path = self.root
        for part in PurePosixPath(rel).parts:
            path = path / part
            if path.is_symlink():
                if refuse:
                    raise OwnedFolderError(f"{path} is a symbolic link; bptsb report does not write through it "
                                           "(nothing was changed)")
                return None
        return path

    def _write_manifest(self, files: set[str], dirs: set[str]) -> None:
        data = {"written_by": WRITTEN_BY, "note": "bptsb report replaces or removes only the files listed here",
                "files": sorted(files), "dirs": sorted(dirs)}
        write_atomic(self.root / MANIFEST, json.dumps(data, indent=1))


def _is_plain_relative(entry: object) -> bool:
    """A non-empty relative POSIX path with no ``..``, ``.`` or empty part (and no backslash or NUL)."""
    if not isinstance(entry, str) or not entry or "\\" in entry or "\x00" in entry or entry.startswith("/"):
        return False
    parts = entry.split("/")
    return all(p not in ("", ".", "..") for p in parts)
