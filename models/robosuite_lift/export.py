"""Export robosuite 1.5.2's Lift (Panda, default gripper and controller) as built.

Run from the repository's root: `python models/robosuite_lift/export.py` (it builds and uses
robosuite's own environment, `rsenv.py`). It writes `lift.xml` (`env.model.get_xml()` with
every asset path made relative, nothing else changed), copies each mesh and texture that
`lift.xml` names byte for byte from robosuite's installed package (meshes under `meshes/`, the
compiler's `meshdir`; textures under `textures/`), rewrites the sha256 table of `README.md`
and checks that `lift.xml` compiles to the very model robosuite's env simulates.
"""

from __future__ import annotations

import argparse
import hashlib
import re
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import rsenv  # noqa: E402

argparse.ArgumentParser(description=__doc__.split("\n")[0]).parse_args()  # --help, before work
rsenv.ensure()

import mujoco  # noqa: E402
import robosuite  # noqa: E402
from lift_env import make_env, same_model  # noqa: E402

OUT = rsenv.HERE
XML = OUT / "lift.xml"
ASSETS = Path(robosuite.__file__).resolve().parent / "models" / "assets"
BEGIN, END = "<!-- sha256: written by export.py -->", "<!-- end sha256 -->"
# an asset element with a file attribute: its tag and the path
FILE = re.compile(r'<(mesh|texture)\b[^>]*?\bfile="([^"]+)"')


def relative(tag: str, path: str) -> tuple[str, Path]:
    """The path `lift.xml` gives the file, and where the file lies in this folder."""
    rel = Path(path).resolve().relative_to(ASSETS).as_posix()
    if tag == "mesh":
        return rel, OUT / "meshes" / rel  # meshes are looked up under meshdir="meshes/"
    return rel, OUT / rel  # textures under textures/, relative to the model's folder


def export() -> list[Path]:
    env = make_env()
    xml = env.model.get_xml()
    if 'meshdir="meshes/"' not in xml:
        raise SystemExit("export: the model's compiler no longer sets meshdir=\"meshes/\"")
    for stale in ("meshes", "textures"):
        shutil.rmtree(OUT / stale, ignore_errors=True)
    files = []

    def swap(match: re.Match) -> str:
        tag, path = match.groups()
        rel, dest = relative(tag, path)
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, dest)
        files.append(dest)
        return match.group(0).replace(f'file="{path}"', f'file="{rel}"')

    XML.write_text(FILE.sub(swap, xml), encoding="utf-8")
    same_model(env.sim.model._model, mujoco.MjModel.from_xml_path(str(XML)))
    return files


def sha256_table(files: list[Path]) -> str:
    rows = ["| file | bytes | sha256 |", "| --- | --- | --- |"]
    for f in sorted({XML, *files}):
        data = f.read_bytes()
        rows.append(f"| `{f.relative_to(OUT).as_posix()}` | {len(data)} | "
                    f"`{hashlib.sha256(data).hexdigest()}` |")  # fmt: skip
    return "\n".join(rows)


def main() -> None:
    files = export()
    readme = OUT / "README.md"
    text = readme.read_text(encoding="utf-8")
    head, rest = text.split(BEGIN)
    _, tail = rest.split(END)
    readme.write_text(f"{head}{BEGIN}\n{sha256_table(files)}\n{END}{tail}", encoding="utf-8")
    print(f"wrote {XML} and {len(files)} assets; robosuite {robosuite.__version__}, "
          f"MuJoCo {mujoco.__version__}")  # fmt: skip


if __name__ == "__main__":
    main()
