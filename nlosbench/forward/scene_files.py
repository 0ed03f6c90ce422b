"""The files a Mitsuba scene loads, found by Mitsuba's own parser, and the scene's content hash over them.

`scene_files` parses the scene file with `mitsuba.parser.parse_file` and the defines the scene is loaded
with, as `mi.load_file` does: `$name` substituted (the values passed, else the file's `<default>`s),
`<include>`s followed recursively, the scene file's folder put first on a copy of the file resolver
(with the `<path>` folders the file adds). The parser lists every XML file it read (`ParserState.files`);
every string property of the parsed scene that the resolver turns into an existing file (meshes,
textures, volumes, measured data: the files plugins open when the scene is instantiated) is one too.
Spectra given by a file are read by the parser itself, so their values are taken from the parsed scene.

`content_hash` folds names and contents into one SHA-256: a mesh edited, renamed through a define or
swapped inside an included file changes it. Names are as written in the scene (after substitution), so
a scene folder that moves keeps its hash.
"""
from __future__ import annotations

import hashlib
from pathlib import Path


def scene_files(scene_file: str | Path, defines: dict, variant: str) -> dict[str, Path]:
    """Name → path of every file Mitsuba reads to load `scene_file` with `defines` (str → str): the XML
    files (the scene file under its own name, includes by their path relative to its folder) and each
    referenced file under the name the scene gives it."""
    return _parse(Path(scene_file), defines, variant)[0]


def content_hash(scene_file: str | Path, defines: dict, variant: str) -> str:
    """SHA-256 hex over the names and bytes of `scene_files` and the values of every spectrum."""
    files, spectra = _parse(Path(scene_file), defines, variant)
    h = hashlib.sha256()
    for name, path in sorted(files.items()):
        h.update(f"{name}\0{hashlib.sha256(path.read_bytes()).hexdigest()}\n".encode())
    h.update(repr(spectra).encode())
    return h.hexdigest()


def _parse(scene_file: Path, defines: dict, variant: str) -> tuple[dict[str, Path], list]:
    """(`scene_files`, [(wavelengths, values) of every spectrum property]) from one parse of the scene."""
    import mitsuba as mi

    base = mi.file_resolver()
    resolver = mi.FileResolver(base)
    resolver.prepend(str(scene_file.parent))
    mi.set_file_resolver(resolver)  # as mi.load_file does; the scene's <path> tags add to this copy
    try:
        state = mi.parser.parse_file(mi.parser.ParserConfig(variant), str(scene_file), **defines)
        files = {_xml_name(Path(str(f)), scene_file): Path(str(f)) for f in state.files}
        spectra = []
        for props in (node.props for node in state.nodes):
            for name in props.keys():
                kind = props.type(name)
                if kind == mi.Properties.Type.String:
                    path = Path(str(resolver.resolve(props[name])))
                    if props[name] and path.is_file():
                        files.setdefault(props[name], path)
                elif kind == mi.Properties.Type.Spectrum:
                    spectra.append((list(props[name].wavelengths), list(props[name].values)))
    finally:
        mi.set_file_resolver(base)
    return files, spectra


def _xml_name(path: Path, scene_file: Path) -> str:
    """An XML file's name in the hash: relative to the scene file's folder when inside it."""
    try:
        return path.resolve().relative_to(scene_file.resolve().parent).as_posix()
    except ValueError:
        return str(path)
