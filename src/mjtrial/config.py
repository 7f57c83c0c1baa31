"""Load and check the experiment's config: the schema first, then what a schema cannot say.

Every problem is reported as one line naming the file, the key and what was expected, before
any work starts, so a typo never costs a run or touches an earlier result.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from mjtrial import REPO_ROOT
from mjtrial.layout import CONFIG_FILE, Layout
from mjtrial.model_spec import ModelError
from mjtrial.provenance import git_state
from mjtrial.simulate import load_model

SCHEMA_PATH = REPO_ROOT / "workflow" / "schemas" / "config.schema.yaml"
DEFAULT_CONFIG = REPO_ROOT / CONFIG_FILE


class ConfigError(ValueError):
    """The config does not describe a runnable experiment; the message is one line."""


# What each schema keyword expects, in the config's words; `s` is the keyword's value.
_EXPECTATIONS = {
    "type": "expected {s}",
    "minimum": "expected >= {s}",
    "maximum": "expected <= {s}",
    "exclusiveMinimum": "expected > {s}",
    "exclusiveMaximum": "expected < {s}",
    "enum": "expected one of {s}",
    "minItems": "expected at least {s} items",
    "maxItems": "expected at most {s} items",
    "minLength": "expected a non-empty string",
    "minProperties": "expected at least {s} entries",
    "pattern": "expected a name matching {s}",
}


def _key(error: jsonschema.ValidationError, child: Any = None) -> str:
    """The key an error is about, from jsonschema's path (`$.states.ranges.mass[0]` ->
    `states.ranges.mass[0]`), optionally one level further down, at `child`."""
    key = error.json_path.removeprefix("$").removeprefix(".")
    if child is not None:
        key = f"{key}.{child}" if key else str(child)
    return key or "(top level)"


def _schema_message(error: jsonschema.ValidationError) -> str:
    """`key: expectation` for one schema error, naming the offending key itself."""
    keyword, value, got = error.validator, error.validator_value, error.instance
    if keyword == "additionalProperties":
        allowed = sorted(error.schema.get("properties", {}))
        unknown = min(set(got) - set(allowed), key=str)
        hint = f"one of {allowed}" if allowed else "no other keys"
        return f"{_key(error, unknown)}: unknown key; expected {hint}"
    if keyword == "required":
        missing = next(k for k in value if k not in got)
        return f"{_key(error, missing)}: missing; this key is required"
    template = _EXPECTATIONS.get(keyword)
    expectation = template.format(s=value) if template else error.message
    return f"{_key(error)}: {expectation}, got {got!r}"


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
    layout = Layout.of(config["experiment"])
    manifest = repo_root / layout.manifest
    if manifest.is_file():
        try:
            recorded = json.loads(manifest.read_text()).get("experiment")
        except (ValueError, AttributeError):
            recorded = None
        if recorded != config["experiment"]:
            raise ConfigError(
                f"{layout.root}/: written by experiment {recorded!r} (manifest.json); expected "
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
        raise ConfigError(f"{source}: {_schema_message(error)}")

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
    try:
        load_model(model_file)
    except ModelError as err:
        fail("model", str(err).replace(str(model_file), config["model"]))
