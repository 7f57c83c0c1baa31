"""Every file a MuJoCo model is built from, found as MuJoCo resolves them.

A model is its scene file, the files it includes (wherever they are), and the meshes, textures,
height fields and skins its assets name. Hashing the scene's folder alone misses an include in
another folder; hashing the closure sees an edit to any file that changes what runs.

Resolution, checked against MuJoCo 3.14 in tests/test_provenance.py: an `<include file=...>`
is looked up in the main model file's folder first, then in the including file's folder; an
asset's path is what `MjSpec` reports, in the compiler's meshdir (meshes, height fields, skins)
or texturedir (textures) when relative; an asset named in an included file comes back resolved
from that file's folder.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco


def _includes(path: Path, main_dir: Path, seen: list[Path]) -> None:
    """Append `path` and every file it includes, depth first, each once."""
    path = path.resolve()
    if path in seen:
        return
    seen.append(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return  # MuJoCo will say what is wrong when it loads the model
    for element in root.iter("include"):
        name = element.get("file")
        if not name:
            continue
        candidates = [main_dir / name, path.parent / name]  # an absolute name: both the same
        found = next((c for c in candidates if c.is_file()), None)
        if found is not None:
            _includes(found, main_dir, seen)


def _asset(spec: mujoco.MjSpec, name: str, subdir: str) -> Path | None:
    if not name:
        return None
    path = Path(name)
    if path.is_absolute():
        return path
    base = Path(spec.modelfiledir)
    candidates = [base / subdir / path, base / path] if subdir else [base / path]
    return next((c for c in candidates if c.is_file()), candidates[0])


def model_closure(scene: Path) -> list[Path]:
    """The scene, then every other file MuJoCo reads to build it (resolved absolute paths,
    sorted, each once). A file that cannot be parsed contributes itself only."""
    scene = Path(scene)
    files: list[Path] = []
    _includes(scene, scene.resolve().parent, files)
    try:
        spec = mujoco.MjSpec.from_file(str(scene.resolve()))  # as physics.load_spec
    except ValueError:
        spec = None
    if spec is not None:
        assets = [_asset(spec, m.file, spec.meshdir) for m in spec.meshes]
        assets += [_asset(spec, h.file, spec.meshdir) for h in spec.hfields]
        assets += [_asset(spec, s.file, spec.meshdir) for s in spec.skins]
        for texture in spec.textures:
            for name in (texture.file, *texture.cubefiles):
                assets.append(_asset(spec, name, spec.texturedir))
        files += [a.resolve() for a in assets if a is not None]
    head, *rest = files
    return [head, *sorted(set(rest) - {head})]
