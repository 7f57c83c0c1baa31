"""Load and check the experiment's config: the schema first, then what a schema cannot say.

Every problem is reported as one line naming the file, the key and what was expected, before
any work starts, so a typo never costs a run or touches an earlier result.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from mjtrial import REPO_ROOT

SCHEMA_PATH = REPO_ROOT / "workflow" / "schemas" / "config.schema.yaml"
DEFAULT_CONFIG = REPO_ROOT / "config" / "config.yaml"


class ConfigError(ValueError):
    """The config does not describe a runnable experiment; the message is one line."""


def _key(path: Any) -> str:
    parts = [str(p) if not isinstance(p, int) else f"[{p}]" for p in path]
    return ".".join(parts).replace(".[", "[") or "(top level)"


def _describe(error: jsonschema.ValidationError) -> tuple[str, str]:
    """(key, expectation) for one schema error, in the config's own words."""
    key = _key(error.absolute_path)
    v, s, got = error.validator, error.validator_value, error.instance
    if v == "additionalProperties":
        allowed = sorted(error.schema.get("properties", {}))
        extra = sorted(set(got) - set(allowed)) if isinstance(got, dict) else []
        name = f"{key}.{extra[0]}" if key != "(top level)" and extra else (extra or [key])[0]
        hint = f"one of {allowed}" if allowed else "no other keys"
        return name, f"unknown key; expected {hint}"
    if v == "required":
        missing = [k for k in s if k not in got]
        name = f"{key}.{missing[0]}" if key != "(top level)" else missing[0]
        return name, "missing; this key is required"
    expect = {
        "type": f"expected {s}",
        "minimum": f"expected >= {s}",
        "maximum": f"expected <= {s}",
        "exclusiveMinimum": f"expected > {s}",
        "exclusiveMaximum": f"expected < {s}",
        "enum": f"expected one of {s}",
        "minItems": f"expected at least {s} items",
        "maxItems": f"expected at most {s} items",
        "minLength": "expected a non-empty string",
        "minProperties": f"expected at least {s} entries",
        "pattern": f"expected a name matching {s}",
    }.get(v, error.message)
    return key, f"{expect}, got {got!r}"


def _duplicate_key(node: yaml.Node, path: tuple[str, ...] = ()) -> tuple[str, int] | None:
    """The first key that appears twice in one mapping, with its line; YAML loaders keep the
    last silently, so a duplicated condition would quietly replace the first."""
    if isinstance(node, yaml.MappingNode):
        seen: set[str] = set()
        for key, value in node.value:
            name = str(key.value)
            if name in seen:
                return ".".join((*path, name)), key.start_mark.line + 1
            seen.add(name)
            found = _duplicate_key(value, (*path, name))
            if found:
                return found
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            found = _duplicate_key(item, (*path[:-1], f"{path[-1]}[{i}]") if path else (f"[{i}]",))
            if found:
                return found
    return None


def read_config_file(path: str | Path) -> dict[str, Any]:
    """Parse a YAML config file strictly (no duplicate keys); no schema check yet."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        config = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ConfigError(f"{path}: not valid YAML{where}: {problem}") from None
    duplicate = _duplicate_key(node) if node is not None else None
    if duplicate:
        key, line = duplicate
        raise ConfigError(f"{path}: {key}: duplicate key (line {line}); expected each key once")
    if not isinstance(config, dict):
        raise ConfigError(f"{path}: expected a mapping of keys at the top level")
    return config


def merge_config(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """`base` with `override`'s values on top, recursively (how Snakemake merges configs)."""
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = merge_config(merged[key], value)
        else:
            merged[key] = value
    return merged


def preflight(config: Mapping[str, Any], *, repo_root: Path) -> list[str]:
    """Checks on the run's surroundings, before any work: warnings to print, or a refusal.

    Refuses (`ConfigError`) a results folder that another experiment wrote, and a dirty
    repository when `provenance.require_clean` is set; a dirty repository otherwise gives one
    warning, since every output will be stamped dirty.
    """
    import json

    from mjtrial.provenance import git_state

    results = Path("results") / config["experiment"]
    manifest = repo_root / results / "manifest.json"
    if manifest.is_file():
        try:
            recorded = json.loads(manifest.read_text()).get("experiment")
        except (ValueError, AttributeError):
            recorded = None
        if recorded != config["experiment"]:
            raise ConfigError(
                f"{results}/: written by experiment {recorded!r} (manifest.json); expected "
                f"{config['experiment']!r}: choose another experiment name or move the folder"
            )
    git = git_state(repo_root)
    if git.get("available") and git.get("dirty"):
        if config["provenance"]["require_clean"]:
            raise ConfigError(
                "provenance.require_clean is true and the repository has uncommitted changes; "
                "expected a clean tree (commit or stash them)"
            )
        return [
            "Warning: the repository has uncommitted changes: every output will be stamped "
            f"dirty: true with the diff's hash {git['diff_sha256'][:12]}"
        ]
    return []


def load_config(path: str | Path = DEFAULT_CONFIG) -> dict[str, Any]:
    """Read a YAML config file and check it (see `check_config`)."""
    config = read_config_file(path)
    check_config(config, source=str(path))
    return config


def check_config(
    config: Mapping[str, Any], *, source: str = "config/config.yaml", repo_root: Path = REPO_ROOT
) -> None:
    """Raise `ConfigError` (one line: file, key, expectation) unless the config is runnable."""
    if not isinstance(config, Mapping):
        raise ConfigError(f"{source}: expected a mapping of keys at the top level")
    schema = yaml.safe_load(SCHEMA_PATH.read_text())
    validator = jsonschema.Draft202012Validator(schema)
    error = jsonschema.exceptions.best_match(validator.iter_errors(dict(config)))
    if error is not None:
        key, expectation = _describe(error)
        raise ConfigError(f"{source}: {key}: {expectation}")

    def fail(key: str, expectation: str) -> None:
        raise ConfigError(f"{source}: {key}: {expectation}")

    conditions = config["conditions"]
    falsifier = config["design"]["falsifier"]
    for role in ("treatment", "baseline"):
        if falsifier[role] not in conditions:
            fail(
                f"design.falsifier.{role}",
                f"expected one of the conditions {sorted(conditions)}, got {falsifier[role]!r}",
            )
    if falsifier["treatment"] == falsifier["baseline"]:
        fail("design.falsifier.baseline", "expected a condition other than the treatment")
    for name, (low, high) in config["states"]["ranges"].items():
        if not low < high:
            fail(
                f"states.ranges.{name}", f"expected [low, high] with low < high, got {[low, high]}"
            )
    if config["states"]["development_seed"] == config["states"]["seed"]:
        fail(
            "states.development_seed",
            "expected a seed other than states.seed (development and evaluation states must be "
            "disjoint)",
        )
    for name, edges in config["analysis"]["bands"].items():
        key = f"analysis.bands.{name}"
        if any(high <= low for low, high in zip(edges[:-1], edges[1:], strict=True)):
            fail(key, f"expected strictly increasing edges, got {edges}")
        parameter = name.removeprefix("abs_")
        low, high = config["states"]["ranges"][parameter]
        if name.startswith("abs_"):
            low, high = 0.0, max(abs(low), abs(high))
        if edges[0] > low or edges[-1] < high:
            fail(key, f"expected edges covering the range of {name} [{low}, {high}], got {edges}")
    model_file = repo_root / config["model"]
    if not model_file.is_file():
        fail("model", f"expected an existing model file, got {config['model']!r} (not found)")
    from mjtrial.simulate import ModelError, load_model

    try:
        load_model(model_file)
    except ModelError as err:
        fail("model", str(err).replace(str(model_file), config["model"]))
