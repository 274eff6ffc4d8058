"""Files stay within ComfyUI's folders: a server started with --listen must not read or write
every path it can reach. NumPy-free and torch-free, so that it is tested without ComfyUI."""

from __future__ import annotations

import hashlib
import os


def inside(base: str, given: str, what: str) -> str:
    """`given` (relative to `base`, or absolute) resolved, links followed; refused, naming both,
    unless it lies within `base`."""
    root = os.path.realpath(base)
    path = os.path.realpath(os.path.join(root, os.path.expanduser(given)))
    if os.path.commonpath([root, path]) != root:
        raise ValueError(f"matup: {what} stays within ComfyUI's folder {root}; '{given}' is outside it")
    return path


def stamp(folder: str) -> str:
    """What changes when a file of `folder` does: each file's name, size and time, hashed."""
    digest = hashlib.sha256()
    for entry in sorted(os.scandir(folder), key=lambda e: e.name):
        if entry.is_file():
            info = entry.stat()
            digest.update(f"{entry.name}\0{info.st_size}\0{info.st_mtime_ns}\n".encode())
    return digest.hexdigest()
