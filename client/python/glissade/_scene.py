"""A scene file and the mesh files it names, read as the CLI reads them."""

from __future__ import annotations

import hashlib
import os
import sys
from typing import Dict, List, Tuple

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from .errors import GlissadeError


def read_scene(path: str) -> Tuple[str, List[Tuple[str, bytes, str]]]:
    """The scene's text and its mesh files (name, bytes, SHA-256 hex), each once.

    A body with `mesh = { file = "...", volume = "..." }` names a Gmsh file next to the scene
    file; the coordinator and the pools open no path, so the bytes travel with the scene.
    """
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except OSError as e:
        raise GlissadeError(f"cannot read scene {path}: {e.strerror}") from e
    try:
        scene = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise GlissadeError(f"scene {path}: {e}") from e
    files: Dict[str, bytes] = {}
    for i, body in enumerate(scene.get("bodies", [])):
        mesh = body.get("mesh") if isinstance(body, dict) else None
        name = mesh.get("file") if isinstance(mesh, dict) else None
        if not isinstance(name, str) or name in files:
            continue
        mesh_path = os.path.join(os.path.dirname(path), name)
        try:
            with open(mesh_path, "rb") as f:
                files[name] = f.read()
        except OSError as e:
            raise GlissadeError(f"scene {path}: bodies[{i}].mesh.file: cannot read {mesh_path}: {e.strerror}") from e
    return text, [(name, data, hashlib.sha256(data).hexdigest()) for name, data in sorted(files.items())]
