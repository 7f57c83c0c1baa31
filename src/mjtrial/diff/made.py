"""What differs in how two runs were made, read from their stamps and manifests: the commit,
each stage's code, the config by key, the model's files, libraries, Python and the machine."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from mjtrial.diff.source import Run, iter_stamps

# What a stamp's platform says of the machine, in the order a diff shows it.
PLATFORM_KEYS = (
    "system",
    "machine",
    "python_implementation",
    "cpu_model",
    "cpu_flags_fp",
    "ncpu",
)


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """A nested mapping as {dotted key: leaf value}; lists are leaves. `{}` stays a leaf."""
    if not isinstance(value, Mapping) or (not value and prefix):
        return {prefix: value}
    out: dict[str, Any] = {}
    for key, inner in value.items():
        out.update(flatten(inner, f"{prefix}.{key}" if prefix else str(key)))
    return out


def _one(values: Iterable[Any]) -> Any:
    """The value all stamps agree on, or the sorted distinct values when they do not."""
    distinct = sorted({repr(v): v for v in values}.items())
    return distinct[0][1] if len(distinct) == 1 else [v for _, v in distinct]


def _commit(git: Mapping[str, Any]) -> str:
    if not git.get("available"):
        return f"no git ({git.get('reason', 'unknown')})"
    dirty = git.get("diff_sha256")
    return git["commit"] + (f" + uncommitted changes {dirty[:12]}" if dirty else "")


def made_facts(run: Run) -> dict[str, dict[str, Any]]:
    """Every fact of how the run was made, by section and key, each a JSON value."""
    code: dict[str, Any] = {}
    modules: dict[str, dict[str, str]] = {}
    commits, versions, platform, threads = [], {}, {}, []
    benchmark_config: dict[str, Any] = {}
    for _, stamp in iter_stamps(run):
        if stamp.get("rule") == "benchmark":  # a benchmark has no manifest: its summary's
            benchmark_config = {"benchmark": stamp.get("config_slice") or {}}
        stage = str(stamp.get("rule", "?")).split(":")[0]
        extra = stamp.get("extra") or {}
        if "code_sha256" in extra:
            code.setdefault(stage, set()).add(extra["code_sha256"])
            modules.setdefault(stage, {}).update(extra.get("code") or {})
        commits.append(_commit(stamp.get("git") or {}))
        for key, value in (stamp.get("versions") or {}).items():
            versions.setdefault(key, []).append(value)
        for key in PLATFORM_KEYS:
            platform.setdefault(key, []).append((stamp.get("platform") or {}).get(key))
        if "threads" in extra:
            threads.append(extra["threads"])
    manifest = run.json(run.layout.manifest.name) or {}
    rerun = manifest.get("rerun") or {}
    model = manifest.get("model") or {}
    return {
        "commit": {"commit": _one(commits)} if commits else {},
        "code": {stage: _one(hashes) for stage, hashes in sorted(code.items())},
        "modules": modules,
        "config": flatten(rerun.get("config") or benchmark_config),
        "model": {
            **{f"files.{name}": sha for name, sha in sorted((model.get("files") or {}).items())},
            **{k: model[k] for k in ("sha256", "compiled_sha256") if k in model},
        },
        "versions": {key: _one(v) for key, v in sorted(versions.items())},
        "platform": {
            **{key: _one(v) for key, v in platform.items()},
            **({"rollout_threads": _one(threads)} if threads else {}),
        },
    }


def _differing(a: Mapping[str, Any], b: Mapping[str, Any]) -> list[dict[str, Any]]:
    return [
        {"key": key, "a": a.get(key), "b": b.get(key)}
        for key in sorted(set(a) | set(b), key=lambda k: (k not in a, k))
        if a.get(key) != b.get(key) and not _emptied(key, a, b) and not _emptied(key, b, a)
    ]


def _emptied(key: str, one: Mapping[str, Any], other: Mapping[str, Any]) -> bool:
    """Whether `key` is an empty mapping in `one` (`flatten` keeps `{}` as a leaf: a condition
    with no settings) that `other` holds keys under: the keys below say what differs, and the
    condition is in both runs (not "{} -> (absent)")."""
    return one.get(key) == {} and key not in other and any(k.startswith(f"{key}.") for k in other)


def how_made(a: Run, b: Run) -> dict[str, list[dict[str, Any]]]:
    """Per section (commit, code, config, model, versions, platform), the keys whose values
    differ between the runs, each `{"key", "a", "b"}` (None: absent). A stage whose code
    differs names the modules that do (`modules`)."""
    fa, fb = made_facts(a), made_facts(b)
    out = {s: _differing(fa[s], fb[s]) for s in fa if s != "modules"}
    for row in out["code"]:
        ma, mb = fa["modules"].get(row["key"], {}), fb["modules"].get(row["key"], {})
        row["modules"] = [r["key"] for r in _differing(ma, mb)]
    return out
