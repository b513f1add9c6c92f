"""The files an MJCF model reads besides its own: included files (recursively) and the assets
they name (meshes, height fields, skins, textures), resolved as MuJoCo's compiler resolves them
(`<compiler meshdir texturedir assetdir strippath>`; includes from the main file's folder).

`model_files_digest` hashes them by content, so a robot's identity
(`tkujax.robot.robot_setup.file_digest`, in a sweep's spec hash) changes with any of them.
"""

from __future__ import annotations

import hashlib
import os
import xml.etree.ElementTree as ET
from pathlib import Path

# Elements whose file attributes name assets, and the compiler folder each is looked up in.
MESH_LIKE = ("mesh", "hfield", "skin")
TEXTURE_ATTRS = ("file", "fileright", "fileleft", "fileup", "filedown", "filefront",
                 "fileback")
# Includes nested deeper than this are a loop (MuJoCo refuses them too).
MAX_INCLUDE_DEPTH = 32


def _parse(path: Path) -> ET.Element | None:
    try:
        return ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        return None          # MuJoCo's own loader reports it; the digest hashes the bytes


def _elements(main: Path) -> tuple[list[Path], list[ET.Element]]:
    """(the included files, recursively, in order; every element of the model)."""
    includes: list[Path] = []
    elements: list[ET.Element] = []

    def walk(path: Path, depth: int) -> None:
        root = _parse(path)
        if root is None or depth > MAX_INCLUDE_DEPTH:
            return
        for el in root.iter():
            elements.append(el)
            if el.tag == "include" and el.get("file"):
                child = main.parent / el.get("file")
                if not child.is_file():
                    child = path.parent / el.get("file")
                includes.append(child)
                walk(child, depth + 1)

    walk(main, 0)
    return includes, elements


def _resolve(main: Path, name: str, folder: str | None, strip: bool) -> Path:
    if strip:
        name = os.path.basename(name)
    if os.path.isabs(name):
        return Path(name)
    if folder and os.path.isabs(folder):
        return Path(folder) / name
    return main.parent / (folder or "") / name


def model_files(mjcf: str | Path) -> list[Path]:
    """Every file the model at `mjcf` reads besides itself, in a fixed order (included files,
    then assets), each once; missing ones are listed too (their absence is part of the
    identity)."""
    main = Path(mjcf)
    includes, elements = _elements(main)
    compiler: dict[str, str] = {}
    for el in elements:
        if el.tag == "compiler":
            compiler.update(el.attrib)
    strip = compiler.get("strippath", "false") == "true"
    assetdir = compiler.get("assetdir")
    meshdir, texturedir = compiler.get("meshdir", assetdir), compiler.get("texturedir", assetdir)
    assets = []
    for el in elements:
        if el.tag in MESH_LIKE and el.get("file"):
            assets.append(_resolve(main, el.get("file"), meshdir, strip))
        elif el.tag == "texture":
            assets += [_resolve(main, el.get(a), texturedir, strip) for a in TEXTURE_ATTRS
                       if el.get(a)]
    seen, files = set(), []
    for path in includes + assets:
        key = os.path.normpath(str(path))
        if key not in seen:
            seen.add(key)
            files.append(Path(key))
    return files


def model_files_digest(mjcf: str | Path) -> str:
    """sha256 (hex) over the content of `model_files(mjcf)`, each with its path relative to
    the model's folder (a missing file hashes as missing)."""
    main = Path(mjcf)
    h = hashlib.sha256()
    for path in model_files(main):
        h.update(os.path.relpath(path, main.parent).encode() + b"\0")
        try:
            h.update(path.read_bytes())
        except OSError:
            h.update(b"missing\0")
    return h.hexdigest()
