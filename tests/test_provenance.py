"""Tests for mjtrial.provenance.stamp: hashes, git state, versions, platform, make_stamp."""

from __future__ import annotations

import ast
import getpass
import hashlib
import importlib.metadata
import json
import os
import re
import shutil
import socket
import subprocess
from pathlib import Path

import pyarrow as pa
import pytest

import mjtrial.provenance.stamp as building
from mjtrial.provenance import (
    config_hash,
    file_sha256,
    git_state,
    library_versions,
    make_stamp,
    platform_fingerprint,
)

needs_git = pytest.mark.skipif(shutil.which("git") is None, reason="git executable not installed")

# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


@pytest.fixture
def git_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> dict[str, str]:
    """Environment for git subprocesses: identity via env, no user/system config read."""
    monkeypatch.setenv("GIT_CONFIG_GLOBAL", os.devnull)
    monkeypatch.setenv("GIT_CONFIG_NOSYSTEM", "1")
    return {
        **os.environ,
        "GIT_AUTHOR_NAME": "Test Author",
        "GIT_AUTHOR_EMAIL": "author@example.invalid",
        "GIT_COMMITTER_NAME": "Test Committer",
        "GIT_COMMITTER_EMAIL": "committer@example.invalid",
    }


def _git(cwd: Path, env: dict[str, str], *args: str) -> str:
    out = subprocess.run(
        ["git", *args], cwd=cwd, env=env, check=True, capture_output=True, text=True
    )
    return out.stdout.strip()


@pytest.fixture
def repo(tmp_path: Path, git_env: dict[str, str]) -> Path:
    """A throwaway repo with one commit: tracked.txt, .gitignore (*.log), data/input.csv."""
    root = tmp_path / "repo"
    root.mkdir()
    _git(root, git_env, "init", "-q", "-b", "main")
    (root / "tracked.txt").write_text("line 1\n")
    (root / ".gitignore").write_text("*.log\n")
    (root / "data").mkdir()
    (root / "data" / "input.csv").write_text("a,b\n1,2\n")
    _git(root, git_env, "add", "-A")
    _git(root, git_env, "commit", "-q", "-m", "initial")
    return root


@pytest.fixture
def stamp(repo: Path, tmp_path: Path) -> dict:
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (outside / "external.bin").write_bytes(b"\x00\x01\x02")
    return make_stamp(
        rule="simulate",
        config_slice={"episodes": 3, "model": "gantry_gripper", "noise": [0.1, 0.2]},
        inputs={
            "data": repo / "data" / "input.csv",
            "external": outside / "external.bin",
            "many": [repo / "tracked.txt", str(repo / ".gitignore")],
        },
        seeds={"master": 12345},
        repo_dir=repo,
        extra={"code_sha256": "0" * 64, "note": "ünïcode ✓"},
    )


# --------------------------------------------------------------------------------------------
# Hashes
# --------------------------------------------------------------------------------------------


def test_config_hash_independent_of_key_order() -> None:
    a = {"b": 1, "a": {"y": [1, 2], "x": "s"}}
    b = {"a": {"x": "s", "y": [1, 2]}, "b": 1}
    assert config_hash(a) == config_hash(b)
    canonical = b'{"a":{"x":"s","y":[1,2]},"b":1}'
    assert config_hash(a) == hashlib.sha256(canonical).hexdigest()
    assert config_hash(a) != config_hash({**a, "b": 2})
    assert config_hash([1, 2]) != config_hash([2, 1])  # list order matters


def test_file_sha256_streams_large_file(tmp_path: Path) -> None:
    data = os.urandom((5 << 20) // 2 + 17)  # 2.5 MiB + a bit: several 1 MiB blocks
    p = tmp_path / "big.bin"
    p.write_bytes(data)
    assert file_sha256(p) == hashlib.sha256(data).hexdigest()
    empty = tmp_path / "empty"
    empty.write_bytes(b"")
    assert file_sha256(str(empty)) == hashlib.sha256(b"").hexdigest()


def test_folder_sha256_covers_names_and_bytes_of_its_visible_files(tmp_path: Path) -> None:
    folder = tmp_path / "fast"
    folder.mkdir()
    (folder / "b.rrd").write_bytes(b"second")
    (folder / "a.rrd").write_bytes(b"first")
    (folder / ".snakemake_timestamp").write_bytes(b"")  # Snakemake's, not the output's
    lines = "".join(
        f"{name}\0{hashlib.sha256(data).hexdigest()}\n"
        for name, data in [("a.rrd", b"first"), ("b.rrd", b"second")]
    )
    expected = hashlib.sha256(lines.encode()).hexdigest()
    assert file_sha256(folder) == expected
    (folder / ".snakemake_timestamp").write_bytes(b"touched")
    assert file_sha256(folder) == expected
    (folder / "b.rrd").rename(folder / "c.rrd")  # a rename changes it
    assert file_sha256(folder) != expected


# --------------------------------------------------------------------------------------------
# Git
# --------------------------------------------------------------------------------------------


@needs_git
def test_git_state_clean(repo: Path, git_env: dict[str, str]) -> None:
    state = git_state(repo)
    assert state == {
        "available": True,
        "commit": _git(repo, git_env, "rev-parse", "HEAD"),
        "branch": "main",
        "dirty": False,
        "diff_sha256": None,
    }
    assert git_state(repo / "data") == state  # found from a subdirectory too


@needs_git
def test_git_state_modified_tracked_file(repo: Path, git_env: dict[str, str]) -> None:
    (repo / "tracked.txt").write_text("line 1\nchange A\n")
    a = git_state(repo)
    assert a["available"] and a["dirty"] is True
    assert re.fullmatch(r"[0-9a-f]{64}", a["diff_sha256"])
    assert git_state(repo)["diff_sha256"] == a["diff_sha256"]  # deterministic

    (repo / "tracked.txt").write_text("line 1\nchange B\n")
    b = git_state(repo)
    assert b["dirty"] is True and b["diff_sha256"] != a["diff_sha256"]

    _git(repo, git_env, "add", "tracked.txt")  # staged changes count as well
    assert git_state(repo)["diff_sha256"] == b["diff_sha256"]

    (repo / "tracked.txt").write_text("line 1\n")
    _git(repo, git_env, "add", "tracked.txt")
    assert git_state(repo)["dirty"] is False


@needs_git
def test_git_state_untracked_files(repo: Path) -> None:
    # Outputs and ignored files do not count.
    (repo / "results").mkdir()
    (repo / "results" / "table.parquet").write_bytes(b"x")
    (repo / ".snakemake").mkdir()
    (repo / ".snakemake" / "log.txt").write_text("x")
    (repo / "debug.log").write_text("ignored by .gitignore")
    clean = git_state(repo)
    assert clean["dirty"] is False and clean["diff_sha256"] is None

    new = repo / "src_new.py"
    new.write_text("print(1)\n")
    a = git_state(repo)
    assert a["dirty"] is True and a["diff_sha256"] is not None

    new.write_text("print(2)\n")  # untracked content is part of the hash
    assert git_state(repo)["diff_sha256"] != a["diff_sha256"]


@needs_git
def test_git_state_detached_head(repo: Path, git_env: dict[str, str]) -> None:
    head = _git(repo, git_env, "rev-parse", "HEAD")
    _git(repo, git_env, "checkout", "-q", "--detach", head)
    state = git_state(repo)
    assert state["available"] is True
    assert state["commit"] == head and state["branch"] is None


def _inside_some_repo(path: Path) -> bool:
    return any((p / ".git").exists() for p in [path, *path.parents])


@needs_git
def test_git_state_not_a_repo(tmp_path: Path, git_env: dict[str, str]) -> None:
    plain = tmp_path / "plain"
    plain.mkdir()
    if _inside_some_repo(plain):
        pytest.skip("tmp_path lies inside a git repository")
    state = git_state(plain)
    assert state["available"] is False
    assert isinstance(state["reason"], str) and state["reason"]
    assert "\n" not in state["reason"]
    assert str(tmp_path) not in state["reason"]

    missing = git_state(tmp_path / "no" / "such" / "dir")
    assert missing["available"] is False and missing["reason"]


@needs_git
def test_git_state_no_commits(tmp_path: Path, git_env: dict[str, str]) -> None:
    root = tmp_path / "empty_repo"
    root.mkdir()
    _git(root, git_env, "init", "-q", "-b", "main")
    (root / "file.txt").write_text("x")
    state = git_state(root)
    assert state["available"] is False
    assert "commit" in state["reason"]


def test_git_state_git_missing(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    git = pytest.importorskip("git")

    def boom(*args, **kwargs):
        raise git.GitCommandNotFound("git", "not installed")

    monkeypatch.setattr(git, "Repo", boom)
    state = git_state(tmp_path)
    assert state["available"] is False and "git" in state["reason"]


@needs_git
def test_git_state_never_raises(monkeypatch: pytest.MonkeyPatch, repo: Path) -> None:
    def boom(*args, **kwargs):
        raise RuntimeError(f"exploded in {repo}\nsecond line")

    monkeypatch.setattr(building, "_git_state_of", boom)
    state = git_state(repo)
    assert state["available"] is False
    assert "RuntimeError" in state["reason"]
    assert "\n" not in state["reason"] and str(repo) not in state["reason"]


# --------------------------------------------------------------------------------------------
# Environment
# --------------------------------------------------------------------------------------------


def test_library_versions(monkeypatch: pytest.MonkeyPatch) -> None:
    real = importlib.metadata.version

    def fake(name: str) -> str:
        if name == "rerun-sdk":
            raise importlib.metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(importlib.metadata, "version", fake)
    v = library_versions()
    assert set(v) == {
        "python",
        "mujoco",
        "numpy",
        "snakemake",
        "rerun-sdk",
        "gitpython",
        "pyarrow",
        "mjtrial",
    }
    assert v["rerun-sdk"] is None
    assert v["python"] and v["numpy"] == real("numpy") and v["pyarrow"] == pa.__version__


def test_platform_fingerprint() -> None:
    fp = platform_fingerprint()
    assert set(fp) == {
        "system",
        "machine",
        "python_implementation",
        "cpu_model",
        "cpu_flags_fp",
        "ncpu",
    }
    assert fp["cpu_flags_fp"] == sorted(fp["cpu_flags_fp"])
    assert set(fp["cpu_flags_fp"]) <= building._FP_FLAGS
    assert fp["ncpu"] is None or fp["ncpu"] >= 1
    json.dumps(fp)


# --------------------------------------------------------------------------------------------
# make_stamp
# --------------------------------------------------------------------------------------------


@needs_git
def test_make_stamp_fields(stamp: dict, repo: Path, git_env: dict[str, str]) -> None:
    assert stamp["mjtrial_stamp"] == 1
    assert stamp["rule"] == "simulate"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", stamp["created_utc"])
    assert stamp["git"]["available"] is True
    assert stamp["git"]["commit"] == _git(repo, git_env, "rev-parse", "HEAD")
    assert stamp["config_slice"] == {
        "episodes": 3,
        "model": "gantry_gripper",
        "noise": [0.1, 0.2],
    }
    assert stamp["config_slice_sha256"] == config_hash(stamp["config_slice"])
    assert stamp["inputs"]["data"] == {
        "path": "data/input.csv",
        "sha256": file_sha256(repo / "data" / "input.csv"),
    }
    assert stamp["inputs"]["external"]["path"] == "external.bin"  # outside repo: basename
    assert [i["path"] for i in stamp["inputs"]["many"]] == ["tracked.txt", ".gitignore"]
    assert stamp["seeds"] == {"master": 12345}
    assert stamp["extra"] == {"code_sha256": "0" * 64, "note": "ünïcode ✓"}
    assert stamp["versions"] == library_versions()
    assert stamp["platform"] == platform_fingerprint()
    json.dumps(stamp, allow_nan=False)


def test_make_stamp_relative_inputs_and_defaults(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "cfg").mkdir()
    (tmp_path / "cfg" / "a.yaml").write_text("a: 1\n")
    monkeypatch.chdir(tmp_path)
    s = make_stamp(rule="r", config_slice=None, inputs={"cfg": "cfg/a.yaml"}, repo_dir=Path("."))
    assert s["inputs"]["cfg"]["path"] == "cfg/a.yaml"
    assert s["seeds"] == {} and s["extra"] == {}
    assert s["git"]["available"] in (True, False)


@needs_git
def test_make_stamp_holds_nothing_private(
    repo: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    secret = "s3cret-token-value-9f8e7d"
    monkeypatch.setenv("MJTRIAL_TEST_SECRET", secret)
    monkeypatch.setenv("MJTRIAL_TEST_SECRET_PATH", str(tmp_path / "private" / "dir"))
    (tmp_path / "elsewhere.txt").write_text("e")
    s = make_stamp(
        rule="r",
        config_slice={"k": 1},
        inputs={"x": repo / "tracked.txt", "y": tmp_path / "elsewhere.txt"},
        repo_dir=repo,
    )
    text = json.dumps(s, ensure_ascii=False)
    assert secret not in text
    assert str(tmp_path) not in text

    # Values recorded on purpose (library versions, platform) may coincide with an env var
    # such as PYTHON_VERSION, and short flags such as CI=true coincide with JSON's own words;
    # anything else of some length taken from the environment must not appear.
    public = {str(v) for part in ("versions", "platform") for v in s[part].values()}
    for key, value in os.environ.items():
        if len(value) >= 8 and value not in public:
            assert value not in text, f"value of ${key} leaked into the stamp"

    home = str(Path.home())
    if home not in ("/", ""):
        assert home not in text
    user = getpass.getuser()
    if len(user) >= 4:
        assert user not in text
    host = socket.gethostname()
    if len(host) >= 4:
        assert host not in text


# --------------------------------------------------------------------------------------------
# The package's place among mjtrial's modules
# --------------------------------------------------------------------------------------------


def test_provenance_imports_no_other_mjtrial_module() -> None:
    # Every stage imports provenance; a module it imported, even inside a function (as it once
    # did recording), would import it back: a cycle.
    imported = set()
    for source in Path(building.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(source.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                imported.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                imported.add(node.module)
    ours = {m for m in imported if m.split(".")[0] == "mjtrial"}
    assert ours == {
        "mjtrial.files.atomic",
        "mjtrial.provenance.formats",
        "mjtrial.provenance.model_closure",
        "mjtrial.provenance.rows",
        "mjtrial.provenance.stamp",
    }


def _model_with_assets(root):
    """A scene in root/robot/ that includes ../common/arm.xml (which includes parts.xml from its
    own folder and names a mesh beside it), with a mesh and a binary height field in its meshdir
    and a PNG texture; plus a file in the folder that the model does not load."""
    import struct

    from PIL import Image

    (root / "robot" / "meshes").mkdir(parents=True)
    (root / "common").mkdir()
    tetra = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\n"
    (root / "robot" / "meshes" / "base.obj").write_text(tetra)
    (root / "common" / "link.obj").write_text(tetra)
    Image.new("RGB", (4, 4), (200, 10, 10)).save(root / "robot" / "checker.png")
    heights = struct.pack("<ii", 2, 2) + struct.pack("<4f", 0, 1, 1, 0)
    (root / "robot" / "meshes" / "ground.bin").write_bytes(heights)
    (root / "robot" / "unused.xml").write_text("<mujoco/>")
    (root / "common" / "parts.xml").write_text(
        '<mujoco><worldbody><geom name="part" size="0.01"/></worldbody></mujoco>'
    )
    (root / "common" / "arm.xml").write_text(
        '<mujoco><include file="parts.xml"/><asset><mesh name="link" file="link.obj"/></asset>'
        '<worldbody><body name="arm"><freejoint/><geom type="mesh" mesh="link"/></body>'
        "</worldbody></mujoco>"
    )
    scene = root / "robot" / "scene.xml"
    scene.write_text(
        '<mujoco><compiler meshdir="meshes"/><include file="../common/arm.xml"/><asset>'
        '<mesh name="base" file="base.obj"/><texture name="t" type="2d" file="checker.png"/>'
        '<material name="m" texture="t"/>'
        '<hfield name="ground" file="ground.bin" size="1 1 0.1 0.1"/>'
        '</asset><worldbody><geom type="mesh" mesh="base" material="m"/>'
        '<geom type="hfield" hfield="ground"/></worldbody></mujoco>'
    )
    return scene


def test_model_closure_is_what_mujoco_loads(tmp_path):
    """Survey case 1: the closure lists exactly the files MuJoCo reads, wherever they are:
    a hand-written list, and removing any one of them makes MuJoCo fail to load the model."""
    import mujoco

    from mjtrial.provenance.model_closure import model_closure

    scene = _model_with_assets(tmp_path)
    mujoco.MjModel.from_xml_path(str(scene))  # the model loads as it is
    expected = [
        scene,
        tmp_path / "common" / "arm.xml",
        tmp_path / "common" / "link.obj",
        tmp_path / "common" / "parts.xml",
        tmp_path / "robot" / "checker.png",
        tmp_path / "robot" / "meshes" / "ground.bin",
        tmp_path / "robot" / "meshes" / "base.obj",
    ]
    closure = model_closure(scene)
    assert closure[0] == scene
    assert sorted(closure[1:]) == sorted(p.resolve() for p in expected[1:])
    for path in expected[1:]:
        saved = path.read_bytes()
        path.unlink()
        with pytest.raises(ValueError):
            mujoco.MjModel.from_xml_path(str(scene))
        path.write_bytes(saved)


def test_model_hash_sees_an_edit_to_an_include_in_another_folder(tmp_path):
    from mjtrial import provenance

    scene = _model_with_assets(tmp_path)
    before = provenance.model_sha256(scene)
    (tmp_path / "robot" / "unused.xml").write_text("<mujoco><!-- not loaded --></mujoco>")
    assert provenance.model_sha256(scene) == before
    parts = tmp_path / "common" / "parts.xml"
    parts.write_text(parts.read_text().replace('size="0.01"', 'size="0.02"'))
    assert provenance.model_sha256(scene) != before
